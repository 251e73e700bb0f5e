"""The accelerometer bias a calibration leaves (1σ per axis, m/s²): what the aided levelling of `ahrsd calibrate
mag --gnss` takes as its bias prior and what mekf's published tilt σ carries (MekfParams.accel_bias_sigma_m_s2),
told by the daemon (at start and after every calibration change) and by `ahrsd replay --calibration`.

One rule: an accelerometer calibration in force (a model other than the identity) leaves ACCEL_BIAS_SIGMA_CALIBRATED_M_S2;
none leaves what the estimator assumes by default for the chip's own factory calibration (None here).
"""

from __future__ import annotations

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

from .models import AccelModel

ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 = 2e-3 * STANDARD_GRAVITY_M_S2   # residual accelerometer bias 1σ with a bench
    # calibration in force: the fit's own uncertainty (its quality.sigma_bias_m_s2), the ADIS16405's 0.2 mg
    # in-run instability, and a margin for the change between the bench power-up and the run's, which the data
    # sheet does not give


def calibration_accel_bias_sigma_m_s2(calibration) -> float | None:
    """The residual accelerometer bias 1σ (m/s²) with `calibration` in force; None when it holds no accelerometer
    calibration (the estimator's default for the uncalibrated chip then applies)."""
    if calibration is None or calibration.accel == AccelModel.identity():
        return None
    return ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
