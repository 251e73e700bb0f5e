"""What the operator decides on, printed first by `ahrsd calibrate mag` (the verdict, the heading error the fit
predicts, the coverage behind it, the residuals) and the details after it without the fitting internals
(optimiser messages, iteration counts, the paper's intermediate sphere fit, the fit's own CPU time)."""

from __future__ import annotations

import math

from ahrsd.calibration.mag.backstepping import fit_blocks_lowpassed
from ahrsd.calibration.report import fmt_value
from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

# quality keys a reader of the report cannot act on: the optimiser's own bookkeeping and intermediate fits
INTERNAL_KEYS = frozenset({"sphere_fit_paper", "time_s", "backstep", "fit_rate_hz", "n_samples", "support_model",
                           "lm_status"})    # the accelerometer fit's least-squares exit code
INTERNAL_NESTED = frozenset({"message", "nfev", "init", "converged"})


def _num(value) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan


def levelling_source(quality: dict) -> str | None:
    """What levelled the field the fit used, in words: the fit records an attitude handed to it as "given", which
    with --gnss is the aided estimator's smoothed attitude."""
    source = quality.get("attitude_source")
    if source != "given":
        return source
    aided = quality.get("aided_levelling")
    if isinstance(aided, dict):
        return f"the GNSS-aided attitude ({aided.get('estimator', 'ins')}{', smoothed' if aided.get('smoothed') else ''})"
    return "the attitude given to the fit"


def _levelling_error_text(lev: dict) -> str:
    """What of the levelling's error the prediction carries (quality.predicted_heading.levelling)."""
    if "accel_bias_sigma_m_s2" in lev:
        return (f"with the accelerometer levelling's bias, {lev['accel_bias_sigma_m_s2'] / STANDARD_GRAVITY_M_S2 * 1e3:g}"
                f" mg, and its tilt errors correlated over {lev['residual_correlation_samples']:.0f} fitted samples")
    return f"with the aided levelling's body-fixed tilt, {lev['given_tilt_sigma_deg']:.2f}° per axis"


def mag_decision_lines(result, outcome: str) -> list[str]:
    """The lead of the magnetometer report: verdict (`outcome`: saved where / not saved / refused why), the
    predicted heading error, the coverage and the residuals."""
    q = result.quality
    lines = [f"  verdict: {outcome}"]
    pred = q.get("predicted_heading") or {}
    offset, varying = _num(pred.get("offset_std_deg")), _num(pred.get("heading_dependent_std_deg"))
    if math.isfinite(offset) or math.isfinite(varying):
        envelope = _num(pred.get("envelope_tilt_deg"))
        lev = pred.get("levelling")
        lines.append(f"  predicted heading error (1σ): {offset:.2f}° constant offset, {varying:.2f}° varying with "
                     "heading" + (f", for tilts within ±{envelope:.0f}°" if math.isfinite(envelope) else "")
                     + (f" ({_levelling_error_text(lev)})" if lev else ""))
    parts = []
    heading_cov = _num(q.get("heading_coverage"))
    if math.isfinite(heading_cov):
        parts.append(f"headings {heading_cov:.0%}")
    sphere = _num(q.get("coverage"))
    if math.isfinite(sphere):
        parts.append(f"sphere {sphere:.0%}")
    tilt = q.get("tilt") or {}
    if math.isfinite(_num(tilt.get("tilt_max_deg"))):
        parts.append(f"tilt up to {tilt['tilt_max_deg']:.1f}°")
    if parts:
        lines.append("  coverage: " + ", ".join(parts))
    lines.append(residual_line(result))
    levelled_by = levelling_source(q)
    if levelled_by:
        lines[-1] += f" (levelled by {levelled_by})"
    for warning in q.get("warnings", ()):
        lines.append(f"  WARNING: {warning}")
    return lines


def residual_line(result) -> str:
    """The fit's residuals, each named by the samples it is of: `residual_rms_ut` of the unfiltered blocks at the
    fit's rate, and the vertical-channel fit's own (`vertical_channel.*_rms_ut`) of the blocks it fitted, which
    the accelerometer's levelling low-passes (two figures of one fit, unlabelled, read as a contradiction)."""
    q = result.quality
    rate_hz = _num(q.get("fit_rate_hz"))
    line = f"  residual: |m| − |F| RMS {result.residual_rms_ut:.3f} µT"
    if math.isfinite(rate_hz):
        line += f" of the {rate_hz:g} Hz block means"
    channel = q.get("vertical_channel") or {}
    magnitude, vertical = _num(channel.get("magnitude_rms_ut")), _num(channel.get("vertical_rms_ut"))
    lowpassed = fit_blocks_lowpassed(q)
    as_fitted = []
    if lowpassed and math.isfinite(magnitude):
        as_fitted.append(f"|m| − |F| {magnitude:.3f} µT")
    if math.isfinite(vertical):
        as_fitted.append(f"vertical field {vertical:.3f} µT")
    if as_fitted:
        how = " (low-passed with the levelling)" if lowpassed else ""
        line += f"; of the blocks fitted{how}: " + ", ".join(as_fitted)
    return line


def detail_lines(quality: dict, shown: frozenset) -> list[str]:
    """`key: value` for each quality entry not in `shown` and not internal; a nested dict loses its internal
    keys, and an infinite threshold reads as "none"."""
    out = []
    for key, value in quality.items():
        if key in shown or key in INTERNAL_KEYS:
            continue
        if isinstance(value, dict):
            value = {k: _readable(v) for k, v in value.items() if k not in INTERNAL_NESTED}
        out.append(f"    {key}: {fmt_value(_readable(value))}")
    return out


def _readable(value):
    if isinstance(value, float) and math.isinf(value):
        return "none"
    if isinstance(value, dict):
        return {k: _readable(v) for k, v in value.items() if k not in INTERNAL_NESTED}
    if isinstance(value, list):
        return [_readable(v) for v in value]
    return value
