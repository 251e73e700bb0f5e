"""Kalman-filter noise tuning from the noise terms an Allan analysis found (in the form the
ADIS16405 AHRS thesis tunes its filter with).

Q (6, rad²/s, continuous-time densities) = diag((3·N_i)², (3·w_b,i)²): the gyro white noise N (ARW) and the
bias-driving noise w_b, both inflated ×3 because the axes' noises are correlated but Q is kept diagonal
(the thesis's rule). w_b comes from the bias terms that were seen, as the density of a random-walk bias
ḃ = w_b (variances add when several are seen):
  - rate random walk K: w_b = K (IEEE Std 952 C.4: the RRW is exactly a random walk of the rate);
  - first-order Gauss–Markov σ, Tc: w_b = σ·√(2/Tc), the driving density of ḃ = −b/Tc + w (IEEE Std 952 C.6),
    with Tc reported for a filter that models the Markov state;
  - flicker B read at τ_B: the random walk whose Allan deviation equals the floor 0.664·B at τ_B:
    w_b = 0.664·B·√(3/τ_B) (a random walk is the usual finite-state stand-in for 1/f noise).
With none seen, the thesis's rule w_b = N/10 is used and listed as assumed; a white noise that was not
seen is taken from the datasheet below and listed as assumed.
R (6) = diag(σ_mag², σ_accel²) from the output standard deviations.
"""

from __future__ import annotations

import math

from .terms import FLICKER_FACTOR

Q_INFLATION = 3.0          # the thesis's rule: diagonal Q inflated ×3 for correlated axes
BIAS_DRIVE_FRACTION = 0.1  # the thesis's rule: bias-driving noise = ARW/10 (used only when no bias term is seen)
AXES = ("x", "y", "z")

# Analog Devices ADIS16405 data sheet (Rev. B), Table 1: used only where the recording did not show the term.
DEG = math.pi / 180.0
DATASHEET = {
    "gyro_white_noise": (2.0 / 60.0 * DEG, "ADIS16405 data sheet angle random walk 2 °/√h"),
    "gyro_bias_instability": (0.007 * DEG, "ADIS16405 data sheet in-run bias stability 0.007 °/s"),
    "accel_white_noise": (0.2 / 60.0, "ADIS16405 data sheet velocity random walk 0.2 m/s/√h"),
}


def bias_drive(p) -> tuple[float | None, list[str]]:
    """(w_b in u/√s, which terms it came from) for one axis' NoiseParameters; (None, []) when none was seen."""
    var, sources = 0.0, []
    if p.rate_random_walk is not None:
        var += p.rate_random_walk**2
        sources.append("rate random walk K")
    if p.gauss_markov_sigma is not None and p.gauss_markov_tau_s:
        var += 2.0 * p.gauss_markov_sigma**2 / p.gauss_markov_tau_s
        sources.append("Gauss–Markov σ·√(2/Tc)")
    if p.bias_instability is not None and p.tau_bias_instability_s:
        var += 3.0 * (FLICKER_FACTOR * p.bias_instability) ** 2 / p.tau_bias_instability_s
        sources.append("flicker 0.664·B·√(3/τ_B)")
    return (math.sqrt(var), sources) if sources else (None, [])


def kalman_tuning(result) -> dict:
    """The thesis's Kalman Q and R (form above) from an AllanResult, saying what was assumed."""
    out: dict = {"source": "Q = diag((3·N)², (3·w_b)²), R = diag(σ²); terms from the Allan analysis", "assumed": []}
    gyro = result.parameters.get("gyro")
    if gyro:
        arw, drive, drive_src, corr = [], [], [], []
        for ax in AXES:
            p = gyro[ax]
            n = p.white_noise
            if n is None:
                n, why = DATASHEET["gyro_white_noise"]
                out["assumed"].append({"key": f"gyro_arw_rad_sqrt_s.{ax}", "value": n,
                                       "source": f"{why} (no white noise seen)"})
            w, src = bias_drive(p)
            if w is None:
                w = BIAS_DRIVE_FRACTION * n
                out["assumed"].append({"key": f"gyro_bias_drive_rad_s_sqrt_s.{ax}", "value": w,
                                       "source": "rule w_b = ARW/10 (no bias term seen)"})
                src = ["assumed: ARW/10"]
            if p.bias_instability is None:
                value, why = DATASHEET["gyro_bias_instability"]
                out["assumed"].append({"key": f"gyro_bias_instability_rad_s.{ax}", "value": value,
                                       "source": f"{why} (no flicker floor seen)"})
            arw.append(n)
            drive.append(w)
            drive_src.append(" + ".join(src))
            corr.append(p.gauss_markov_tau_s)
        out["gyro_arw_rad_sqrt_s"] = arw
        out["gyro_bias_drive_rad_s_sqrt_s"] = drive
        out["gyro_bias_drive_from"] = drive_src
        out["gyro_bias_corr_time_s"] = corr
        out["Q_diag"] = [(Q_INFLATION * v) ** 2 for v in arw] + [(Q_INFLATION * v) ** 2 for v in drive]
        out["Q_units"] = "rad^2/s"
        out["gyro_bias_instability_rad_s"] = [gyro[ax].bias_instability for ax in AXES]
    mag, acc = result.parameters.get("mag"), result.parameters.get("accel")
    if mag and acc:
        out["R_diag"] = [mag[ax].std**2 for ax in AXES] + [acc[ax].std**2 for ax in AXES]
        out["R_units"] = ["uT^2"] * 3 + ["(m/s^2)^2"] * 3
    if acc:
        vrw = []
        for ax in AXES:
            n = acc[ax].white_noise
            if n is None:
                n, why = DATASHEET["accel_white_noise"]
                out["assumed"].append({"key": f"accel_vrw_m_s2_sqrt_hz.{ax}", "value": n,
                                       "source": f"{why} (no white noise seen)"})
            vrw.append(n)
        out["accel_vrw_m_s2_sqrt_hz"] = vrw
    if mag:
        out["mag_white_noise_ut_sqrt_hz"] = [mag[ax].white_noise for ax in AXES]
    return out
