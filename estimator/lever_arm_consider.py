"""How uncertain the antenna arm the filter fuses with is: the covariance P_r (body FRD, m²) of its error, which the
GNSS fusion adds to the fixes' noise as a consider parameter (ins_core.py `_arm_consider`: R_v += C[ω×] P_r [ω×]ᵀCᵀ,
R_p += C P_r Cᵀ; Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems, 2nd ed.,
§14.2.1). Without it the fusion takes the arm as exact, and an antenna a metre or two from where the filter was told
bends the heading by more than its σ says (docs/gnss.md "The arm's own uncertainty in the fusion").

P_r is `lever_arm_sigma_m` per axis: the told arm's σ (a tape measure's: a few centimetres), or for an arm not
told (left at (0, 0, 0)) how far the antenna may be from the IMU (2 m, the lever-arm check's prior PRIOR_SIGMA_M,
is what the figures in docs/gnss.md were measured with). NaN, the default: the arm fused as exact; a finite σ
changes every GNSS-aided run's output, and docs/gnss.md says which figures were measured with which.

The arm's error is one constant; what it makes of a fix, C [ω×] δr, changes only as the vehicle's rotation does. Taken
as white noise at every fix it would average away over a turn's fixes, which it does not: the fusion takes it as one
error per ARM_TERM_CORRELATION_S, its variance times that span over the fix interval (ins_core `_arm_consider`;
time-correlated measurement noise, Groves §3.4.3), so the fixes' rate does not change what the arm's error is
worth."""

from __future__ import annotations

import math

import numpy as np

ARM_TERM_CORRELATION_S = 1.0   # the span over which the arm's velocity term stays one error: a vehicle's rotation
                       # rate changes over about a second (a car's steering into and out of a turn, a plane's roll into
                       # a bank, a boat's roll rate a quarter of its 4–8 s period)


def arm_covariance_m2(lever_arm_sigma_m: float) -> np.ndarray:
    """P_r: `lever_arm_sigma_m` on every axis; none (zeros: the arm fused as exact) when it is NaN."""
    if not math.isfinite(lever_arm_sigma_m):
        return np.zeros((3, 3))
    return lever_arm_sigma_m ** 2 * np.eye(3)
