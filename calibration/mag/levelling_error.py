"""What the levelling's error adds to a back-stepping fit's predicted heading error.

The fit weights every levelled sample as an independent tilt error (vertical_channel.py, σ_tilt per sample).
On a vehicle two parts of the levelling error are not independent:

- the accelerometer's bias, fixed in the body: a tilt error b/g that the fit folds into the soft iron as a small
  rotation, invisible in its residuals. At heading ψ it turns the heading by tan(dip)·(ε_x cos ψ − ε_y sin ψ)
  (the rotation ε moves the calibrated horizontal field by H_z·(ε_y, −ε_x)), RMS over heading tan(dip)·σ_b/g
  per axis: a heading-dependent error, no constant offset;
- what is left of the lean in turns and of the waves after the low-pass and the centripetal compensation,
  correlated over a turn or a wave group: the fit's data then hold fewer independent samples than rows. The
  vertical-channel residual carries it (a tilt error δ shows as H_h·δ there), so its integrated autocorrelation
  time (Sokal, "Monte Carlo Methods in Statistical Mechanics", 1996, §3: τ_int = 1 + 2 Σ ρ_k, summed up to the
  first lag M ≥ 5 τ_int) is the factor by which the parameter covariance grows.

Levelled by the GNSS-aided estimator (`--gnss`, backstepping_aided.py) the body-fixed part is the tilt the
filter cannot tell from an accelerometer bias and gyro misalignment on a vehicle that stays near level and
mostly yaws (docs/magcal-vehicle.md): it is what the RTS smoother's tilt 1σ is left with once the fixes before
and after every sample are in. It enters as the accelerometer's bias does, a body-fixed tilt ε turning the
heading by tan(dip)·ε: `tilt_heading_std_deg` of the smoother's per-axis 1σ (`body_fixed_tilt_sigma_rad`).
"""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

SOKAL_WINDOW = 5.0      # sum the autocorrelation up to the first lag ≥ SOKAL_WINDOW · τ_int (Sokal 1996)


def integrated_autocorrelation_time(residual: np.ndarray) -> float:
    """τ_int (in samples, ≥ 1) of a residual series in time order: 1 for white residuals, about the
    correlation length for residuals correlated over several samples."""
    x = np.asarray(residual, dtype=np.float64)
    x = x[np.isfinite(x)] - np.mean(x[np.isfinite(x)])
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0
    spec = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[:n]
    rho = acf / acf[0]
    tau = 1.0
    for lag in range(1, n):
        tau += 2.0 * rho[lag]
        if lag >= SOKAL_WINDOW * tau:
            break
    return max(tau, 1.0)


def tilt_heading_std_deg(tilt_sigma_rad: float, vertical_ut: float, total_ut: float) -> float:
    """RMS over heading (deg, 1σ) of the heading error a body-fixed levelling tilt of 1σ `tilt_sigma_rad` per
    axis leaves in the fit: tan(dip)·σ (the rotation ε moves the calibrated horizontal field by H_z·(ε_y, −ε_x))."""
    horizontal = math.sqrt(max(total_ut**2 - vertical_ut**2, 1e-12))
    return math.degrees(abs(vertical_ut) / horizontal * tilt_sigma_rad)


def accel_bias_heading_std_deg(accel_bias_sigma_m_s2: float, vertical_ut: float, total_ut: float) -> float:
    """RMS over heading (deg, 1σ) of the heading error a body-fixed accelerometer bias of 1σ
    `accel_bias_sigma_m_s2` per axis leaves in a fit levelled by that accelerometer: tan(dip)·σ_b/g."""
    horizontal = math.sqrt(max(total_ut**2 - vertical_ut**2, 1e-12))
    return math.degrees(abs(vertical_ut) / horizontal * accel_bias_sigma_m_s2 / STANDARD_GRAVITY_M_S2)


def frame_tilt_sigma_deg(levelling: dict | None) -> float | None:
    """The per-axis 1σ (deg) of the body-fixed tilt a fit's levelling left in the calibration's frame, from its
    predicted heading's `levelling` entry (backstepping._with_levelling_error): the aided levelling's stated tilt,
    or the accelerometer's bias over g when it levelled the fit. None: not known (a given attitude taken as exact,
    another method). ins carries that tilt as two states with this prior (estimator/mag_frame_tilt.py)."""
    if not isinstance(levelling, dict):
        return None
    if "given_tilt_sigma_deg" in levelling:
        value = levelling["given_tilt_sigma_deg"]
    elif "accel_bias_sigma_m_s2" in levelling:
        value = math.degrees(float(levelling["accel_bias_sigma_m_s2"]) / STANDARD_GRAVITY_M_S2)
    else:
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0.0 else None


def frame_tilt_heading_std_deg(levelling: dict | None) -> float | None:
    """The heading error (deg, 1σ, RMS over heading) the fit's predicted heading error holds for that body-fixed
    tilt (`frame_tilt_sigma_deg`): tan(dip)·σ, added in quadrature to its heading-dependent part
    (backstepping._with_levelling_error). It is all once per turn, so ins takes it out of the calibration's
    once-per-turn harmonics when its frame-tilt states carry the tilt (mag_harmonics.prior_variances_rad2). None:
    not known, as `frame_tilt_sigma_deg`."""
    if not isinstance(levelling, dict):
        return None
    value = levelling.get("given_tilt_heading_std_deg", levelling.get("accel_bias_heading_std_deg"))
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0.0 else None


def body_fixed_tilt_sigma_rad(tilt_sigma_rad: np.ndarray) -> float:
    """The per-axis 1σ (rad) of the body-fixed tilt an estimator's levelling leaves, from its per-sample tilt 1σ
    √(σ_roll² + σ_pitch²) (rad; NaN where it had not started): the RMS over the samples, per axis (÷ √2). The
    part that stays fixed in the body is one draw for the whole run, so its σ is not reduced by the number of
    samples; the RMS keeps the filter's start in, where its tilt is least known."""
    s = np.asarray(tilt_sigma_rad, dtype=np.float64)
    s = s[np.isfinite(s)]
    return float(np.sqrt(np.mean(s**2)) / math.sqrt(2.0)) if s.size else math.nan
