"""The magnetometer heading measurement with its disturbance rejection, shared by `mekf` and `ins` (numba).

Given the field already rotated into the estimated NED frame, decides whether it is undisturbed and, if so,
returns the heading innovation and its noise; the caller applies the update to its own error state (the
heading component only, gain on tilt forced to zero). The field is checked against a learned reference
(magnitude, dip), rejected while it differs, and a consistently changed field is adopted after enough
rotation (VQF's magnetic disturbance rejection: D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information Fusion 91, 2023, §IV-D);
after too long a rejection the field is used again with 100× the noise; an innovation gate in σ guards the
rest.

The state it keeps is a MAG_HEADING_STATE_DTYPE record inside each filter's state record, its parameters a
MAG_HEADING_PARAMS_DTYPE record inside each filter's parameter record, so both filters run the same code on
their own state.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MAG_HEADING_STATE_DTYPE = np.dtype([
    ("ref_norm_ut", np.float64),        # reference field magnitude (0 = learn from the next sample)
    ("ref_dip_rad", np.float64),        # reference dip (inclination, positive down)
    ("cand_norm_ut", np.float64),       # candidate new field magnitude
    ("cand_dip_rad", np.float64),       # candidate new field dip
    ("cand_t_s", np.float64),           # time the candidate has been consistent while rotating
    ("undisturbed_t_s", np.float64),    # time the field has matched the reference
    ("since_update_s", np.float64),     # time since the last accepted heading update
    ("disturbed_t_s", np.float64),      # time the field has been continuously disturbed
    ("gate_open_s", np.float64),        # the innovation gate stays open this much longer (new calibration)
    ("ref_weight", np.float64),         # 1 − exp(−Δt/ref_tau_s) for the Δt and τ below (_reference_weight)
    ("ref_weight_dt_s", np.float64),
    ("ref_weight_tau_s", np.float64),
])

MAG_HEADING_PARAMS_DTYPE = np.dtype([
    ("noise_ut", np.float64),                 # magnetometer noise per axis
    ("heading_noise_rad", np.float64),        # heading noise floor in motion
    ("heading_noise_rest_rad", np.float64),   # heading noise floor at rest
    ("norm_tol", np.float64),                 # relative field-magnitude tolerance against the reference
    ("dip_tol_rad", np.float64),              # dip tolerance against the reference
    ("min_undisturbed_s", np.float64),        # the field must match this long before it is used
    ("new_time_s", np.float64),               # a consistent new field is adopted after this much rotation time
    ("new_min_rate_rad_s", np.float64),       # rotation counts towards new_time_s only above this rate
    ("ref_tau_s", np.float64),                # time constant of the reference's tracking
    ("gate_sigma", np.float64),               # innovation gate, σ
    ("unavailable_s", np.float64),            # no heading update for this long → MAG_UNAVAILABLE
    ("reject_max_s", np.float64),             # after this long continuously disturbed: the field with 100× the noise
])


def heading_params(params) -> np.ndarray:
    """A MAG_HEADING_PARAMS_DTYPE record (0-d array) from a filter's parameters (`MekfParams`, `InsParams`:
    the fields mag_noise_ut, mag_heading_noise_rad, … of the same names)."""
    rec = np.zeros((), MAG_HEADING_PARAMS_DTYPE)
    rec["noise_ut"] = params.mag_noise_ut
    rec["heading_noise_rad"] = params.mag_heading_noise_rad
    rec["heading_noise_rest_rad"] = params.mag_heading_noise_rest_rad
    rec["norm_tol"] = params.mag_norm_tol
    rec["dip_tol_rad"] = params.mag_dip_tol_rad
    rec["min_undisturbed_s"] = params.mag_min_undisturbed_s
    rec["new_time_s"] = params.mag_new_time_s
    rec["new_min_rate_rad_s"] = params.mag_new_min_rate_rad_s
    rec["ref_tau_s"] = params.mag_ref_tau_s
    rec["gate_sigma"] = params.mag_gate_sigma
    rec["unavailable_s"] = params.mag_unavailable_s
    rec["reject_max_s"] = params.mag_reject_max_s
    return rec


# result of heading_measurement
MAG_NONE = 0       # no usable field (zero magnitude): nothing to do, no flag
MAG_REJECTED = 1   # disturbed or gated out: flag MAG_REJECTED
MAG_USE = 2        # apply the update with the returned innovation and variance

_TWO_PI = 2.0 * math.pi

# after a calibration change the heading gate stays open this long: the undisturbed wait (0.5 s) plus the
# filter's heading convergence (time constant ≈ 1 s at the default tuning) with a wide margin
RELEARN_GATE_OPEN_S = 10.0


@njit(cache=True)
def _reference_weight(ms, mp, dt):
    """The reference's and the candidate's low-pass weight 1 − exp(−Δt/ref_tau_s), kept for the last Δt and τ
    (a filter's Δt rarely changes: no exp per sample)."""
    if ms.ref_weight_dt_s != dt or ms.ref_weight_tau_s != mp.ref_tau_s:
        ms.ref_weight_dt_s = dt
        ms.ref_weight_tau_s = mp.ref_tau_s
        ms.ref_weight = 1.0 - math.exp(-dt / mp.ref_tau_s)
    return ms.ref_weight


@njit(cache=True, inline="always")
def _track_field(ms, mp, dt, rate, mnorm, dip):
    """Compare the field (magnitude mnorm, dip) with the learned reference and keep the undisturbed and
    disturbed times; the first field sets the reference. A field that differs but stays consistent while the
    body rotates (the candidate) for new_time_s has changed for good (a new place, new iron) and is adopted.
    Returns whether the field matches the reference (after an adoption it does)."""
    if ms.ref_norm_ut <= 0.0:
        ms.ref_norm_ut = mnorm
        ms.ref_dip_rad = dip
        ms.cand_norm_ut = mnorm
        ms.cand_dip_rad = dip
    ref_norm = ms.ref_norm_ut
    tol = mp.norm_tol
    dtol = mp.dip_tol_rad
    matches = abs(mnorm - ref_norm) < tol * ref_norm and abs(dip - ms.ref_dip_rad) < dtol
    if matches:
        ms.undisturbed_t_s += dt
        ms.disturbed_t_s = 0.0
    else:
        ms.undisturbed_t_s = 0.0
        ms.disturbed_t_s += dt
    cn = ms.cand_norm_ut
    if abs(mnorm - cn) < tol * cn and abs(dip - ms.cand_dip_rad) < dtol:
        kc = _reference_weight(ms, mp, dt) if dt > 0.0 else 0.0
        ms.cand_norm_ut += kc * (mnorm - cn)
        ms.cand_dip_rad += kc * (dip - ms.cand_dip_rad)
        if rate > mp.new_min_rate_rad_s:
            ms.cand_t_s += dt
    else:
        ms.cand_norm_ut = mnorm
        ms.cand_dip_rad = dip
        ms.cand_t_s = 0.0
    if (not matches) and ms.cand_t_s >= mp.new_time_s:
        ms.ref_norm_ut = ms.cand_norm_ut
        ms.ref_dip_rad = ms.cand_dip_rad
        ms.undisturbed_t_s = mp.min_undisturbed_s
        ms.disturbed_t_s = 0.0
        matches = True
    return matches


@njit(cache=True, inline="always")
def _heading_innovation(ms, mp, at_rest, mn, me, mh, declination, heading_var, inflate):
    """The heading measurement α = −δθ_D, the angle of the horizontal field (mn, me; magnitude mh) in the
    estimated NED frame minus `declination`, wrapped to ±π, and its variance (the field noise over mh plus the
    heading noise floor, times `inflate`); rejected beyond the innovation gate unless inflated or the gate is
    held open after a calibration change (relearn_reference). Returns (MAG_*, α, variance)."""
    alpha = math.atan2(me, mn) - declination
    if alpha > math.pi:
        alpha -= _TWO_PI
    elif alpha < -math.pi:
        alpha += _TWO_PI
    sig_a = mp.noise_ut / mh
    floor = mp.heading_noise_rest_rad if at_rest else mp.heading_noise_rad
    r = (sig_a * sig_a + floor * floor) * inflate
    s = heading_var + r
    gate_open = ms.gate_open_s > 0.0
    if alpha * alpha > mp.gate_sigma ** 2 * s and inflate == 1.0 and not gate_open:
        return MAG_REJECTED, 0.0, 0.0
    return MAG_USE, alpha, r


@njit(cache=True)
def heading_measurement(ms, mp, dt, rate, at_rest, moved_at_rest, mn, me, md, mnorm,
                        declination, heading_var):
    """Check one field sample (mn, me, md: the field in the estimated NED frame, µT; mnorm its magnitude) and
    form the heading measurement. Returns (MAG_*, innovation rad, variance rad²).

    The innovation is the angle of the horizontal field in the estimated frame minus `declination` (0 for a
    filter whose frame is magnetic north), i.e. −δθ_D: the caller applies it with the row h = −e_D.
    rate: bias-corrected angular rate magnitude (rad/s); at_rest / moved_at_rest: from the caller's rest
    detector (a field that moves at rest is a disturbance); heading_var: the filter's heading variance (rad²)
    for the innovation gate. The field is checked against the learned reference (`_track_field`), used once
    it has matched for min_undisturbed_s (or, disturbed for longer than reject_max_s, with its variance
    inflated a hundredfold), and then measures the heading (`_heading_innovation`)."""
    if mnorm <= 1e-6:
        return MAG_NONE, 0.0, 0.0
    mh = math.sqrt(mn * mn + me * me)
    dip = math.atan2(md, mh)
    matches = _track_field(ms, mp, dt, rate, mnorm, dip)
    undisturbed = matches and ms.undisturbed_t_s >= mp.min_undisturbed_s and not moved_at_rest
    inflate = 1.0
    if not undisturbed and ms.disturbed_t_s > mp.reject_max_s:
        undisturbed = True  # disturbed for too long: use it, but trust it little
        inflate = 100.0
    if not (undisturbed and mh > 1e-3 * mnorm):
        return MAG_REJECTED, 0.0, 0.0
    if matches and dt > 0.0:
        kr = _reference_weight(ms, mp, dt)
        ms.ref_norm_ut += kr * (mnorm - ms.ref_norm_ut)
        ms.ref_dip_rad += kr * (dip - ms.ref_dip_rad)
    return _heading_innovation(ms, mp, at_rest, mn, me, mh, declination, heading_var, inflate)


@njit(cache=True)
def heading_bookkeeping(ms, mp, dt, used):
    """After the step: count down the open gate, time since the last heading update. Returns True when the
    heading has gone without an update for longer than mp.unavailable_s (flag MAG_UNAVAILABLE)."""
    if ms.gate_open_s > 0.0:
        ms.gate_open_s = max(0.0, ms.gate_open_s - dt)
    if used:
        ms.since_update_s = 0.0
        return False
    ms.since_update_s += dt
    return ms.since_update_s > mp.unavailable_s


def relearn_reference(ms, gate_open_s: float) -> None:
    """Forget the learned field reference of the MAG_HEADING_STATE_DTYPE record `ms` (the next sample sets it
    again) and open the innovation gate for `gate_open_s` (a new magnetometer calibration may move the heading
    by more than the gate)."""
    for name in ("ref_norm_ut", "ref_dip_rad", "cand_norm_ut", "cand_dip_rad", "cand_t_s", "undisturbed_t_s",
                 "disturbed_t_s"):
        ms[name] = 0.0
    ms["gate_open_s"] = gate_open_s


def widen_after_calibration_change(P, heading_index: int, bias_index: int, down_body, heading_change_rad: float,
                                   bias_sigma_rad_s: float) -> None:
    """After a magnetometer calibration change that moves the heading by `heading_change_rad` (the new
    calibration's heading minus the old one's on the current sample; NaN: not known, 0: the magnetometer model
    did not change — then nothing is done), widen in place what the filter learned from the old calibration's
    heading, in its error covariance `P`:

    * the heading (row/column `heading_index`): it may now be off by the change, an error independent of every
      other state's, so its variance is raised to at least the change squared. The σ then covers the heading
      error while it converges, and the Kalman gain takes the new heading at once instead of over seconds.
    * the gyro bias about the vertical (body-frame block at `bias_index`, `down_body` the unit down vector in the
      body frame), when the change is beyond the heading's 3σ (the old heading was wrong by more than the filter
      knew): only the heading observes that bias, so a calibration that made the heading wrong as the vehicle
      turned taught it a wrong bias too (a heading error that changes with the heading looks like a rate bias
      while turning). Its variance along down is raised to at least `bias_sigma_rad_s`² (the filter's initial
      bias uncertainty: what it knew before any heading), so the new heading re-learns it.

    Both add a positive semi-definite term (a raised diagonal element, a rank-one u·uᵀ), so P stays positive
    semi-definite; the cross-covariances are kept."""
    change = float(heading_change_rad)
    if not math.isfinite(change) or change == 0.0:
        return
    heading_var = float(P[heading_index, heading_index])
    P[heading_index, heading_index] = max(heading_var, change * change)
    if change * change <= 9.0 * heading_var:
        return
    u = np.asarray(down_body, dtype=np.float64)
    b = slice(bias_index, bias_index + 3)
    var_down = float(u @ P[b, b] @ u)
    missing = bias_sigma_rad_s * bias_sigma_rad_s - var_down
    if missing > 0.0:
        P[b, b] += missing * np.outer(u, u)
