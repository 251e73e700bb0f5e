"""The accelerometer bias the input still carries where no bench calibration measured it, 1σ per axis: the
estimators' default (`MekfParams.accel_bias_sigma_m_s2`) and the magnetometer fits' levelling error
(calibration/mag/backstepping.py's default) take it from here. A module of its own so that the mag-cal fit worker
(daemon/magcal.py), which needs this figure and no estimator, does not import the estimators' compiled kernels
(numba) with it."""

from __future__ import annotations

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

# the ADIS16405's residual turn-on bias after its factory calibration, 5 mg (the simulator's draw,
# docs/simulation.md; the datasheet's uncalibrated worst case is 50 mg)
ACCEL_BIAS_SIGMA_UNCALIBRATED_M_S2 = 5e-3 * STANDARD_GRAVITY_M_S2
