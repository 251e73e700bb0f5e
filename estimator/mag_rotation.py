"""The vertical gyro bias from how the magnetometer's field turns in the body, which no vehicle iron changes.

The magnetometer measures m = A·v + b: v = C_bnᵀ·B the Earth field in the body frame, A = I + D the soft iron and
b the hard iron, both fixed to the body. Between two instants m₁ − m₀ = A·(v₁ − v₀): the hard iron cancels in the
difference and the soft iron (a few % of scale and coupling, `IronLearner`'s D) only scales it. So the *turning*
of the field is a measurement of how the body turned, good to a few % of the angle turned, whether or not the
magnetometer's heading is calibrated: on a straight leg, where the GNSS says nothing of the yaw, it sees the
vertical gyro bias that would otherwise turn the heading unseen (docs/estimator.md, "heading9").

A window of heading checks (GNSS rate) is compared with the heading the gyro gives from the window's start:
v_k = C_kᵀ·B with C_k the filter's attitude at check k — its tilt, which the GNSS holds — turned about down to the
heading of C₀·ΔC_k, ΔC_k the gyro's body rotation since the start (made with the bias estimate b̂_z of each
interval). What the measured change does not explain, projected on the direction a turn about down moves the
field, w = A·C_kᵀ·(B × e_z), is the heading the gyro got wrong since the start: φ_k = −(b_z·t_k − Σ b̂_j Δt_j).
With the bias changes within the window moved to the newest estimate b̂_end, its least-squares slope against time
(free intercept: the first sample's noise) is b_z − b̂_end. Its variance: the scatter about the line (inflated
for its correlation from check to check), the gyro's white noise (the heading is a random walk), and what the
known-to-δ soft iron, gyro scale, attitude of the start and the change of the filter's tilt over the window (at
the dip's tangent) make of the window's motion. A window ends after `window_s`, or when the vehicle has turned
by `max_turn_rad` (the soft-iron and scale terms grow with the turn), and is used only while the filter's tilt
is known to `max_att_sigma_rad` at its start (the direction of B in the body). The start attitude's error enters
per body axis, at the filter's covariance then: a heading error at the start turns v₀ and every v_k alike about
down, so the fit hardly sees it (its slope is small), while a tilt error tips B's large vertical part into the
horizontal as the vehicle turns; the largest σ on every axis would give a window started while the heading is
still being found (σ of degrees, the tilt's tenths) a tilt term of the heading's size, and wait for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numba import njit

_DOWN = np.array([0.0, 0.0, 1.0])
_EYE3 = np.eye(3)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of two 3-vectors: np.cross's products and differences in its order (the same float64 result) without
    its broadcasting set-up, which costs many times the arithmetic (four crosses at each window's start)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _heading(c_bn: np.ndarray) -> float:
    return math.atan2(c_bn[1, 0], c_bn[0, 0])


def _turn(rot: np.ndarray) -> float:
    """The turn about body z of the rotation body now → body then (small tilts), rad."""
    return math.atan2(rot[1, 0], rot[0, 0])


def window_tilt_sigma_rad(p_tilt_rad2: np.ndarray, p_tilt_bias: np.ndarray, p_bias: np.ndarray) -> float:
    """The 1σ of the filter's tilt error that can move between a window's ends (rad), for the fit's tilt term: the
    largest of the horizontal tilt errors' variances (p_tilt, 2×2: δθ_N, δθ_E) less what the accelerometer bias
    explains (p_tilt_bias 2×3, p_bias 3×3: its covariance with the body-frame bias and the bias's own), the Schur
    complement p_tilt − p_tilt_bias · p_bias⁻¹ · p_tilt_biasᵀ.

    Why not the whole tilt σ: while the vehicle holds its heading (a window ends at `max_turn_rad` of turn) a
    horizontal accelerometer bias and a tilt are one error to the GNSS (the specific force it reads g·δθ + b: the
    aided filter separates them only by turning; Groves, Principles of GNSS, Inertial, and Multisensor Integrated
    Navigation Systems, 2nd ed., §14.2.1), and the bias's error lasts far longer than a window (its Gauss–Markov time
    and its turn-on part), so the tilt error it explains is the same at both ends and leaves no trend. Only the
    tilt error uncorrelated with the bias error (the gyro's walk between GNSS corrections and the corrections' own
    noise) can change across the window: the Gaussian conditional of the one given the other."""
    p_tb = np.asarray(p_tilt_bias, dtype=float)
    p_b = np.asarray(p_bias, dtype=float)
    try:
        gain = np.linalg.solve(p_b, p_tb.T)
    except np.linalg.LinAlgError:        # a bias state held (no variance): what it cannot explain stays
        gain = np.linalg.pinv(p_b, hermitian=True) @ p_tb.T
    unexplained = np.asarray(p_tilt_rad2, dtype=float) - p_tb @ gain
    return math.sqrt(max(float(unexplained[0, 0]), float(unexplained[1, 1]), 0.0))


@njit(cache=True, inline="always")
def rotation_vector_step(theta, gx, gy, gz, dt_s):
    """Add one gyro sample (rad/s) to the rotation vector θ of an interval (a float64 array of 3, in the compiled
    step: per sample), in place, with the coning term ½ θ × Δθ (Bortz; Savage, Strapdown Analytics §7.1): a
    vehicle rolling and pitching out of phase turns about z."""
    ax, ay, az = gx * dt_s, gy * dt_s, gz * dt_s
    tx, ty, tz = theta
    theta[0] = tx + ax + 0.5 * (ty * az - tz * ay)
    theta[1] = ty + ay + 0.5 * (tz * ax - tx * az)
    theta[2] = tz + az + 0.5 * (tx * ay - ty * ax)


@dataclass
class MagRotationBias:
    """One window of magnetometer samples against the gyro's heading; `add` returns the vertical gyro bias
    correction b_z − b̂_z (rad/s) and its variance when a window completes."""

    gyro_noise_rad_s_rthz: float = 0.0  # the gyro's white noise (the filter's own figure)
    window_s: float = 30.0
    max_turn_rad: float = math.radians(5.0)
    min_samples: int = 30
    min_span_s: float = 8.0
    max_att_sigma_rad: float = math.radians(5.0)   # the largest tilt 1σ at a window's start
    scale_sigma: float = 0.003          # gyro scale-factor uncertainty, dimensionless
    span_s: float = 0.0                 # the last fitted window's length, s
    # the last fitted window's variance, term by term ((rad/s)²): the scatter about the line (inflated for its
    # correlation), the gyro scale, the soft iron, the start attitude, the gyro's white noise and the tilt's change;
    # then the residuals' check-to-check correlation r₁ and the tilt 1σ at the start (rad) (for a reader:
    # bench/yaw_drift_trace.py --terms)
    terms: tuple = ()
    t0_s: float = math.nan
    m0_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v0_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    c0: np.ndarray = field(default_factory=lambda: np.eye(3))
    b_ned_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rot: np.ndarray = field(default_factory=lambda: np.eye(3))    # ΔC: body now → body at the start
    bias_dt: float = 0.0                # Σ b̂_j Δt_j since the start, rad
    att_cov_body_rad2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # the start's, body axes
    start_tilt_sigma_rad: float = 0.0   # the filter's larger tilt 1σ at the window's start
    tilt_sigma_rad: float = 0.0         # the filter's tilt 1σ at the last fitted window's end
    # the filter's tilt 1σ at the latest check, or the function that gives it (`add`)
    _tilt_sigma_now: float | Callable[[], float] = field(default=0.0, init=False, repr=False)
    samples: list = field(default_factory=list)   # (t, φ, Σ b̂Δt, turn, soft-iron and attitude sensitivities)
    # what stays the same through a window, made at its start: B × e_z (the direction a turn about down moves the
    # field, in NED) and e_i × v₀ for the three axes (how v₀ moves with an attitude error about each)
    turn_ned_ut: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)
    v0_moves_ut: tuple = field(default=(), repr=False)

    def restart(self) -> None:
        self.t0_s = math.nan

    def add(self, t_s: float, mag_ut, c_bn, b_ned_ut, step_rot, bias_z_rad_s: float, dt_s: float,
            soft_iron: np.ndarray, soft_sigma: float, att_cov_ned_rad2: np.ndarray,
            tilt_sigma_rad: float | Callable[[], float]) -> tuple[float, float] | None:
        """One heading check: the magnetometer (body, µT, calibration in force), the filter's attitude c_bn and
        the Earth field (NED, µT), the gyro's body rotation since the last check (body now → body then) made with
        the bias estimate b̂_z over dt_s, the learned soft iron A and the 1σ of its elements, the filter's
        attitude error covariance (3×3, NED: δθ_N, δθ_E, δθ_D with C_true = (I + [δθ×])·C_est; read at a window's
        start) and the 1σ of its tilt error that can move over a window (window_tilt_sigma_rad), or a function
        that gives it: it is asked only when this check completes a window (the fit's tilt term), since working it
        out is a 3×3 solve. Returns (b_z − b̂_z, its variance, rad/s) when a window completes, else None."""
        m = np.asarray(mag_ut, dtype=float)
        c_bn = np.asarray(c_bn, dtype=float)
        if not math.isfinite(self.t0_s):
            self._start(t_s, m, c_bn, b_ned_ut, att_cov_ned_rad2, tilt_sigma_rad)
            return None
        self._tilt_sigma_now = tilt_sigma_rad
        rot = self.rot @ np.asarray(step_rot, dtype=float)
        if abs(_turn(rot)) > self.max_turn_rad:
            # the vehicle turned: fit the window up to the last check, start a new one here
            result = self._fit(bias_z_rad_s, soft_sigma)
            self._start(t_s, m, c_bn, b_ned_ut, att_cov_ned_rad2, tilt_sigma_rad)
            return result
        self.rot = rot
        self.bias_dt += bias_z_rad_s * dt_s
        # the filter's tilt now, the gyro's heading: its attitude turned about down to C₀·ΔC's heading
        dpsi = _heading(self.c0 @ rot) - _heading(c_bn)
        cz, sz = math.cos(dpsi), math.sin(dpsi)
        c_k = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]]) @ c_bn
        c_kt = c_k.T
        v = c_kt @ self.b_ned_ut
        w = soft_iron @ (c_kt @ self.turn_ned_ut)     # ∂m/∂(a turn about down)
        ww = float(w @ w)
        if ww < 1.0:            # no horizontal field to turn (µT²)
            self.restart()
            return None
        d = v - self.v0_ut
        rho = (m - self.m0_ut) - soft_iron @ d
        # how φ moves with an error δA of the soft iron (∂φ/∂δA_ij = w_i d_j / |w|²) and with an error ε of the
        # attitude v₀ was taken at (v₀ → v₀ + ε × v₀)
        rt_i = rot.T - _EYE3
        att = np.array([-(soft_iron @ (rt_i @ e_v0)) @ w / ww for e_v0 in self.v0_moves_ut])
        self.samples.append((t_s, float(rho @ w) / ww, self.bias_dt, _turn(rot),
                             (w[:, None] * d[None, :]).reshape(9) / ww, att))
        if t_s - self.t0_s < self.window_s:
            return None
        result = self._fit(bias_z_rad_s, soft_sigma)
        self.restart()
        return result

    def _start(self, t_s, m, c_bn, b_ned_ut, att_cov_ned_rad2, tilt_sigma_rad) -> None:
        self.t0_s = t_s
        self.m0_ut = m.copy()
        self.c0 = c_bn.copy()
        self.b_ned_ut = np.asarray(b_ned_ut, dtype=float).copy()
        self.v0_ut = c_bn.T @ self.b_ned_ut
        self.turn_ned_ut = _cross(self.b_ned_ut, _DOWN)
        self.v0_moves_ut = tuple(_cross(e, self.v0_ut) for e in _EYE3)
        self.rot = np.eye(3)
        self.bias_dt = 0.0
        # the attitude error in the body: C_true = C_est·(I + [ε×]), ε = C₀ᵀ·δθ
        p = np.asarray(att_cov_ned_rad2, dtype=float)
        self.att_cov_body_rad2 = c_bn.T @ p @ c_bn
        self.start_tilt_sigma_rad = math.sqrt(max(float(p[0, 0]), float(p[1, 1]), 0.0))
        self._tilt_sigma_now = tilt_sigma_rad
        self.samples = []

    def _fit(self, bias_end_rad_s: float, soft_sigma: float) -> tuple[float, float] | None:
        n = len(self.samples)
        if n < self.min_samples or self.samples[-1][0] - self.t0_s < self.min_span_s \
                or self.start_tilt_sigma_rad > self.max_att_sigma_rad:
            return None
        t = np.array([s[0] for s in self.samples]) - self.t0_s
        phi = np.array([s[1] for s in self.samples])
        bias_dt = np.array([s[2] for s in self.samples])
        turn = np.array([s[3] for s in self.samples])
        soft = np.array([s[4] for s in self.samples])
        att = np.array([s[5] for s in self.samples])
        self.span_s = float(t[-1])
        # −φ_k + Σ b̂_j Δt_j − b̂_end·t_k = (b_z − b̂_end)·t_k: each interval turned with its own b̂_j
        y = -phi + bias_dt - bias_end_rad_s * t
        tc = t - t.mean()
        stt = float(tc @ tc)
        if stt <= 0.0:
            return None
        slope = float(tc @ (y - y.mean())) / stt
        res = y - y.mean() - slope * tc
        var = float(res @ res) / (n - 2) / stt
        # the scatter is not white (the vehicle rolls and pitches for seconds): the slope's variance grows by
        # (1 + r₁)/(1 − r₁) for residuals correlated r₁ from one check to the next (AR(1))
        r1 = min(max(float(res[1:] @ res[:-1]) / max(float(res @ res), 1e-30), 0.0), 0.95)
        var *= (1.0 + r1) / (1.0 - r1)
        scatter = var
        # a gyro scale and a soft iron known to δ, and the start attitude, through the window's motion
        turn_slope = float(tc @ (turn - turn.mean())) / stt
        soft_slopes = tc @ (soft - soft.mean(axis=0)) / stt
        att_slopes = tc @ (att - att.mean(axis=0)) / stt
        scale = (self.scale_sigma * turn_slope) ** 2
        soft_iron = soft_sigma ** 2 * float(soft_slopes @ soft_slopes)
        attitude = float(att_slopes @ self.att_cov_body_rad2 @ att_slopes)
        var += scale + soft_iron + attitude
        # the gyro's white noise makes the heading a random walk, which the scatter does not show: the
        # least-squares slope of a random walk of density q over T has variance 6 q² / (5 T)
        walk = 1.2 * self.gyro_noise_rad_s_rthz ** 2 / t[-1]
        var += walk
        # the filter's tilt, which gives v its dip, may have moved by up to √2 σ between the window's ends (σ: the
        # part of its error that can move, window_tilt_sigma_rad): at the dip's tangent (vertical over horizontal
        # field) it turns the magnetometer's heading
        now = self._tilt_sigma_now
        self.tilt_sigma_rad = now() if callable(now) else now
        b = self.b_ned_ut
        tan_dip = abs(float(b[2])) / max(math.hypot(float(b[0]), float(b[1])), 1e-6)
        tilt = (math.sqrt(2.0) * tan_dip * self.tilt_sigma_rad / t[-1]) ** 2
        var += tilt
        self.terms = (scatter, scale, soft_iron, attitude, walk, tilt, r1, self.start_tilt_sigma_rad)
        return slope, var
