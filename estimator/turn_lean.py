"""The lean a turn leaves in an accelerometer-levelled attitude: the published 1σ's terms for it (compiled).

A vehicle turning at ω_D about the vertical with speed v feels the centripetal acceleration ω_D·v, horizontal:
the apparent vertical leans by φ = atan(ω_D v / g) while |f| stays within (ω_D v)²/(2g) of g (0.005 m/s² for a
boat at 9 °/s and 2 m/s), below what any norm check can see, and a filter that levels with the accelerometer
cannot tell it from a tilt. Without a velocity v is unknown: a plausible turning speed stands for it (the
filters' `turn_speed_m_s`), and mekf reads a faster vehicle's speed from its turns (`track_turn_speed`: the
force across the heading over the turn rate). Through the field's dip I that tilt error becomes a heading error of the
magnetometer (`track_heading_push`). Neither error is white noise, so neither is in the filter's covariance:
both are tracked here beside it and added to the published 1σ in quadrature (Schmidt's "consider" terms).

A vehicle that speeds up or brakes leans the apparent vertical along its track the same way, by a/g, and no
gyro shows it: `track_accel_push` sums the levelling's own corrections, which add up to the lean it has taken
whatever the acceleration was (its docstring), and the sum enters the tilt (and, through the dip, the heading)
push in quadrature. mekf only: it learns its gyro bias from the levelling, so its corrections average to
nothing once the lean is gone; ins levels tilt only (its biases get no gain from the accelerometer), and on a
turning vehicle its levelling holds off the horizontal gyro bias at a rate that turns with the heading, and the
sum would count that as lean (docs/estimator.md "Known limits").

One rule for both filters that level with the accelerometer: mekf (always) and ins (while no GNSS velocity
aids it: with GNSS the lean is observed and corrected). Each filter keeps a TURN_LEAN_DTYPE record in its state
and calls, in its own stages:
  `lowpass_rate_down`    the rate about the vertical, low-passed as the levelling's specific force is
  `track_turn_speed`     beside it (mekf): the speed the turns show (`turn_speed_m_s`: it or the prior)
  `levelling_gain`       k = P/(P + R) of a levelling update, once per axis for the two pushes below
  `track_tilt_push`      at each accepted levelling update
  `track_accel_push`     at each accepted levelling update (mekf)
  `track_bias_learning`  once per step, after its updates (mekf): the sum less what the bias learning explains
                         (`prior_share`: the part of a bias change that learns the bias's prior)
  `track_heading_push`   at each magnetometer heading update
  `track_lean_bias_drift` once per step, after its updates (mekf): the drift of the gyro bias learnt from motion
                         (a lean's levelling, a rest declared into a motion's start) while no levelling corrects it
  `bound_pushes`         after a stretch that did not track (mekf's batch): an upper bound of what tracking
                         would have left (the speed change's sum is tracked on mekf's batch too: it has
                         no target to bound)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

TURN_LEAN_DTYPE = np.dtype([
    ("rate_down_lp_rad_s", np.float64),   # rate about the vertical, low-passed as the specific force is
    ("tilt_push_rad", np.float64),        # tilt error a sustained push has left in the estimate
    ("heading_push_rad", np.float64),     # heading error that tilt error leaves through the dip
    ("accel_push_n_rad", np.float64),     # tilt (about north, east) the levelling took from the specific force's
    ("accel_push_e_rad", np.float64),     # horizontal part, forgotten over ACCEL_PUSH_MEMORY_S (`track_accel_push`)
    ("bias_tilt_n_s", np.float64, (3,)),  # tilt about north (rad) a body-frame gyro bias error of 1 rad/s turns
    ("bias_tilt_e_s", np.float64, (3,)),  # the estimate by, over the same memory (`track_bias_learning`); east
    ("lean_bias_rad_s", np.float64, (3,)),  # the gyro bias (body) the summed levelling taught, over the same
                                            # memory (`track_lean_bias_drift`)
    ("lean_drift_n_rad", np.float64),     # tilt (about north, east) that bias turned the estimate by while no
    ("lean_drift_e_rad", np.float64),     # levelling corrected it, forgotten with the sum (`track_lean_bias_drift`)
    ("rest_bias_recent_rad_s", np.float64, (3,)),  # the bias learnt at rest over the rest detector's lag
    ("was_at_rest", np.float64),          # 1 while the previous step was at rest
    ("lateral_lp_m_s2", np.float64),      # specific force across the heading (to the right), low-passed as ω_D
    ("speed_moment_m_s", np.float64),     # Σ lateral·ω_D·dt and Σ ω_D²·dt (rad²/s), forgotten over
    ("speed_weight_rad2_s", np.float64),  # TURN_SPEED_MEMORY_S: the turn speed's regression (`track_turn_speed`)
])
ACCEL_PUSH_MEMORY_S = 30.0
"""How long `track_accel_push` remembers the levelling's corrections, s: the longest sustained speed change whose
lean it covers, and the span over which the gyro errors the levelling corrects add up as if they were lean."""


@njit(cache=True, inline="always")
def lowpass_rate_down(u, k, rate_down_rad_s):
    """The rate about the vertical (the third row of C_b^n times the bias-corrected rate) low-passed with the
    weight `k` of the levelling's specific-force low-pass: the levelled vertical sees the turn through it."""
    u.rate_down_lp_rad_s += k * (rate_down_rad_s - u.rate_down_lp_rad_s)


TURN_SPEED_MEMORY_S = 60.0
"""How long `track_turn_speed` remembers the turns it saw, s: a turn's onset (small ω_D, little evidence of its
own) uses the speed the turns of the last minute showed."""
TURN_SPEED_EVIDENCE_RAD2_S = (2.0 * math.pi / 180.0) ** 2
"""Σ ω_D²·dt (rad²/s) below which the turns seen tell no speed and the prior `turn_speed_m_s` stands alone: a
second of turning at 2 °/s, where a tilt error of 0.5° (g·ε = 0.09 m/s² across the heading) reads as 2.5 m/s."""


@njit(cache=True, inline="always")
def track_turn_speed(u, k, dt, fn, fe, xn, xe):
    """The vehicle's speed as its turns show it. In a turn at ω_D about the vertical a vehicle moving along its
    heading at v feels the centripetal acceleration ω_D·v across its heading (to the right for ω_D > 0, NED), and
    nothing else leans the specific force in step with the turn rate: the lateral specific force, low-passed with
    the weight k of the rate about the vertical (`lowpass_rate_down`, so the two lag alike), is regressed on it
    through the origin, v = Σ a ω dt / Σ ω² dt (forgotten over TURN_SPEED_MEMORY_S). A speed change (along the
    heading) does not enter it; a tilt error or a sway that does not turn with ω_D averages out of the
    numerator; the share of the lean the levelling has already taken is missing from the lateral force, so the
    figure is low by that share. fn, fe: the specific force in the estimated NED frame, north and east, m/s²;
    xn, xe: the body x axis in it (C_b^n's first column); below 60° of pitch only (the heading is then defined).
    Call after `lowpass_rate_down` with the same k; dt: the step, s."""
    h2 = xn * xn + xe * xe
    if dt <= 0.0 or h2 < 0.25:
        return
    lateral = (xn * fe - xe * fn) / math.sqrt(h2)
    u.lateral_lp_m_s2 += k * (lateral - u.lateral_lp_m_s2)
    w = u.rate_down_lp_rad_s
    keep = max(1.0 - dt / TURN_SPEED_MEMORY_S, 0.0)
    u.speed_moment_m_s = u.speed_moment_m_s * keep + u.lateral_lp_m_s2 * w * dt
    u.speed_weight_rad2_s = u.speed_weight_rad2_s * keep + w * w * dt


@njit(cache=True, inline="always")
def turn_speed_m_s(u, prior_m_s):
    """The speed a turn's lean is reckoned at: the speed the turns showed (`track_turn_speed`), or the prior (the
    filter's `turn_speed_m_s`) where that is larger or the turns seen are too few to tell."""
    if u.speed_weight_rad2_s < TURN_SPEED_EVIDENCE_RAD2_S:
        return prior_m_s
    return max(prior_m_s, u.speed_moment_m_s / u.speed_weight_rad2_s)


@njit(cache=True, inline="always")
def lean_rad(turn_speed_m_s, rate_down_rad_s, g_m_s2):
    """φ = atan(v·|ω_D|/g): how far the apparent vertical leans in a turn at ω_D and speed v."""
    return math.atan(turn_speed_m_s * abs(rate_down_rad_s) / g_m_s2)


@njit(cache=True, inline="always")
def levelling_gain(p_tilt, r):
    """k = P/(P + R): the gain of a levelling update on the tilt axis it observes (p_tilt: that axis' variance
    before the update, r: the update's noise variance), the fraction of its innovation it takes."""
    return p_tilt / (p_tilt + r)


@njit(cache=True)
def track_tilt_push(u, turn_speed_m_s, g_m_s2, gain):
    """Each accepted levelling update moves the estimate toward the lean (`lean_rad` at the low-passed rate)
    with its own gain k (`levelling_gain`; both filters pass δθ_E's), so the lean carried into the estimate
    follows ε ← ε + k (φ − ε): it builds up over a turn and is corrected away after it at the rate the filter
    corrects any tilt error."""
    phi = lean_rad(turn_speed_m_s, u.rate_down_lp_rad_s, g_m_s2)
    u.tilt_push_rad += gain * (phi - u.tilt_push_rad)


@njit(cache=True)
def track_accel_push(u, nu_n, nu_e, gain_n, gain_e, dt, summing):
    """The tilt the levelling takes from a speed change. Speeding up or braking at a leans the apparent vertical
    by a/g along the track; nothing but the velocity shows a, so the levelling reads the lean as tilt error and
    corrects toward it. Its innovation ν (the low-passed vertical's horizontal part in the estimated frame) is
    then the lean φ less the error e the filter already carries, and each update moves the estimate by k·ν
    (k = P/(P + R), `levelling_gain`): e ← e + k(φ − e). The sum of those corrections is e itself, whatever φ
    was (the measurement noise in ν telescopes away: Σ k(n − e) = e_N − e_0), so summing k·ν reconstructs the
    lean the filter carries with no speed known. What else it would sum is not lean: the corrections of the
    gyro's own drift, of which `track_bias_learning` takes out what the filter's bias learning explains, and the
    sum forgets at ACCEL_PUSH_MEMORY_S, which bounds the rest by the drift over the memory (so only a filter
    whose levelling also learns the gyro bias may use it: the module docstring); and the corrections nothing
    leans, which the filter does not sum (`summing` False): at rest (the gyro bias being learned and its noise)
    and while it still converges from its initialisation (the error it started with, which its covariance
    carries). The forgetting is per accepted update: a lean taken stays in the estimate while no update corrects
    it. nu_n: the innovation on δθ_E, nu_e: on −δθ_N (mekf_core._tilt_update); gain_n, gain_e: the
    `levelling_gain` of δθ_N and δθ_E; dt: the time since the previous update, s."""
    track_accel_push_kept(u, nu_n, nu_e, gain_n, gain_e, math.exp(-dt / ACCEL_PUSH_MEMORY_S), summing)


@njit(cache=True)
def track_accel_push_kept(u, nu_n, nu_e, gain_n, gain_e, keep, summing):
    """`track_accel_push` with its forgetting keep = exp(−dt/ACCEL_PUSH_MEMORY_S) given: a caller whose dt
    repeats computes it once (mekf_core caches it per dt), not an exp per update."""
    u.accel_push_e_rad *= keep
    u.accel_push_n_rad *= keep
    mn = u.bias_tilt_n_s      # the bias learning's weights forget with the sum (`track_bias_learning`)
    me = u.bias_tilt_e_s
    lb = u.lean_bias_rad_s    # and so does the bias the summed levelling taught (`track_lean_bias_drift`)
    for i in range(3):
        mn[i] *= keep
        me[i] *= keep
        lb[i] *= keep
    u.lean_drift_n_rad *= keep
    u.lean_drift_e_rad *= keep
    if summing:
        u.accel_push_e_rad += gain_e * nu_n
        u.accel_push_n_rad -= gain_n * nu_e


@njit(cache=True, inline="always")
def prior_share(p_before, q, p_after):
    """The share of a step's bias learning that learns what was unknown before it, in [0, 1]: its updates take
    the bias variance from p_before + q (q: the random walk the step added) down to p_after; of that reduction
    p_before − p_after shrinks what was left from before (a turn-on bias being learned from its prior), and the
    rest, q, only relearns what the walk let wander this step (the share then 0: a bias held at its steady
    state, whose estimate moves with whatever else the levelling reads as bias)."""
    learnt = p_before + q - p_after
    if learnt <= 0.0:
        return 0.0
    return min(max((p_before - p_after) / learnt, 0.0), 1.0)


@njit(cache=True)
def track_bias_learning(u, dt, c, summing, db0, db1, db2):
    """Once per step, after its updates: take out of the speed change's sum (`track_accel_push`) the corrections
    the filter's own gyro bias learning explains. The estimate propagates with ω − b̂ and each correction turns
    it by δθ, so its NED error moves as dε = C_b^n (b − b̂(τ)) dτ + δθ, and the corrections sum to
        Σ w δθ = Σ w dε − ∫ w C (b − b̂(t)) dτ − ∫ w C (b̂(t) − b̂(τ)) dτ
    (w(t, τ): the sum's forgetting). The first term is what the sum is for (the lean taken); the second is the
    bias error the filter still has (its covariance's); the third is drift that the bias learned since τ
    explains in hindsight (the start's bias learning, a bias that moves). It is known to the filter:
    X = M b̂(t) − ∫ w C b̂ dτ with M = ∫ w C dτ, so dX = M db̂ + (X's forgetting, the sum's), and adding it
    (X ← X + M δb̂ here, forgotten with the sum) leaves Σ w dε − ∫ w C (b − b̂(t)) dτ. M (`bias_tilt_n_s`,
    `bias_tilt_e_s`: the north and east rows, how far a body-frame bias error of 1 rad/s has turned the
    estimate about north and east over the memory) takes the time whose corrections are summed (`summing`).
    Only a bias being learned explains drift this way: one held at its steady state also moves with what the
    levelling reads as bias (a speed change's lean among it), so the caller passes the share of δb̂ that learns
    the bias's prior (`prior_share`: all of it while a turn-on bias is learned, none at the steady state), at
    rest too (the bias measured there explains the drift summed before). c: C_b^n of the step (`dcm`'s
    9-tuple, the attitude propagated with b̂ before δb̂); db0, db1, db2: that share of the change of b̂ over
    the step's updates, rad/s; dt: the step, s."""
    c00, c01, c02, c10, c11, c12, _, _, _ = c
    mn = u.bias_tilt_n_s
    me = u.bias_tilt_e_s
    if summing:
        mn[0] += c00 * dt
        mn[1] += c01 * dt
        mn[2] += c02 * dt
        me[0] += c10 * dt
        me[1] += c11 * dt
        me[2] += c12 * dt
    u.accel_push_n_rad += mn[0] * db0 + mn[1] * db1 + mn[2] * db2
    u.accel_push_e_rad += me[0] * db0 + me[1] * db1 + me[2] * db2


class RestLearning(NamedTuple):
    """What a rest taught the gyro bias on one step (`track_lean_bias_drift`; numba passes it by value)."""
    at_rest: bool                          # the step was at rest
    keep: float                            # exp(−Δt/τ_rest): the share of what rest learnt before that still counts
    db_rad_s: tuple[float, float, float]   # the step's at-rest change of the bias estimate, body frame, rad/s


@njit(cache=True)
def track_lean_bias_drift(u, dt, c, summing, levelled, lean_db_rad_s, rest):
    """Once per step, after its updates: the drift of the gyro bias the summed levelling taught, while no
    levelling corrects it. The levelling learns the bias from its innovations, so the lean it takes (a turn's
    roll-in, a speed change) is also read as bias: the estimate then propagates with ω − b̂ and turns by
        dε = −C_b^n b_lean dτ
    per step (track_bias_learning's dε with b − b̂ = −b_lean). While levelling updates are accepted they correct
    that drift and the speed change's sum takes their corrections (`track_accel_push`); while they are rejected (a
    sustained bank, a hard acceleration) nothing corrects or sums it, so it is tracked here (`lean_drift_n_rad`,
    `lean_drift_e_rad`: ε's north and east rows) and enters the tilt push in quadrature beside the sum, not into
    the signed sum: whatever else the sum holds (the gyro's own drift corrections) is no lean and must not cancel
    it. Forgotten with the sum, per accepted update; the corrections that later remove the drift go into the sum,
    so the two overlap for the memory (an upper bound, not an estimate). b_lean (`lean_bias_rad_s`) is
    Σ (1 − prior share)·δb̂ over the summed steps (the part of a bias change that does not learn the bias's prior,
    `prior_share`), forgotten with the sum. c: C_b^n of the step (`dcm`'s 9-tuple); summing: the step's levelling
    is summed (`_sums_lean`); levelled: a levelling update was accepted this step (or the step was at rest);
    lean_db_rad_s: (1 − prior share)·δb̂ of the step (body x, y, z), rad/s.
    The rest detector declares the end of a rest only once its low-passed motion exceeds its threshold, so the
    start of a motion is learnt as bias at rest (`rest`: the step's `RestLearning`, its at-rest δb̂); what rest
    learnt over the detector's lag (`rest_bias_recent_rad_s`, forgotten by rest.keep = exp(−Δt/τ_rest) per step)
    is added to b_lean when the rest ends: it may be motion, not bias."""
    lb = u.lean_bias_rad_s
    rr = u.rest_bias_recent_rad_s
    if rest.at_rest:
        rb0, rb1, rb2 = rest.db_rad_s
        rr[0] = rr[0] * rest.keep + rb0
        rr[1] = rr[1] * rest.keep + rb1
        rr[2] = rr[2] * rest.keep + rb2
        u.was_at_rest = 1.0
    elif u.was_at_rest != 0.0:
        for i in range(3):
            lb[i] += rr[i]
            rr[i] = 0.0
        u.was_at_rest = 0.0
    if summing:
        lb0, lb1, lb2 = lean_db_rad_s
        lb[0] += lb0
        lb[1] += lb1
        lb[2] += lb2
    if not levelled:
        c00, c01, c02, c10, c11, c12, _, _, _ = c
        u.lean_drift_n_rad -= (c00 * lb[0] + c01 * lb[1] + c02 * lb[2]) * dt
        u.lean_drift_e_rad -= (c10 * lb[0] + c11 * lb[1] + c12 * lb[2]) * dt


@njit(cache=True, inline="always")
def tilt_pushes_rad(u):
    """The tilt terms together (1σ, rad): the turn's lean, the speed change's and the drift of the bias learnt
    from a lean while no levelling corrects it, in quadrature."""
    return math.sqrt(u.tilt_push_rad * u.tilt_push_rad + u.accel_push_n_rad * u.accel_push_n_rad
                     + u.accel_push_e_rad * u.accel_push_e_rad + u.lean_drift_n_rad * u.lean_drift_n_rad
                     + u.lean_drift_e_rad * u.lean_drift_e_rad)


@njit(cache=True)
def track_heading_push(u, dip_rad, p_heading, r):
    """The heading error the tilt push leaves through the field's dip. The heading is the direction of the
    horizontal field in the estimated NED frame; a tilt error ε about the north axis turns the vertical field
    B sin I into the east component, ε B sin I, against a horizontal field B cos I: a heading error ε tan I.
    Each heading update moves the estimate toward that with its own gain P/(P + R)."""
    target = abs(math.tan(dip_rad)) * tilt_pushes_rad(u)
    u.heading_push_rad += p_heading / (p_heading + r) * (target - u.heading_push_rad)


@njit(cache=True)
def bound_pushes(u, turn_speed_m_s, rate_down_max_rad_s, g_min_m_s2, dip_max_rad):
    """After a stretch that did not track the pushes: set them to an upper bound of what tracking would have
    left. Each tracked term moves toward its target with a gain in [0, 1] (a convex combination), so it never
    exceeds the larger of its value before and its largest target: the tilt lean (`lean_rad`) at the largest
    low-passed rate about the vertical and the smallest g, and the heading lean |tan I|·(that tilt bound) at
    the steepest dip."""
    tilt = max(u.tilt_push_rad, lean_rad(turn_speed_m_s, rate_down_max_rad_s, g_min_m_s2))
    u.tilt_push_rad = tilt
    u.heading_push_rad = max(u.heading_push_rad, abs(math.tan(dip_max_rad)) * tilt_pushes_rad(u))


@njit(cache=True, inline="always")
def clear(u):
    """No lean left: the attitude is held by something that observes it (ins with GNSS velocity)."""
    u.tilt_push_rad = 0.0
    u.heading_push_rad = 0.0
    u.accel_push_n_rad = 0.0
    u.accel_push_e_rad = 0.0
    u.lean_drift_n_rad = 0.0
    u.lean_drift_e_rad = 0.0


@njit(cache=True, inline="always")
def add_pushes_to_sigma(u, sigma_rpy_rad):
    """Roll, pitch and yaw 1σ (rad, in place) with the pushes added in quadrature. The tilt push is the same
    about every horizontal axis, so adding it to the roll and pitch variances is adding it to the north and
    east tilt variances before they are rotated into the heading frame. Nothing to do (and nothing done) while
    both are zero."""
    e = tilt_pushes_rad(u)
    h = u.heading_push_rad
    if e != 0.0:
        sigma_rpy_rad[0] = math.sqrt(sigma_rpy_rad[0] * sigma_rpy_rad[0] + e * e)
        sigma_rpy_rad[1] = math.sqrt(sigma_rpy_rad[1] * sigma_rpy_rad[1] + e * e)
    if h != 0.0:
        sigma_rpy_rad[2] = math.sqrt(sigma_rpy_rad[2] * sigma_rpy_rad[2] + h * h)
