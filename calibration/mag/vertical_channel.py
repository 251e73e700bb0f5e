"""The generalised back-stepping fit for real vehicles: the vertical channel.

It imposes the paper's two conditions (see backstepping_paper.py) — the field magnitude equals the WMM total
intensity and the levelled vertical component equals the WMM vertical intensity — on every sample at once,
with a full 3×3 soft-iron matrix, by least squares. Levelling uses roll/pitch, so the vertical component
depends on how each axis responds to the vertical field: this is what pins the z hard iron and z scale (and
the whole vertical soft-iron column) that an ellipsoid fit cannot see on data with only a few degrees of tilt.
Without a known position the dip angle is a free parameter (it needs more tilt: observability.py's limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2, down_in_body, wrap_pi
from ahrsd.estimator.rotations import euler_to_dcm

from .backstepping_paper import BacksteppingError, magnetic_heading_deg

ADIS16405_MAG_NOISE_UT = 0.125   # ADIS16405 datasheet: magnetometer output noise 1.25 mgauss rms
DEFAULT_TILT_SIGMA_DEG = 0.3     # roll/pitch error of a low-passed accelerometer / AHRS (1σ, assumed)
PRIOR_SIGMA_SOFT_IRON = 0.5      # weak prior on each soft-iron entry (keeps undetermined directions at the start value)
PRIOR_SIGMA_SPEED_M_S = 20.0     # weak prior on the fitted forward speed (centripetal compensation)


@dataclass(frozen=True)
class VerticalChannelFit:
    """calibrated = soft_iron·(raw − hard_iron). `vertical_ut`: the reference or fitted vertical intensity;
    `jacobian` of the whitened data residuals at the solution (for uncertainty); `names` of its columns."""

    soft_iron: np.ndarray
    hard_iron_ut: np.ndarray
    total_ut: float
    vertical_ut: float
    free_dip: bool
    magnitude_rms_ut: float
    vertical_rms_ut: float
    whitened_rms: float
    jacobian: np.ndarray
    names: list
    init: str
    nfev: int
    success: bool
    message: str
    speed_m_s: float | None = None     # fitted forward speed of the centripetal compensation (None: not fitted)
    vertical_residual: np.ndarray | None = None   # whitened vertical-channel residuals per sample, in time order


_PARAM_NAMES = [f"soft_iron[{i}{j}]" for i in "xyz" for j in "xyz"] + ["hard_iron_x_ut", "hard_iron_y_ut", "hard_iron_z_ut"]


def _conic_init(raw: np.ndarray, d: np.ndarray, total: float, vertical: float):
    """Start values for level-ish data: a 2-D ellipse through the horizontal components gives the horizontal
    hard iron and soft iron; the vertical row comes from regressing raw z on the calibrated horizontal
    components and on the body-z field implied by the vertical constraint (b·d = H_z)."""
    xy0 = raw[:, :2].mean(axis=0)
    xy = raw[:, :2] - xy0
    a = np.column_stack((xy[:, 0] ** 2, xy[:, 0] * xy[:, 1], xy[:, 1] ** 2, xy[:, 0], xy[:, 1]))
    coef, *_ = np.linalg.lstsq(a, np.ones(xy.shape[0]), rcond=None)
    a2 = np.array([[coef[0], coef[1] / 2], [coef[1] / 2, coef[2]]])
    g = coef[3:5]
    try:
        x0 = -0.5 * np.linalg.solve(a2, g)
    except np.linalg.LinAlgError:
        return None
    k = 1.0 + x0 @ a2 @ x0
    a2n = a2 / k
    ev, evec = np.linalg.eigh(a2n)
    if not np.all(ev > 0):
        return None
    hh = math.sqrt(max(total**2 - vertical**2, 1e-6 * total**2))
    w_h = hh * (evec * np.sqrt(ev)) @ evec.T            # symmetric square root, radius → H_h
    ch = (xy - x0) @ w_h.T
    dz = np.where(np.abs(d[:, 2]) > 0.2, d[:, 2], 0.2)
    bz = (vertical - ch[:, 0] * d[:, 0] - ch[:, 1] * d[:, 1]) / dz
    k0 = 1.0 / float(np.mean(np.linalg.svd(w_h, compute_uv=False)))
    # ridge row: prior k = k0 with σ 30 % against ~0.2 µT data noise (only matters when b_z barely varies)
    lam = 0.2 / (0.3 * k0)
    reg = np.column_stack((ch, bz, np.ones_like(bz)))
    reg = np.vstack((reg, [0.0, 0.0, lam, 0.0]))
    rhs = np.concatenate((raw[:, 2], [lam * k0]))
    zc, *_ = np.linalg.lstsq(reg, rhs, rcond=None)
    dmat = np.zeros((3, 3))
    dmat[:2, :2] = np.linalg.inv(w_h)
    dmat[2] = zc[:3]
    try:
        w0 = np.linalg.inv(dmat)
    except np.linalg.LinAlgError:
        return None
    h0 = np.array([xy0[0] + x0[0], xy0[1] + x0[1], zc[3]])
    return w0, h0


def _ellipsoid_init(raw: np.ndarray, total: float):
    """Start values from an algebraic 10-parameter ellipsoid (only when it is one: positive definite)."""
    c0 = raw.mean(axis=0)
    x = raw - c0
    a = np.column_stack((x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2],
                         2 * x[:, 1] * x[:, 2], 2 * x[:, 0], 2 * x[:, 1], 2 * x[:, 2], np.ones(x.shape[0])))
    _, _, vt = np.linalg.svd(a, full_matrices=False)
    p = vt[-1]
    m = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    if np.trace(m) < 0:
        m, p = -m, -p
    try:
        centre = -np.linalg.solve(m, p[6:9])
    except np.linalg.LinAlgError:
        return None
    k = centre @ m @ centre - p[9]
    if not k > 0:
        return None
    m = m / k
    ev, evec = np.linalg.eigh(m)
    if not np.all(ev > 0):
        return None
    w0 = total * (evec * np.sqrt(ev)) @ evec.T
    return w0, centre + c0


def centripetal_direction(gyro_rad_s: np.ndarray, down_body: np.ndarray) -> np.ndarray:
    """k: the body specific force added per m/s of forward speed in a turn. A boat, rover or AUV turning at
    ψ̇ moves along a horizontal track, so the centripetal acceleration is ψ̇·V along the horizontal right
    direction r = d × x̂/|d × x̂| (d = down in the body frame): k = ψ̇·r, ψ̇ = (q·d_y + r·d_z)/(d_y² + d_z²)
    (ZYX kinematics, ψ̇ = (q sinφ + r cosφ)/cosθ). The velocity does not pitch with the hull in waves: the
    body-fixed form ω × [V, 0, 0] would add −q·V on z, a spurious tilt of V·θ̇/g in every wave."""
    w = np.asarray(gyro_rad_s, dtype=np.float64)
    d = np.asarray(down_body, dtype=np.float64)
    c2 = np.maximum(d[:, 1] ** 2 + d[:, 2] ** 2, 1e-6)
    psi_dot = (w[:, 1] * d[:, 1] + w[:, 2] * d[:, 2]) / c2
    return (psi_dot / np.sqrt(c2))[:, None] * np.column_stack((np.zeros(d.shape[0]), d[:, 2], -d[:, 1]))


def corrected_down(d0: np.ndarray, k: np.ndarray | None, speed_m_s) -> np.ndarray:
    """Down direction after removing the centripetal specific force V·k from the levelling: the measured
    specific force is −g·d0 (accelerometer, or an estimator whose roll/pitch follow it), so the true down is
    ∝ g·d0 + V·k."""
    if k is None:
        return d0
    u = d0 + np.asarray(speed_m_s, dtype=np.float64).reshape(-1, 1) * k / STANDARD_GRAVITY_M_S2
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def fit_vertical_channel(raw: np.ndarray, roll_rad, pitch_rad, total_ut: float, vertical_ut: float | None, *,
                         sigma_mag_ut: float = ADIS16405_MAG_NOISE_UT,
                         sigma_tilt_rad: float = math.radians(DEFAULT_TILT_SIGMA_DEG),
                         prior_sigma: float = PRIOR_SIGMA_SOFT_IRON, init=None,
                         robust: bool = False, gyro_rad_s: np.ndarray | None = None,
                         speed_m_s=None) -> VerticalChannelFit:
    """Least-squares W (3×3) and h (3) with, per sample, c = W·(m − h):

        (|c| − F)/σ_F               magnitude equals the WMM total intensity F
        (c·d − H_z)/σ_V             levelled vertical component equals the WMM vertical intensity
                                    (d = NED down in the body frame from roll/pitch)

    plus a weak prior (σ = prior_sigma per W entry) towards the start value, which only matters for directions
    the data do not determine. `vertical_ut=None` fits the dip (H_z = F·sin δ) as a free parameter; F then only
    sets the scale. σ_V = √(σ_F² + (H_h·σ_tilt)²) accounts for the roll/pitch error.

    Turning vehicles: roll/pitch from the accelerometer (and from estimators that follow it) lean into the turn
    by atan(V·ω_z/g). With `gyro_rad_s`, `speed_m_s` removes it: a number or per-sample array (e.g. GNSS
    speed), or "fit" to estimate a constant forward speed as one more parameter (needs turns at varying rates
    or in both directions: a constant lean is indistinguishable from a sensor roll misalignment)."""
    m = np.asarray(raw, dtype=np.float64)
    d0, k, fit_speed, d_fixed = _levelling(roll_rad, pitch_rad, gyro_rad_s, speed_m_s)
    free_dip = vertical_ut is None
    total = float(total_ut)
    hz_guesses = [float(vertical_ut)] if not free_dip else [total * math.sin(math.radians(a))
                                                         for a in (-70, -50, -30, -10, 10, 30, 50, 70)]
    hh_ref = math.sqrt(max(total**2 - hz_guesses[0] ** 2, 0.0)) if not free_dip else 0.6 * total
    sig_f = float(sigma_mag_ut)
    sig_v = math.sqrt(sig_f**2 + (hh_ref * sigma_tilt_rad) ** 2)
    problem = _VerticalChannelProblem(m, d0, k, d_fixed, total, vertical_ut, fit_speed, sig_f, sig_v, prior_sigma)
    starts = _start_values(m, d_fixed, total, hz_guesses, free_dip, init)
    best = _best_start(problem, starts, hz_guesses[0], total, free_dip, fit_speed, robust)
    _, sol1, name, p0 = best
    # stage 2: the best start to convergence. The prior is re-centred on the stage-1 result; it is weak, so this
    # only matters for directions the data do not determine at all
    got = problem.solve(sol1.x, 200, robust) if len(starts) > 1 else (best[0], sol1, problem.make_fun(p0)[1])
    if got is None:
        raise BacksteppingError("the vertical-channel least squares did not converge")
    _cost, sol, jac = got
    return _fit_result(problem, sol, jac, name, total, free_dip, fit_speed, sig_f, sig_v)


def _levelling(roll_rad, pitch_rad, gyro_rad_s, speed_m_s):
    """(d0, k, fit_speed, d_fixed): down in the body frame from roll/pitch; the centripetal direction when the
    lean into turns is removed (gyro and speed given, else None); whether the speed is fitted; and the down
    direction the start values level with (the lean removed at a given speed)."""
    d0 = down_in_body(roll_rad, pitch_rad)
    k = centripetal_direction(gyro_rad_s, d0) if (gyro_rad_s is not None and speed_m_s is not None) else None
    fit_speed = k is not None and isinstance(speed_m_s, str)
    if isinstance(speed_m_s, str) and speed_m_s != "fit":
        raise ValueError(f"speed_m_s must be a number, an array or 'fit', not {speed_m_s!r}")
    d_fixed = corrected_down(d0, k, speed_m_s) if (k is not None and not fit_speed) else d0
    return d0, k, fit_speed, d_fixed


def _best_start(problem, starts, hz_default: float, total: float, free_dip: bool, fit_speed: bool, robust: bool):
    """Stage 1: a few iterations from every start value (to convergence when there is one): (cost, solution,
    start name, start parameters) of the best."""
    best = None
    for start in starts:
        name, w0, h0 = start[0], start[1], start[2]
        hz0 = start[3] if len(start) > 3 else hz_default
        p0 = np.concatenate((w0.ravel(), h0, [hz0 / total] if free_dip else [], [0.0] if fit_speed else []))
        got = problem.solve(p0, 8 if len(starts) > 1 else 200, robust)
        if got is not None and (best is None or got[0] < best[0]):
            best = (got[0], got[1], name, p0)
    if best is None:
        raise BacksteppingError("the vertical-channel least squares did not converge from any start value")
    return best


def _fit_result(problem, sol, jac, start_name: str, total: float, free_dip: bool, fit_speed: bool, sig_f: float,
                sig_v: float) -> VerticalChannelFit:
    """The fit at the solution: W, h, H_z, the residuals' RMS in µT (magnitude, vertical) and whitened, and the
    data residuals' Jacobian with its column names."""
    n = problem.n
    w, h, hz, _ = problem.unpack(sol.x)
    r = sol.fun[:2 * n]
    jd = jac(sol.x)[:2 * n]
    names = list(_PARAM_NAMES) + (["sin_dip"] if free_dip else []) + (["speed_m_s"] if fit_speed else [])
    speed = float(sol.x[problem.i_speed]) if fit_speed else None
    return VerticalChannelFit(w, h, total, hz, free_dip, float(np.sqrt(np.mean((r[:n] * sig_f) ** 2))),
                              float(np.sqrt(np.mean((r[n:] * sig_v) ** 2))), float(np.sqrt(np.mean(r**2))),
                              jd, names, start_name, int(sol.nfev), bool(sol.success), str(sol.message), speed,
                              np.array(r[n:]))


class _VerticalChannelProblem:
    """The least squares of `fit_vertical_channel` for one data set: the parameters p = (W row by row, h,
    [sin δ if the dip is free], [the forward speed if fitted]), the whitened residuals with the prior and their
    Jacobian, and a solve from a start value."""

    def __init__(self, m, d0, k, d_fixed, total, vertical_ut, fit_speed, sig_f, sig_v, prior_sigma):
        self.m, self.d0, self.k, self.d_fixed = m, d0, k, d_fixed
        self.n = m.shape[0]
        self.total, self.vertical_ut = total, vertical_ut
        self.free_dip = vertical_ut is None
        self.fit_speed = fit_speed
        self.sig_f, self.sig_v, self.prior_sigma = sig_f, sig_v, prior_sigma
        self.i_dip = 12 if self.free_dip else None
        self.i_speed = (12 + (1 if self.free_dip else 0)) if fit_speed else None
        self.npar = 12 + (1 if self.free_dip else 0) + (1 if fit_speed else 0)

    def unpack(self, p):
        """(W, h, H_z, the down vector per sample) of the parameters p."""
        hz = p[self.i_dip] * self.total if self.free_dip else float(self.vertical_ut)
        d = corrected_down(self.d0, self.k, p[self.i_speed]) if self.fit_speed else self.d_fixed
        return p[:9].reshape(3, 3), p[9:12], hz, d

    def make_fun(self, p0):
        """The residual function (with the prior centred on p0) and its Jacobian, for least_squares."""
        m, n, npar, total = self.m, self.n, self.npar, self.total
        sig_f, sig_v, free_dip, fit_speed = self.sig_f, self.sig_v, self.free_dip, self.fit_speed
        i_dip, i_speed, d0, k, unpack = self.i_dip, self.i_speed, self.d0, self.k, self.unpack
        prior_w = np.zeros(npar)
        prior_w[:9] = 1.0 / self.prior_sigma
        if free_dip:
            prior_w[i_dip] = 1.0 / 2.0          # sin δ in [−1, 1]: essentially free
        if fit_speed:
            prior_w[i_speed] = 1.0 / PRIOR_SIGMA_SPEED_M_S

        def fun(p):
            w, h, hz, d = unpack(p)
            c = (m - h) @ w.T
            nc = np.linalg.norm(c, axis=1)
            return np.concatenate(((nc - total) / sig_f, (np.einsum("ij,ij->i", c, d) - hz) / sig_v,
                                   (p - p0) * prior_w))

        def jac(p):
            w, h, _, d = unpack(p)
            e = m - h
            c = e @ w.T
            nc = np.linalg.norm(c, axis=1)
            u = c / nc[:, None]
            j = np.zeros((2 * n + npar, npar))
            j[:n, :9] = (u[:, :, None] * e[:, None, :]).reshape(n, 9) / sig_f
            j[:n, 9:12] = -(u @ w) / sig_f
            j[n:2 * n, :9] = (d[:, :, None] * e[:, None, :]).reshape(n, 9) / sig_v
            j[n:2 * n, 9:12] = -(d @ w) / sig_v
            if free_dip:
                j[n:2 * n, i_dip] = -total / sig_v
            if fit_speed:
                un = d0 + p[i_speed] * k / STANDARD_GRAVITY_M_S2
                norm = np.linalg.norm(un, axis=1, keepdims=True)
                dd = (k / STANDARD_GRAVITY_M_S2 - d * np.einsum("ij,ij->i", d, k / STANDARD_GRAVITY_M_S2)[:, None]) / norm
                j[n:2 * n, i_speed] = np.einsum("ij,ij->i", c, dd) / sig_v
            j[2 * n:, :] = np.diag(prior_w)
            return j

        return fun, jac

    def solve(self, p0, max_nfev, robust):
        """(data cost, least_squares solution, Jacobian) from p0, or None when it failed."""
        from scipy.optimize import least_squares

        fun, jac = self.make_fun(p0)
        try:
            if robust:
                sol = least_squares(fun, p0, jac=jac, method="trf", x_scale="jac", max_nfev=max_nfev,
                                    loss="soft_l1", f_scale=3.0)
            else:   # MINPACK LM (QR): much cheaper per iteration than TRF's SVD
                sol = least_squares(fun, p0, jac=jac, method="lm", x_scale="jac", max_nfev=max_nfev)
        except (ValueError, np.linalg.LinAlgError):
            return None
        cost = float(np.sum(sol.fun[:2 * self.n] ** 2))
        return (cost, sol, jac) if np.isfinite(cost) else None


def _start_values(m, d_fixed, total, hz_guesses, free_dip, init) -> list[tuple]:
    """The start values (name, W, h[, H_z]): the given one, the levelled conic for each dip guess, and the
    ellipsoid fit (with each dip guess when the dip is free)."""
    starts = []
    if init is not None:
        starts.append(("given", np.asarray(init[0], dtype=np.float64), np.asarray(init[1], dtype=np.float64)))
    ell = _ellipsoid_init(m, total)
    for hz0 in hz_guesses:
        lev = _conic_init(m, d_fixed, total, hz0)
        if lev is not None:
            starts.append((f"level (dip {math.degrees(math.asin(max(-1, min(1, hz0 / total)))):.0f}°)", *lev, hz0))
    if ell is not None:
        for hz0 in (hz_guesses if free_dip else hz_guesses[:1]):
            starts.append(("ellipsoid", *ell, hz0))
    if not starts:
        raise BacksteppingError("no start value: the horizontal components do not trace an ellipse "
                                "(turn the vehicle through a full circle)")
    return starts


def predicted_heading_std_deg(fit: VerticalChannelFit, tilt_envelope_deg: float, *,
                              prior_sigma: float = PRIOR_SIGMA_SOFT_IRON, n_headings: int = 12,
                              covariance_inflation: float = 1.0) -> dict:
    """Propagate the fit's parameter covariance (data + the weak prior) to the tilt-compensated heading on a
    grid of attitudes (every 360/n_headings° of heading; level and ±tilt_envelope in roll and in pitch). Returns
    the 1σ of the constant heading offset (what a heading reference would remove) and the RMS 1σ of the
    heading-dependent part. `covariance_inflation` scales the data's covariance: the residuals are weighted as
    independent per sample, and when they are not (a levelling error correlated over seconds) the data hold fewer
    independent samples than rows (levelling_error.py)."""
    j = fit.jacobian
    npar = j.shape[1]
    info = j.T @ j * (1.0 / (max(fit.whitened_rms, 1.0) ** 2 * covariance_inflation))
    prior = np.zeros(npar)
    prior[:9] = 1.0 / prior_sigma**2
    for i, name in enumerate(fit.names):
        if name == "sin_dip":
            prior[i] = 0.25
        elif name == "speed_m_s":
            prior[i] = 1.0 / PRIOR_SIGMA_SPEED_M_S**2
    cov = np.linalg.pinv(info + np.diag(prior))
    hh = math.sqrt(max(fit.total_ut**2 - fit.vertical_ut**2, 0.0))
    t = math.radians(tilt_envelope_deg)
    atts = [(r, p) for r, p in ((0, 0), (t, 0), (-t, 0), (0, t), (0, -t))]
    psi = np.radians(np.arange(n_headings) * 360.0 / n_headings)
    roll = np.repeat([a[0] for a in atts], psi.size)
    pitch = np.repeat([a[1] for a in atts], psi.size)
    yaw = np.tile(psi, len(atts))
    cbn = euler_to_dcm(roll, pitch, yaw)
    b = np.einsum("nji,j->ni", cbn, np.array([hh, 0.0, fit.vertical_ut]))   # C_n^b · H^n
    winv = np.linalg.inv(fit.soft_iron)
    raw = b @ winv.T + fit.hard_iron_ut
    p0 = np.concatenate((fit.soft_iron.ravel(), fit.hard_iron_ut, [fit.vertical_ut / fit.total_ut] if fit.free_dip else [],
                         [fit.speed_m_s] if fit.speed_m_s is not None else []))

    def heading(p):
        w, h = p[:9].reshape(3, 3), p[9:12]
        return np.radians(magnetic_heading_deg((raw - h) @ w.T, roll, pitch))

    base = heading(p0)
    grad = np.zeros((base.size, npar))
    for k in range(npar):
        step = 1e-6 * max(1.0, abs(p0[k]))
        dp = np.zeros(npar)
        dp[k] = step
        grad[:, k] = wrap_pi(heading(p0 + dp) - base) / step
    gm = grad.mean(axis=0)
    gv = grad - gm
    offset = math.degrees(math.sqrt(max(gm @ cov @ gm, 0.0)))
    varying = math.degrees(math.sqrt(max(np.mean(np.einsum("ij,jk,ik->i", gv, cov, gv)), 0.0)))
    return {"offset_std_deg": offset, "heading_dependent_std_deg": varying, "envelope_tilt_deg": tilt_envelope_deg}
