"""Magnetometer fits: the shared input/result types (`fit_types`), their acceptance checks (`acceptance`), the
dispatcher (`fit.fit_mag`) and one module per method or building block (ellipsoid, two-/three-step, alignment,
offsets-only, back-stepping and its vertical channel, levelling, observability, the compass swing)."""
