"""Offline Rauch–Tung–Striebel smoothing of the `ins` error-state filter (fixed interval: the whole recording).

The forward pass is the daemon's own filter (`Ins`, unchanged); `SmoothingIns` records, per update epoch, what
the backward pass needs, and `smoothed_roll_pitch()` returns the attitude given every fix of the run, past and
future. The physical gain: the accelerometer and gyro bias states converge over the whole run, and the smoother
carries the end-of-run knowledge back to the start, so the body-fixed tilt error of the forward filter (bias
and misalignment not yet separated from tilt) shrinks. Offline only (calibration levelling).

**The backward pass** (Rauch, Tung & Striebel, AIAA J. 3(8), 1965; Groves, Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems, 2nd ed., §3.4.2), on the error state of a closed-loop filter. Node n
is an epoch where a measurement changed the state: a-priori covariance P⁻_n, a-posteriori P⁺_n, and the
correction dx_n folded into the nominal (the error state is reset to 0 after it). Φ_n is the transition from
node n to n+1 (the product of the filter's own propagation matrices in between, exact for the linearised
model). With s_n the smoothed error relative to the a-posteriori nominal at n:

    C_n  = P⁺_n Φ_nᵀ (P⁻_{n+1})⁻¹
    s_n  = C_n (s_{n+1} + dx_{n+1})                 (δx_s,n = δx_n|n + C_n (δx_s,n+1 − δx_n+1|n), δx_n|n = 0,
                                                     relative to the a-priori nominal at n+1: s_{n+1} + dx_{n+1})
    Ps_n = P⁺_n + C_n (Ps_{n+1} − P⁻_{n+1}) C_nᵀ,   s_N = 0, Ps_N = P⁺_N at the last node.

Memory: nodes are grouped into blocks that end at a GNSS epoch (or every MAX_BLOCK_S); within a block the
recursions compose, s_k = A s_K + b and Ps_k = D + A Ps_K Aᵀ, with A, b, D accumulated in the forward pass, so
only one (A, b, D) per block is kept (about 3 MB per minute at 5 Hz, whatever the sample rate or the number
of magnetometer updates; plus 48 bytes per sample). Between block ends the correction is interpolated linearly in time (0.2 s apart).

**Cuts.** Where the filter is not a Kalman filter — before the first fix sets velocity and position (their
covariance is reset every epoch), while it levels on the accelerometer (unaided, a tilt-only gain), at a
velocity/position reset after a run of rejections or an outage, at a re-initialisation — no information
passes backward across (C = 0): the smoothed values there are the filter's own.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import ins_core as core
from .ins import Ins
from .rotations import _SMALL_ANGLE_RAD, quat_exp, quat_multiply, quat_to_euler

MAX_BLOCK_S = 0.5   # a block also ends after this long without a fix (magnetometer updates in an outage)
_CUT_RESULTS = core.R_NAV_INIT | core.R_OUTAGE_RESET | core.R_VEL_RESET | core.R_POS_RESET
# SmoothingIns records per sample: its time, the filter's own attitude (body → true NED; NaN before the filter
# initialised) and its tilt 1σ
_RECORD_DTYPE = np.dtype([("t_s", np.float64), ("q", np.float64, (4,)), ("tilt_sigma_rad", np.float64)])


class RtsSmoother:
    """The bookkeeping of a fixed-interval RTS smoother over a closed-loop (error-state) Kalman filter of any
    dimension, fed in time order by the filter:

    - `propagate(phi)` for each transition between measurement epochs (several multiply up);
    - `node(t, p_prior, p_post, dx, cut=False, block_end=True)` at each epoch whose measurement changed the
      state (dx: the correction folded into the nominal; `cut`: do not smooth across the link into this node,
      `p_prior` is then ignored; `block_end=False`: an intermediate node, composed into the current block);
    - `smooth()` → (t, s_post, s_pre, P_s) per block end: the smoothed error relative to the filter's
      a-posteriori nominal at that node, relative to its a-priori nominal (s_post + dx; 0 at a cut), and the
      smoothed covariance.
    """

    def __init__(self, n: int):
        self.n = n
        self._eye = np.eye(n)
        self._phi = self._eye.copy()
        self._p_post = None          # P⁺ of the last node
        self._open_block()
        self._t, self._a, self._b, self._d, self._dx, self._cut = [], [], [], [], [], []

    def _open_block(self) -> None:
        self._A = self._eye.copy()
        self._B = np.zeros(self.n)
        self._D = np.zeros((self.n, self.n))

    def propagate(self, phi: np.ndarray) -> None:
        self._phi = phi @ self._phi

    def node(self, t: float, p_prior, p_post, dx, cut: bool = False, block_end: bool = True) -> None:
        p_post = np.array(p_post, dtype=float)
        dx = np.asarray(dx, dtype=float)
        if self._p_post is not None:
            prior = self._p_post if cut else np.asarray(p_prior, dtype=float)
            self._A, self._B, self._D = _compose_link(self._A, self._B, self._D, self._phi, self._p_post, prior, dx,
                                                      cut)
        if block_end or cut:
            if self._t:   # close the block that started at the previous block end
                self._a.append(self._A)
                self._b.append(self._B)
                self._d.append(self._D)
            self._t.append(float(t))
            self._dx.append(dx.copy())
            self._cut.append(bool(cut))
            self._open_block()
        self._p_post = p_post
        self._phi = self._eye.copy()

    def smooth(self):
        """Backward pass. Returns (t, s_post, s_pre, P_s), arrays over the block ends (see the class)."""
        m = len(self._t)
        s_post = np.zeros((m, self.n))
        p_s = np.zeros((m, self.n, self.n))
        if m == 0:
            return np.zeros(0), s_post, s_post.copy(), p_s
        # the block still open after the last block end (identity when no node followed it) ends at the last
        # node, where the smoothed error is 0 and its covariance the filter's
        s_post[m - 1] = self._B
        p_s[m - 1] = self._D + self._A @ self._p_post @ self._A.T
        for k in range(m - 2, -1, -1):
            a, b, d = self._a[k], self._b[k], self._d[k]
            s_post[k] = a @ s_post[k + 1] + b
            p_s[k] = d + a @ p_s[k + 1] @ a.T
        s_pre = s_post + np.array(self._dx)
        s_pre[np.array(self._cut)] = 0.0
        return np.array(self._t), s_post, s_pre, p_s


@njit(cache=True)
def _compose_link(a, b, d, phi, p_post_prev, p_prior, dx, cut):
    """One link of the backward recursion composed into the block (A, b, D) — see the module docstring:
    C = P⁺ Φᵀ (P⁻)⁻¹ over the states the filter has (a state switched off has variance 0; P symmetric), or 0 at
    a cut; E = P⁺ − C P⁻ Cᵀ; then D += A E Aᵀ, A ← A C, b += A dx."""
    n = p_post_prev.shape[0]
    c = np.zeros((n, n))
    if cut:
        e = p_post_prev.copy()
    else:
        on = np.where(np.diag(p_prior) > 0.0)[0]
        m = len(on)
        pp = phi @ p_post_prev
        sub = np.empty((m, m))
        rhs = np.empty((m, n))
        for i in range(m):
            for j in range(m):
                sub[i, j] = p_prior[on[i], on[j]]
            rhs[i, :] = pp[on[i], :]
        sol = np.linalg.solve(sub, rhs)
        for i in range(m):
            c[:, on[i]] = sol[i, :]
        e = p_post_prev - c @ p_prior @ c.T
    d = d + a @ e @ a.T
    a = a @ c
    b = b + a @ dx
    return a, b, d


@njit(cache=True)
def nominal_difference(x_before, x_after, par) -> np.ndarray:
    """The error-state correction (core's N_ERR components) that takes the nominal state x_before to x_after:
    δθ with C_after = exp([δθ×]) C_before (NED), δv, δp (NED, m), and the sensor-error states' differences.
    Scalar arithmetic (numba): it runs at every epoch of the recorded filter."""
    dx = np.zeros(core.N_ERR)
    a0, a1, a2, a3 = x_after["q"][0], x_after["q"][1], x_after["q"][2], x_after["q"][3]
    b0, b1, b2, b3 = x_before["q"][0], -x_before["q"][1], -x_before["q"][2], -x_before["q"][3]
    # q_after ⊗ q_before* (Hamilton), then its rotation vector with w ≥ 0 (rotations.quat_log)
    w = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    u0 = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    u1 = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    u2 = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0
    if w < 0.0:
        w, u0, u1, u2 = -w, -u0, -u1, -u2
    s = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if s < _SMALL_ANGLE_RAD:
        factor = 2.0 / w * (1.0 - s * s / (3.0 * w * w))
    else:
        factor = 2.0 * math.atan2(s, w) / s
    dx[0], dx[1], dx[2] = factor * u0, factor * u1, factor * u2
    for i in range(3):
        dx[3 + i] = x_after["vel_ned_m_s"][i] - x_before["vel_ned_m_s"][i]
    lat, h = x_before["lat_rad"], x_before["h_m"]
    r_n, r_e = core._radii(par, lat)
    dx[6] = (x_after["lat_rad"] - lat) * (r_n + h)
    dx[7] = (x_after["lon_rad"] - x_before["lon_rad"]) * (r_e + h) * math.cos(lat)
    dx[8] = -(x_after["h_m"] - h)
    for i in range(3):
        dx[9 + i] = x_after["gyro_bias_rad_s"][i] - x_before["gyro_bias_rad_s"][i]
        dx[12 + i] = x_after["accel_bias_m_s2"][i] - x_before["accel_bias_m_s2"][i]
        dx[15 + i] = x_after["gyro_scale"][i] - x_before["gyro_scale"][i]
    for i in range(6):
        dx[18 + i] = x_after["gyro_misalignment_rad"][i] - x_before["gyro_misalignment_rad"][i]
    for i in range(core.E_MF - core.E_MH):
        dx[core.E_MH + i] = x_after["mag_heading_error_rad"][i] - x_before["mag_heading_error_rad"][i]
    for i in range(core.E_AZ_LEAN - core.E_MF):
        dx[core.E_MF + i] = x_after["mag_frame_tilt_rad"][i] - x_before["mag_frame_tilt_rad"][i]
    for i in range(core.N_ERR - core.E_AZ_LEAN):
        dx[core.E_AZ_LEAN + i] = x_after["accel_z_lean_rad"][i] - x_before["accel_z_lean_rad"][i]
    return dx


def _copy_records(dst: np.ndarray, src: np.ndarray) -> None:
    """dst[...] = src for record arrays of one dtype, as bytes: bit-identical, and without numpy's copy of a
    structured record field by field (most of the recording's cost when it was per sample)."""
    np.copyto(dst.view(np.uint8), src.view(np.uint8))


@njit(cache=True)
def _epoch_prior(x_pre_arr, x_arr, par_arr, p_before, p, p_prior):
    """What SmoothingIns._epoch needs at every epoch, in one compiled call (from Python, a record argument
    costs more than this arithmetic): whether the call propagated the covariance (with the sums in x_pre_arr,
    which this clears), whether the filter is a Kalman filter after it (`kalman`; not, see the module
    docstring: a cut), whether a measurement changed the covariance (`measured`: p ≠ P⁻); Φ of the
    propagation (0×0 when none); p_prior ← P⁻, p_before propagated."""
    x_pre, x, par = x_pre_arr[0], x_arr[0], par_arr[0]
    kalman = x.nav_ok > 0.0 and core._aided(x, par)
    propagated = x_pre.cov_t_s > 0.0 and x.cov_t_s < x_pre.cov_t_s
    p_prior[:, :] = p_before
    phi = np.zeros((0, 0))
    if propagated:
        phi = core.transition_matrix(x_pre, par)
        core.propagate_covariance(x_pre, p_prior, par)
    measured = False
    n = p.shape[0]
    for i in range(n):
        for j in range(n):
            if p_prior[i, j] != p[i, j]:    # as np.array_equal: a NaN counts as a change
                measured = True
    return propagated, kalman, measured, phi


class SmoothingIns(Ins):
    """`Ins` that records its epochs for `RtsSmoother` (same estimates, same counters; recording costs run time). Run it
    over a recording (`update`, `update_gnss` as for Ins), then `smoothed_roll_pitch()`."""

    def __init__(self, declination_rad: float = 0.0, params=None, **overrides):
        super().__init__(declination_rad, params, **overrides)
        self.smoother = RtsSmoother(core.N_ERR)
        self._live_step = self._step
        self._step = self._recorded_step
        self._shadow_hist = np.zeros_like(self._hist)
        self._shadow_out = np.zeros(1, core.INS_OUT_DTYPE)
        self._shadow_par = np.zeros_like(self._par_arr)
        self._x_pre = np.zeros_like(self._x_arr)     # the state before an epoch's covariance update (scratch)
        self._p_before = np.zeros_like(self._P)
        self._p_prior = np.zeros_like(self._P)
        self._rec = np.empty(4096, _RECORD_DTYPE)   # one row per sample
        self._n_rec = 0
        self._block_t = -math.inf

    # ------------------------------------------------------------------ recording
    def _epoch(self, x_pre, p_before, t, cut: bool, block_end: bool) -> None:
        """After a call that may have propagated the covariance (with the sums in x_pre, a 1-element state array
        this scratches) and then updated the state: a propagation, and a node when a measurement (or a reset:
        `cut`) changed the state."""
        propagated, kalman, measured, phi = _epoch_prior(x_pre, self._x_arr, self._par_arr, p_before, self._P,
                                                         self._p_prior)
        if propagated:
            self.smoother.propagate(phi)
        cut = cut or not kalman
        if not cut and not measured:
            return   # no measurement at this epoch
        end = block_end or cut or t - self._block_t >= MAX_BLOCK_S
        self.smoother.node(t, self._p_prior, self._P, nominal_difference(x_pre[0], self._x, self._par), cut=cut,
                           block_end=end)
        if end:
            self._block_t = t

    def _recorded_step(self, x, P, hist, par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sflags, out, gsf, gsf_par):
        # the mechanisation alone (no covariance epoch, no GNSS-yaw bank) on a copy: its sums are those the
        # epoch will use
        _copy_records(self._shadow_par, par)
        self._shadow_par["cov_period_s"] = math.inf
        self._shadow_par["gnss_yaw"] = 0.0
        xs = self._x_pre
        _copy_records(xs, x)
        self._live_step(xs, P, self._shadow_hist, self._shadow_par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sflags,
                        self._shadow_out, gsf, gsf_par)
        np.copyto(self._p_before, P)
        f = self._live_step(x, P, hist, par, t_s, gx, gy, gz, ax, ay, az, mx, my, mz, sflags, out, gsf, gsf_par)
        if f & core.NEEDS_INIT:
            return f
        # x, xs: 1-element state arrays (the step's arguments)
        self._epoch(xs, self._p_before, float(x[0]["t_last_s"]), False, False)
        return f

    def _fuse(self, fix) -> int:
        _copy_records(self._x_pre, self._x_arr)
        np.copyto(self._p_before, self._P)
        interventions = self.heading_interventions
        res = super()._fuse(fix)
        # a yaw reset or a raised yaw variance (heading monitor) is not a Kalman update: cut there too
        cut = bool(res & _CUT_RESULTS) or self.heading_interventions != interventions
        self._epoch(self._x_pre, self._p_before, float(self._x["t_last_s"]), cut, True)
        return res

    def _initialise(self, t_s, g, a, m, sample_flags: int) -> bool:
        ok = super()._initialise(t_s, g, a, m, sample_flags)
        if ok:
            self._block_t = float(t_s)
            self.smoother.node(float(t_s), None, self._P, np.zeros(core.N_ERR), cut=True)
        return ok

    def update(self, sample):
        e = super().update(sample)
        if self._n_rec == len(self._rec):
            self._rec = np.concatenate([self._rec, np.empty_like(self._rec)])
        row = self._rec[self._n_rec]
        row["t_s"] = sample.t_s
        row["q"] = self._x["q"] if self._initialised else np.nan
        row["tilt_sigma_rad"] = math.hypot(e.sigma_rpy_rad[0], e.sigma_rpy_rad[1])
        self._n_rec += 1
        return e

    # ------------------------------------------------------------------ result
    def smoothed_corrections(self) -> tuple[np.ndarray, np.ndarray]:
        """Per recorded sample: the smoothed error-state correction (N_ERR) relative to the filter's state after
        that sample, and the smoothed tilt 1σ (rad; the filter's own where nothing was smoothed)."""
        t_node, s_post, s_pre, p_s = self.smoother.smooth()
        rec = self._rec[: self._n_rec]
        t = rec["t_s"]
        corr = np.zeros((len(t), core.N_ERR))
        sigma = rec["tilt_sigma_rad"].copy()
        if len(t_node) < 2:
            return corr, sigma
        # sample i follows block end k = the last one at or before it (a node happens within a sample's update)
        k = np.searchsorted(t_node, t, side="right") - 1
        inside = (k >= 0) & (k < len(t_node) - 1)
        ki = k[inside]
        w = (t[inside] - t_node[ki]) / np.maximum(t_node[ki + 1] - t_node[ki], 1e-12)
        corr[inside] = s_post[ki] + w[:, None] * (s_pre[ki + 1] - s_post[ki])
        last = k == len(t_node) - 1
        corr[last] = s_post[-1]
        tilt_var = p_s[:, core.E_TH, core.E_TH] + p_s[:, core.E_TH + 1, core.E_TH + 1]   # δθ_N, δθ_E
        smoothed = inside | last
        sigma[smoothed] = np.sqrt(np.maximum(tilt_var[k[smoothed]], 0.0))
        return corr, sigma

    def smoothed_roll_pitch(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Roll, pitch (rad) and tilt 1σ per recorded sample, smoothed over the whole run (NaN before the
        filter initialised)."""
        corr, sigma = self.smoothed_corrections()
        q = self._rec[: self._n_rec]["q"]
        qs = quat_multiply(quat_exp(corr[:, core.E_TH:core.E_TH + 3]), q)
        rpy = quat_to_euler(qs)
        return rpy[:, 0], rpy[:, 1], sigma


__all__ = ["RtsSmoother", "SmoothingIns", "nominal_difference", "MAX_BLOCK_S"]
