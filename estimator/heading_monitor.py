"""The aided estimator's heading checks: is the magnetometer consistent with the GNSS, how much is it trusted,
and what is its remaining (iron) error — run at the GNSS rate beside `ins`'s compiled step.

Two small parts, each with a named state:

`IronLearner`: a 3-state Kalman filter for the hard iron left after the calibration (body frame, µT), learned
while the GNSS holds the heading: m_body = C_bnᵀ B_wmm + b + v, with C_bn the filter's attitude and B_wmm the
World Magnetic Model at the filter's position. Every axis is observed, the vertical one through the WMM
vertical intensity (what the back-stepping fit's vertical channel uses): a level vehicle learns the z offset
from the known vertical field, the horizontal ones from the known heading. The noise carries the attitude
uncertainty (J P_θθ Jᵀ, J = C_bnᵀ [B×]) and an allowance for what a hard iron cannot explain (unmodelled soft
iron, local anomalies), inflated for its correlation time — compare ArduPilot's `COMPASS_LEARN=3`
(`mag_cal_fixed_yaw`, one sample, no residual check) and EKF3/EKF2's body-field states.

`HeadingMonitor`: the magnetometer heading against the filter's heading (innovation, NIS) and against the
Gaussian-sum GNSS yaw when it is valid (PX4 `mag_heading_consistent`, EKF3 yaw test ratio, EKF-GSF
emergency reset). A magnetometer that disagrees beyond the stated uncertainties for `reject_checks` checks in a
row is rejected; the heading σ is raised to cover the disagreement *before* anything moves; when the GSF yaw is
valid and the filter's yaw is outside their joint 3σ, the yaw is reset to it (counted, capped, spaced). The
magnetometer re-enters only after its learned correction has been consistent for `reentry_s`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.estimate import HeadingState


def wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass
class IronLearner:
    """Learned hard iron on top of the calibration (body frame, µT) and its covariance (µT²)."""

    prior_sigma_ut: float
    offset_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cov_ut2: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    updates: int = 0

    def __post_init__(self):
        if not np.any(self.cov_ut2):
            self.cov_ut2 = np.eye(3) * self.prior_sigma_ut ** 2

    def reset(self) -> None:
        self.offset_ut = np.zeros(3)
        self.cov_ut2 = np.eye(3) * self.prior_sigma_ut ** 2
        self.updates = 0

    def set(self, offset_ut, cov_ut2) -> None:
        off = np.asarray(offset_ut, dtype=float).reshape(3)
        cov = np.asarray(cov_ut2, dtype=float).reshape(3, 3)
        if not (np.all(np.isfinite(off)) and np.all(np.isfinite(cov))):
            raise ValueError("learned iron must be finite")
        cov = 0.5 * (cov + cov.T)
        if np.any(np.linalg.eigvalsh(cov) <= 0.0):
            raise ValueError("learned iron covariance must be positive definite")
        self.offset_ut = off
        self.cov_ut2 = cov
        self.updates = 0

    @property
    def sigma_ut(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov_ut2), 0.0))

    def update(self, mag_body_ut, c_bn, field_ned_ut, p_att_rad2, noise_ut: float, inflate: float) -> float:
        """One measurement m = C_bnᵀ B + b; returns its NIS (3 dof). `noise_ut`: 1σ per axis of what the hard iron
        does not explain; `inflate`: the correlation-time factor applied to the whole measurement noise."""
        c = np.asarray(c_bn, dtype=float)
        b_ned = np.asarray(field_ned_ut, dtype=float)
        predicted = c.T @ b_ned + self.offset_ut
        nu = np.asarray(mag_body_ut, dtype=float) - predicted
        j = c.T @ skew(b_ned)                      # ∂(C_trueᵀ B)/∂δθ with C_true = (I + [δθ×]) C
        r = (j @ p_att_rad2 @ j.T + np.eye(3) * noise_ut ** 2) * inflate
        s = self.cov_ut2 + r
        s_inv = np.linalg.inv(s)
        k = self.cov_ut2 @ s_inv
        self.offset_ut = self.offset_ut + k @ nu
        ikh = np.eye(3) - k
        self.cov_ut2 = ikh @ self.cov_ut2 @ ikh.T + k @ r @ k.T
        self.updates += 1
        return float(nu @ s_inv @ nu)

    def heading_variance(self, c_bn, field_horizontal_ned) -> float:
        """Variance of the magnetometer heading that the learned offset's uncertainty causes (rad²): the heading
        of the horizontal field moves by g·δm_n, g = (−m_e, m_n, 0)/H², δm_n = −C_bn δb."""
        mn, me = float(field_horizontal_ned[0]), float(field_horizontal_ned[1])
        h2 = mn * mn + me * me
        if h2 <= 0.0:
            return math.inf
        g = np.array([-me, mn, 0.0]) / h2
        a = g @ np.asarray(c_bn, dtype=float)
        return float(a @ self.cov_ut2 @ a)


@dataclass
class MonitorDecision:
    mag_use: bool
    mag_bias_var_rad2: float          # the magnetometer heading's slowly varying error variance for the filter
    yaw_var_floor_rad2: float         # raise the filter's yaw variance to at least this (0: leave it)
    reset_yaw_to_rad: float | None    # reset the filter's yaw (true) to this
    reset_yaw_var_rad2: float


@dataclass
class HeadingMonitor:
    """State of the consistency checks (see the module docstring)."""

    calibration_sigma_rad: float      # what the calibration says its heading error is (1σ)
    gate_sigma: float = 3.0
    reject_checks: int = 3
    reentry_s: float = 20.0
    lowpass_tau_s: float = 5.0
    max_resets: int = 3
    reset_spacing_s: float = 20.0
    trusted_sigma_rad: float = math.radians(3.0)
    state: HeadingState = HeadingState.UNKNOWN
    mag_rejected: bool = False
    failures: int = 0
    consistent_s: float = 0.0
    lowpassed_innovation_rad: float = 0.0
    disagreement_rad: float = math.nan
    resets: int = 0
    last_reset_t_s: float = -math.inf
    last_t_s: float = math.nan
    learning: bool = False
    reset_velocity_nis: float = 6.0
    lowpassed_velocity_nis: float = 0.0

    def mag_sigma_rad2(self, iron_var_rad2: float, noise_var_rad2: float) -> float:
        return self.calibration_sigma_rad ** 2 + iron_var_rad2 + noise_var_rad2

    def check(self, t_s: float, yaw_rad: float, yaw_var_rad2: float, mag_yaw_rad: float, mag_var_rad2: float,
              gsf_yaw_rad: float, gsf_var_rad2: float, gsf_valid: bool, heading_observable: bool,
              velocity_nis: float = math.nan) -> MonitorDecision:
        """One check at a fused GNSS fix. yaw: the filter's (true); mag_yaw: the heading the magnetometer (with
        the learned iron removed) gives at the filter's tilt, NaN when it has none; mag_var: its variance
        (calibration + learned iron + noise); gsf_*: the Gaussian-sum yaw; heading_observable: the filter's yaw
        σ is small enough that the GNSS holds the heading (iron learning and magnetometer re-entry need it);
        velocity_nis: the filter's last GNSS velocity NIS (2–3 dof) — a reset to the GNSS yaw also needs the
        filter's own velocity fusion to show the heading is wrong (low-passed NIS above `reset_velocity_nis`),
        as EKF3's realignYawGPS needs a failing velocity test."""
        dt = 0.0 if math.isnan(self.last_t_s) else max(0.0, t_s - self.last_t_s)
        self.last_t_s = t_s
        floor = 0.0
        reset_to = None
        reset_var = 0.0
        have_mag = math.isfinite(mag_yaw_rad)
        innovation = wrap_pi(mag_yaw_rad - yaw_rad) if have_mag else 0.0
        k = 1.0 - math.exp(-dt / self.lowpass_tau_s) if dt > 0.0 else 1.0
        self.lowpassed_innovation_rad += k * (innovation - self.lowpassed_innovation_rad)
        self.disagreement_rad = wrap_pi(mag_yaw_rad - gsf_yaw_rad) if (have_mag and gsf_valid) else math.nan
        if have_mag:
            s_ins = yaw_var_rad2 + mag_var_rad2
            bad = innovation ** 2 > self.gate_sigma ** 2 * s_ins or \
                self.lowpassed_innovation_rad ** 2 > self.gate_sigma ** 2 * s_ins
            if gsf_valid:
                # the GNSS yaw alone does not reject the magnetometer (a bank whose tilt is wrong in a coordinated
                # turn is confidently wrong): it must agree with the filter's own innovation being beyond 1σ
                bad = bad or (self.disagreement_rad ** 2 > self.gate_sigma ** 2 * (gsf_var_rad2 + mag_var_rad2)
                              and innovation ** 2 > s_ins)
        else:
            bad = False
        if bad:
            self.failures += 1
            self.consistent_s = 0.0
        else:
            self.failures = 0
            self.consistent_s += dt
        if not self.mag_rejected and have_mag and self.failures >= self.reject_checks:
            # σ first: cover what the magnetometer may already have pulled the heading by (its low-passed
            # innovation: a step just seen has not moved the filter yet) and the disagreement with the GNSS yaw
            self.mag_rejected = True
            floor = self.lowpassed_innovation_rad ** 2 + yaw_var_rad2
            if gsf_valid:
                floor = max(floor, wrap_pi(yaw_rad - gsf_yaw_rad) ** 2 + gsf_var_rad2)
        elif self.mag_rejected and have_mag and heading_observable and self.consistent_s >= self.reentry_s \
                and mag_var_rad2 < self.trusted_sigma_rad ** 2:
            self.mag_rejected = False
        if math.isfinite(velocity_nis):
            self.lowpassed_velocity_nis += k * (min(velocity_nis, 100.0) - self.lowpassed_velocity_nis)
        if gsf_valid and self.lowpassed_velocity_nis > self.reset_velocity_nis and (self.mag_rejected or not have_mag or mag_var_rad2 > self.trusted_sigma_rad ** 2):
            d = wrap_pi(gsf_yaw_rad - yaw_rad)
            if d * d > self.gate_sigma ** 2 * (yaw_var_rad2 + gsf_var_rad2) and self.resets < self.max_resets \
                    and t_s - self.last_reset_t_s >= self.reset_spacing_s:
                reset_to = gsf_yaw_rad
                reset_var = gsf_var_rad2
                self.resets += 1
                self.last_reset_t_s = t_s
        self.learning = heading_observable and (self.mag_rejected or mag_var_rad2 > self.trusted_sigma_rad ** 2)
        return MonitorDecision(not self.mag_rejected, mag_var_rad2 if not self.mag_rejected else 0.0, floor,
                               reset_to, reset_var)

    def heading_state(self, yaw_sigma_rad: float, initialising: bool, aided: bool, unknown_sigma_rad: float,
                      mag_var_rad2: float) -> HeadingState:
        if initialising or not (yaw_sigma_rad <= unknown_sigma_rad):
            return HeadingState.UNKNOWN
        if aided and self.mag_rejected:
            return HeadingState.LEARNING if self.learning else HeadingState.GNSS_ONLY
        if aided and mag_var_rad2 > self.trusted_sigma_rad ** 2:
            return HeadingState.LEARNING if self.learning else HeadingState.GNSS_ONLY
        if self.mag_rejected:
            return HeadingState.UNKNOWN
        return HeadingState.MAGNETOMETER
