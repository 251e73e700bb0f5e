"""The lean of the specific force the gyro did not turn: a speed change, not a rest (compiled, mekf's rest test).

mekf's rest detector (VQF's: gyro and specific force steady, |f| = g) cannot tell a vehicle standing still
from one that speeds up or slows down steadily on a straight leg: a forward acceleration a leans f by a/g about
the body's y axis while |f| changes by only a²/2g and the gyro sees nothing. Declared rest, the levelling
(its small at-rest noise, a high gain) takes that lean as the vertical within seconds, and the speed change's
sum (turn_lean.track_accel_push) adds nothing at rest: a pitch error of a/g under an at-rest σ.

What tells them apart is consistency over time: at rest f keeps its direction in a frame the gyro turns; a real
tilt change comes with a gyro rate that turns the frame with it; a speed change moves f's direction in that
frame while the gyro sees no rotation. The estimated NED frame is such a frame but for the estimate's own
corrections (the levelling pulls it onto f's lean), so those are summed here (`add_correction`, a rotation
vector, first order: the corrections over a reference's age are a few degrees at most) and taken back out: the
rest's reference direction, turned by the corrections since, against f now (`lowpass_f`). The horizontal part of
the difference over g is the lean no rotation explains (`leans_unturned`). The gyro's own drift reads as lean
too, so the limit grows with what it can turn the frame by. While f leans, mekf's levelling corrects only across
the lean (mekf_core._correct_tilt_across): along it f holds the acceleration; the gyro holds the attitude there,
and the rest's bias learning goes on (the gyro reads the bias during a straight-leg speed change). HOLD_S is the
prior on how long a speed change lasts: a steady acceleration held longer is again indistinguishable from a
tilted rest. docs/estimator.md "σ honesty in turns" has the figures and what was tried.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SETTLE_S = 1.0
"""A rest's reference is taken this long after the rest began, s: by then the detector's
low-pass (the rest detector's τ, 0.5 s) has forgotten the motion before the rest (e^(−5) of it with the 1.5 s the
rest detector waits: 0.2° of a turn's 28° lean)."""
TURNING_RAD_S = 0.3 * math.pi / 180.0
"""While the rate about the vertical is above this, rad/s, a rest's reference is taken afresh at every step: up
to 17 m/s such a turn leans f by less than the limit (ω·v/g), and its lean ends with the turn."""
REFRESH_S = 2.0
"""How often a rest's reference direction is taken again while f has not leaned from it, s: a lean must build up
beyond the limit within this to count, as a speed change's onset does in a second or two, while the gyro's drift
(a bias error of 0.1 °/s: 0.2° in 2 s) is followed (a 10 s refresh read an AUV's slow drift as lean)."""
HOLD_S = 12.0
"""How long a reference is held while f leans from it, s: the longest speed change taken as one; a lean held
longer is accepted as the vertical (a tilted rest the gyro missed is then no longer excluded for ever)."""
LEAN_LIMIT_RAD = 0.5 * math.pi / 180.0
"""A lean larger than this is no rest, rad: well above the low-passed specific force's noise and the
accelerometer's drift over a reference's age, well below a/g of a gentle speed change (0.5 m/s²: 2.9°)."""
DRIFT_SIGMAS = 3.0
"""The gyro bias error counted against the limit, in its 1σ (the bias error × the reference's age reads as
lean)."""

UNTURNED_LEAN_DTYPE = np.dtype([
    ("f_m_s2", np.float64, (3,)),           # the specific force in the estimated NED frame, low-passed (rest's τ)
    ("turned_rad", np.float64, (3,)),       # the estimate's corrections summed (NED rotation vector)
    ("ref_f_m_s2", np.float64, (3,)),       # f_m_s2 when the reference was taken
    ("ref_turned_rad", np.float64, (3,)),   # turned_rad then
    ("ref_bias_rad_s", np.float64, (3,)),   # the gyro bias estimate then (body)
    ("ref_age_s", np.float64),              # the reference's age
    ("rest_s", np.float64),                 # how long the filter has been at rest
])


@njit(cache=True, inline="always")
def add_correction(lean, dx0, dx1, dx2):
    """The estimate was turned by the NED rotation vector (dx0, dx1, dx2) (mekf_core._apply_correction)."""
    t = lean.turned_rad
    t[0] += dx0
    t[1] += dx1
    t[2] += dx2


@njit(cache=True, inline="always")
def lowpass_f(lean, k, fn, fe, fd):
    """The specific force rotated into the estimated NED frame, low-passed with weight k (the rest detector's:
    short, so a rest's reference holds little of the motion before it). Not turned with the estimate's
    corrections as the levelling's low-pass is: at rest they are hundredths of a degree per second, and the
    low-pass lags them by its τ only."""
    f = lean.f_m_s2
    f[0] += k * (fn - f[0])
    f[1] += k * (fe - f[1])
    f[2] += k * (fd - f[2])


@njit(cache=True, inline="always")
def _take_reference(lean, bias_rad_s):
    for i in range(3):
        lean.ref_f_m_s2[i] = lean.f_m_s2[i]
        lean.ref_turned_rad[i] = lean.turned_rad[i]
        lean.ref_bias_rad_s[i] = bias_rad_s[i]
    lean.ref_age_s = 0.0


@njit(cache=True, inline="always")
def leans_unturned(lean, at_rest, dt, g_m_s2, bias_rad_s, bias_var_rad2_s2, rate_down_rad_s):
    """Whether, at rest, the low-passed specific force (`lowpass_f`) leans by more than the limit from the rest's
    reference direction, the estimate's corrections since it was taken (`add_correction`) taken back out: the
    reference r turned into the frame of now by them, Δ, is r + Δ × r (mekf_core._apply_correction's rotation of
    the levelling's low-pass), and the lean is the horizontal part of f − (r + Δ × r) over g.
    The limit: LEAN_LIMIT_RAD and, times the reference's age, what the gyro's drift can turn the frame by:
    DRIFT_SIGMAS × the bias 1σ (bias_var_rad2_s2: its largest variance) and the change of the bias estimate
    since the reference (bias_rad_s: b̂; a bias rest is still learning, or the start of a motion rest learnt as
    bias), in quadrature.
    The reference is taken SETTLE_S into a rest and again at every step of it while the vehicle may still be
    turning (the rest detector lets rates below its bias clip pass; while `rate_down_rad_s`, the low-passed rate
    about the vertical, is above TURNING_RAD_S the turn's centripetal lean is in f, and it ends with the turn),
    again every REFRESH_S while f keeps to it, and held while f leans from it for up to HOLD_S.
    Returns (leaning, the lean's north and east parts over g: rad)."""
    if not at_rest:
        lean.rest_s = 0.0
        return False, 0.0, 0.0
    lean.rest_s += dt
    if lean.rest_s <= SETTLE_S or abs(rate_down_rad_s) > TURNING_RAD_S:
        _take_reference(lean, bias_rad_s)
        return False, 0.0, 0.0
    lean.ref_age_s += dt
    age_s = lean.ref_age_s
    f = lean.f_m_s2
    r = lean.ref_f_m_s2
    rt = lean.ref_turned_rad
    t = lean.turned_rad
    d0 = t[0] - rt[0]
    d1 = t[1] - rt[1]
    d2 = t[2] - rt[2]
    hn = f[0] - r[0] - (d1 * r[2] - d2 * r[1])
    he = f[1] - r[1] - (d2 * r[0] - d0 * r[2])
    hn /= g_m_s2
    he /= g_m_s2
    h2 = hn * hn + he * he
    rb = lean.ref_bias_rad_s
    moved2 = (bias_rad_s[0] - rb[0]) ** 2 + (bias_rad_s[1] - rb[1]) ** 2 + (bias_rad_s[2] - rb[2]) ** 2
    drift2 = (DRIFT_SIGMAS * DRIFT_SIGMAS * bias_var_rad2_s2 + moved2) * age_s * age_s
    if h2 > LEAN_LIMIT_RAD * LEAN_LIMIT_RAD + drift2:
        if age_s < HOLD_S:
            return True, hn, he
        _take_reference(lean, bias_rad_s)
    elif age_s >= REFRESH_S:
        _take_reference(lean, bias_rad_s)
    return False, 0.0, 0.0
