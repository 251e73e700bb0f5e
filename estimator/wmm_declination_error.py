"""The World Magnetic Model's own declination error: how far the true field's azimuth may be from WMM's.

The filter takes the Earth field from WMM2025 (core/wmm.py); the real field differs from it by the crustal field
WMM leaves out (degree > 12), the external fields and the secular variation's drift. NOAA/BGS state that error
globally as a 1σ per element; the declination's grows as the horizontal intensity H falls (the same field error
turns a weak horizontal field further):

    σ_D = sqrt(0.26² + (5417 nT / H)²)  degrees                         (H in nT)

(The US/UK World Magnetic Model for 2025-2030, Technical Report, section "Uncertainty estimates", the error model
of WMM2025; WMM2020's was 0.26° and 5625 nT.) 0.375° at H = 20 µT, 0.601° at 10 µT.

The error is fixed to north, the same at every heading while the vehicle stays in one region: in a calibrated
magnetometer's heading it is a constant offset, the north-fixed harmonic state c0 (mag_harmonics.py), which the
GNSS can learn on a manoeuvring vehicle, not white noise
(docs/estimator.md "WMM's declination error as the calibration's offset").
"""

from __future__ import annotations

import math

DECLINATION_SIGMA_FLOOR_DEG = 0.26
"""WMM2025's declination 1σ that does not depend on H, degrees (technical report, error model)."""

DECLINATION_SIGMA_H_NT_DEG = 5417.0
"""WMM2025's declination 1σ term inverse in H: this over H (nT), degrees (technical report, error model)."""


def wmm_declination_sigma_rad(horizontal_ut: float) -> float:
    """WMM2025's declination 1σ at a horizontal intensity of `horizontal_ut` µT, rad (module docstring); at a
    horizontal field of zero (a magnetic pole) every declination is possible: π."""
    h_nt = float(horizontal_ut) * 1000.0
    if not h_nt > 0.0:
        return math.pi
    sigma_deg = math.hypot(DECLINATION_SIGMA_FLOOR_DEG, DECLINATION_SIGMA_H_NT_DEG / h_nt)
    return min(math.pi, math.radians(sigma_deg))
