"""The tuning of the magnetometer heading measurement and its disturbance rejection (mag_heading.py), one set of
fields and defaults for both filters: `MekfParams` and `InsParams` inherit them (mag_heading.heading_params reads
them into the kernels' MAG_HEADING_PARAMS_DTYPE record). SI units; angles in rad."""

from __future__ import annotations

import math
from dataclasses import dataclass

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class MagHeadingParams:
    mag_noise_ut: float = 0.7
    """Magnetometer noise per axis, µT (BROAD rest data: 0.7 µT; ADIS16405 datasheet 1.25 mgauss = 0.125 µT)."""
    mag_heading_noise_rad: float = 0.12
    """Heading noise floor in motion (residual hard/soft iron, field gradients over the work space, dynamic
    errors: BROAD's field direction varies by ±4–8° in fast rotation even with the true attitude), rad."""
    mag_heading_noise_rest_rad: float = 0.03
    """Heading noise floor at rest, rad: no dynamic errors (sensor timing skew, lag) while nothing moves."""
    mag_norm_tol: float = 0.1
    """Field magnitude must be within this fraction of the reference (VQF magNormTh)."""
    mag_dip_tol_rad: float = 15.0 * _DEG
    """Dip angle must be within this of the reference. VQF uses 10°; the dip seen in fast rotation varies by
    ±10° even with the true attitude (BROAD trial 06), so 15°."""
    mag_min_undisturbed_s: float = 0.5
    """The field must match the reference this long before it is used again (VQF magMinUndisturbedTime)."""
    mag_new_time_s: float = 20.0
    """A consistent new field is adopted after this much rotation time (VQF magNewTime)."""
    mag_new_min_rate_rad_s: float = 20.0 * _DEG
    """Only rotation faster than this counts towards mag_new_time_s (VQF magNewMinGyr)."""
    mag_ref_tau_s: float = 20.0
    """Time constant with which the reference magnitude/dip follow an accepted field, s."""
    mag_gate_sigma: float = 6.0
    """Innovation gate for the heading update, in σ (the gate widens as the heading uncertainty grows)."""
    mag_reject_max_s: float = 60.0
    """After this long continuously disturbed the field is used again with 100× the noise (VQF
    magMaxRejectionTime)."""
    mag_unavailable_s: float = 10.0
    """No heading update for this long sets MAG_UNAVAILABLE, s."""
    mag_field_circle_check: bool = True
    """Without GNSS, check the calibration by the circle the levelled field sweeps in turns and add the heading
    error an off-centre or elliptic circle implies to the published σ (field_circle.py); False: not checked."""
