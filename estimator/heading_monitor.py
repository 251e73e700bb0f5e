"""The aided estimator's heading checks: is the magnetometer consistent with the GNSS, how much is it trusted,
and what is its remaining (iron) error — run at the GNSS rate beside `ins`'s compiled step.

Two small parts, each with a named state:

`IronLearner`: a 12-state linear Kalman filter for the iron left after the calibration, learned while the GNSS
holds the heading: m_body = (I + D)·C_bnᵀ·B_wmm + b + v, with b the hard iron (body frame, µT), D the soft iron
(3×3), C_bn the filter's attitude and B_wmm the World Magnetic Model at the filter's position — linear in (b, D)
for a known attitude. The Earth field is known in magnitude and direction, so every combination the motion
rotates is observed (the vertical one through the WMM vertical intensity, what the back-stepping fit's
vertical channel uses): a level vehicle that turns learns b's horizontal part, the horizontal 2×2 block of D
and D_zx, D_zy; D's third column multiplies the constant vertical field and is seen only together with b, so
that split stays at its prior (and costs no heading while the vehicle stays level: the covariance carries their
correlation); banking and pitching separate them. The noise carries the attitude uncertainty (J P_θθ Jᵀ,
J = (I + D) C_bnᵀ [B×]) and an allowance for what the iron model does not explain (WMM and local anomalies),
inflated for its correlation time — compare ArduPilot's `COMPASS_LEARN=3` (`mag_cal_fixed_yaw`: offsets only,
one sample, no residual check) and EKF3/EKF2's body-field states (offsets only).

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

from ahrsd.core.angles import wrap_pi_float as wrap_pi
from ahrsd.core.estimate import HeadingState

from .mag_step import MagStepDetector

N_IRON = 12
"""IronLearner's states: the hard iron b (3, µT) then the soft iron D row by row (9)."""
_YAW = 2
"""The attitude error's component about the vertical (the yaw error)."""


def _across(direction: np.ndarray) -> np.ndarray:
    """2×3: an orthonormal basis of the plane perpendicular to `direction` (rows)."""
    u = np.asarray(direction, dtype=float)
    n = float(np.linalg.norm(u))
    if n <= 0.0:
        return np.eye(3)[:2]
    w, v = np.linalg.eigh(np.eye(3) - np.outer(u, u) / (n * n))
    return v[:, np.argsort(w)[1:]].T


def largest(values) -> float:
    """The largest of the floats as np.max takes it (NaN if any is NaN), without numpy's array set-up: a few floats
    at every heading check."""
    top = -math.inf
    for v in values:
        if v != v:
            return math.nan
        if v > top:
            top = v
    return top


_EYE3 = np.eye(3)
_EYE_IRON = np.eye(N_IRON)
_LEVEL_HEADINGS = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
"""The headings IronLearner.level_heading_variance looks at (rad)."""


def skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _finite(value, shape) -> np.ndarray:
    a = np.asarray(value, dtype=float).reshape(shape)
    if not np.all(np.isfinite(a)):
        raise ValueError("learned iron must be finite")
    return a


def _positive_definite(value, n: int, semi: bool = False) -> np.ndarray:
    a = _finite(value, (n, n))
    a = 0.5 * (a + a.T)
    low = np.linalg.eigvalsh(a)
    if np.any(low < -1e-12 * max(1.0, float(np.max(np.abs(a))))) if semi else np.any(low <= 0.0):
        raise ValueError("learned iron covariance must be positive " + ("semi-definite" if semi else "definite"))
    return a


def _level_attitudes(yaw: np.ndarray) -> np.ndarray:
    """C_bn (k×3×3) of a level vehicle at each yaw (rad)."""
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], 1)


_LEVEL_FIELD_TERMS: dict = {}
"""`_level_field_terms` of each (field, yaw array) it was asked for, by their bytes: the heading checks ask for the
same few yaw arrays (_LEVEL_HEADINGS, the harmonic fit's yaws) at every learning step, at a field that changes every
~1 km."""


def _level_field_terms(field_ned_ut, yaw_rad) -> tuple[np.ndarray, np.ndarray]:
    """(g·C_bn, C_bnᵀ·B) of a level vehicle at each yaw (k×3 each, read only), g = (−B_E, B_N, 0)/H² the heading's
    gradient: the part of `IronLearner.level_heading_rows` that depends on the field and the yaws alone, made once
    per field and yaw array (the WMM field at the filter's position changes every ~1 km; the learner's iron, at
    every learning step)."""
    b = np.asarray(field_ned_ut, dtype=float)
    yaw = np.asarray(yaw_rad)
    key = (b.tobytes(), yaw.dtype.str, yaw.shape, yaw.tobytes())
    terms = _LEVEL_FIELD_TERMS.get(key)
    if terms is None:
        h2 = b[0] * b[0] + b[1] * b[1]
        g = np.array([-b[1], b[0], 0.0]) / h2
        c_bn = _level_attitudes(yaw)
        terms = (np.einsum("j,kji->ki", g, c_bn), np.einsum("kji,j->ki", c_bn, b))
        for t in terms:
            t.setflags(write=False)
        if len(_LEVEL_FIELD_TERMS) >= 16:     # a caller sweeping fields or yaws: keep the cache small
            _LEVEL_FIELD_TERMS.clear()
        _LEVEL_FIELD_TERMS[key] = terms
    return terms


@dataclass
class IronLearner:
    """Learned iron on top of the calibration: the hard iron b (body frame, µT) and the soft iron D
    (dimensionless, m = (I + D)·C_bnᵀ·B + b), with their joint covariance. `soft_prior_sigma` 0 learns the hard
    iron alone (the soft-iron states stay pinned at zero)."""

    prior_sigma_ut: float
    soft_prior_sigma: float = 0.0
    state: np.ndarray = field(default_factory=lambda: np.zeros(N_IRON))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((N_IRON, N_IRON)))
    updates: int = 0
    # (I + D)⁻¹ and level_heading_variance, kept with what they were computed from: the heading checks ask for
    # them several times a check, and after the learning (or without it) they do not change for hours
    _inverse: tuple = field(default=(None, None), init=False, repr=False, compare=False)
    _level_variance: tuple = field(default=(None, 0.0), init=False, repr=False, compare=False)
    last_gain: tuple = field(default=None, init=False, repr=False, compare=False)   # update's (K, H, j)
    offset_held: bool = False    # the heading offset is no longer learned against the yaw (`hold_offset`)

    def __post_init__(self):
        if not np.any(self.cov):
            self.cov = self._prior_cov()

    def _prior_cov(self) -> np.ndarray:
        return np.diag(np.r_[np.full(3, self.prior_sigma_ut ** 2), np.full(9, self.soft_prior_sigma ** 2)])

    def reset(self) -> None:
        self.state = np.zeros(N_IRON)
        self.cov = self._prior_cov()
        self.updates = 0
        self.offset_held = False

    def set(self, offset_ut, cov_ut2, soft_iron=None, soft_cov=None) -> None:
        """Start from a persisted hard iron and its covariance, and optionally the soft iron I + D and the 9×9
        covariance of D row by row (without them the soft iron goes back to its prior)."""
        off = _finite(offset_ut, (3,))
        cov = _positive_definite(cov_ut2, 3)
        soft = None if soft_iron is None else _finite(soft_iron, (3, 3))
        s_cov = None if soft_cov is None else _positive_definite(soft_cov, 9, semi=True)   # 0: soft iron not learned
        if soft is not None and abs(np.linalg.det(soft)) < 1e-3:
            raise ValueError("learned soft iron is singular")
        self.reset()
        self.state[0:3] = off
        self.cov[0:3, 0:3] = cov
        if soft is not None:
            self.state[3:] = (soft - np.eye(3)).reshape(9)
            if s_cov is not None:
                self.cov[3:, 3:] = s_cov

    @property
    def offset_ut(self) -> np.ndarray:
        return self.state[0:3].copy()

    @property
    def cov_ut2(self) -> np.ndarray:
        return self.cov[0:3, 0:3].copy()

    @property
    def sigma_ut(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.cov.diagonal()[0:3], 0.0))

    @property
    def soft_iron(self) -> np.ndarray:
        """I + D: what the body field is multiplied by before the hard iron adds."""
        return _EYE3 + self.state[3:].reshape(3, 3)

    @property
    def soft_iron_sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov[3:, 3:]), 0.0)).reshape(3, 3)

    @property
    def largest_soft_iron_sigma(self) -> float:
        """The largest element of `soft_iron_sigma` (NaN if any is NaN), read from the covariance's diagonal
        without building the 3×3: the square root is monotone, so the root of the largest variance is the
        largest root."""
        return math.sqrt(max(largest(self.cov.diagonal()[3:].tolist()), 0.0))

    @property
    def soft_iron_inverse(self) -> np.ndarray:
        return self._kept_inverse().copy()

    def _kept_inverse(self) -> np.ndarray:
        """(I + D)⁻¹, kept while D stays: the array itself, for the products here that only read it (the property
        hands out a copy)."""
        key = self.state[3:].tobytes()
        if self._inverse[0] != key:
            self._inverse = (key, np.linalg.inv(self.soft_iron))
        return self._inverse[1]

    def corrected(self, mag_ut) -> np.ndarray:
        """The body field the learned iron leaves: (I + D)⁻¹·(m − b)."""
        return self._kept_inverse() @ (np.asarray(mag_ut, dtype=float) - self.state[0:3])

    @staticmethod
    def _jacobian(field_body_ut) -> np.ndarray:
        """∂m/∂(b, D): I for the hard iron; m_i = Σ_j D_ij B_j for the soft iron (row-major D)."""
        h = np.zeros((3, N_IRON))
        h[:, 0:3] = _EYE3
        for i in range(3):
            h[i, 3 + 3 * i:6 + 3 * i] = field_body_ut
        return h

    def update(self, mag_body_ut, c_bn, field_ned_ut, p_att_rad2, noise_ut: float, inflate: float) -> float:
        """One measurement m = (I + D)·C_bnᵀ·B + b + v (linear in b and D for a known attitude); returns its NIS
        (3 dof; 2 once the offset is held, `hold_offset`). `noise_ut`: 1σ per axis of what the iron does not explain; `inflate`: the correlation-time
        factor applied to the whole measurement noise. A level vehicle turning sees the horizontal field rotate
        in the body frame (the 2×2 horizontal block and D_zx, D_zy observed) but a constant vertical field, so D's
        third column is seen only together with b: those combinations stay at their prior split."""
        c = np.asarray(c_bn, dtype=float)
        b_ned = np.asarray(field_ned_ut, dtype=float)
        field_body = c.T @ b_ned
        a = self.soft_iron
        predicted = a @ field_body + self.state[0:3]
        nu = np.asarray(mag_body_ut, dtype=float) - predicted
        j = a @ c.T @ skew(b_ned)                  # ∂(A C_trueᵀ B)/∂δθ with C_true = (I + [δθ×]) C
        r = (j @ p_att_rad2 @ j.T + _EYE3 * noise_ut ** 2) * inflate
        h = self._jacobian(field_body)
        if self.offset_held:
            # the limit of an unknown yaw (its variance without bound): only the two directions a yaw error
            # does not move are measured
            t = _across(j[:, _YAW])
            nu, r, h, j = t @ nu, t @ r @ t.T, t @ h, t @ j
        ph = self.cov @ h.T
        s = h @ ph + r
        s_inv = np.linalg.inv(s)
        k = ph @ s_inv
        self.state = self.state + k @ nu
        self.last_gain = (k, h, j)
        ikh = _EYE_IRON - k @ h
        self.cov = ikh @ self.cov @ ikh.T + k @ r @ k.T
        self.cov = 0.5 * (self.cov + self.cov.T)
        self.updates += 1
        return float(nu @ s_inv @ nu)

    def hold_offset(self, field_ned_ut, yaw_var_rad2: float) -> bool:
        """Whether the updates no longer learn against the filter's yaw, holding it so from here (until `reset`,
        `set` or `release_offset`) once the learned magnetometer's heading offset (`offset_heading_variance`) is
        known, by the learner's own covariance, at least as well as the filter's yaw (yaw_var, rad²). Each update
        takes the filter's attitude as the truth within its covariance, renewed as noise every correlation time;
        the yaw error is not renewed: it is the gyro's drift since the GNSS last corrected it, common to minutes
        of updates (learned_iron.py). Such an error turns the Earth field about the vertical in every update, and
        an iron takes it in as a heading offset, the same at every heading; past this point an update tells the
        offset nothing the yaw's own error does not swamp, and what it takes in is that error, learned as iron,
        which the filter then reads back as a second heading (a reference error common to all measurements, the
        consider analysis: Maybeck, Stochastic Models, Estimation and Control vol. 1, §6.8). From here `update`
        learns only from the part of the measurement a yaw error does not move: the field along itself and the
        vertical, which still show the hard iron and the soft iron's stretch over a turn, but not its rotation."""
        if not self.offset_held and self.updates > 0 and math.isfinite(yaw_var_rad2):
            self.offset_held = self.offset_heading_variance(field_ned_ut) <= yaw_var_rad2
        return self.offset_held

    def offset_heading_variance(self, field_ned_ut) -> float:
        """The variance of the learned magnetometer's heading offset on a level vehicle, rad²: the mean over a
        turn of its heading error (the constant term of the harmonic series mag_harmonics.py fits, the mean of
        `level_heading_rows` over evenly spread headings), as the learner's covariance states it."""
        b = np.asarray(field_ned_ut, dtype=float)
        if b[0] * b[0] + b[1] * b[1] <= 0.0:
            return math.inf
        a = np.mean(self.level_heading_rows(b, _LEVEL_HEADINGS), axis=0)
        return float(a @ self.cov @ a)

    def release_offset(self) -> None:
        """The heading offset is learned against the yaw again (the magnetometer has just been rejected: its iron
        may have changed)."""
        self.offset_held = False

    def heading_variance(self, c_bn, field_corrected_ned) -> float:
        """Variance of the magnetometer heading that the learned iron's uncertainty causes (rad²): the heading of
        the horizontal field moves by g·δm_n, g = (−m_e, m_n, 0)/H², δm_n = −C_bn (I + D)⁻¹ H δx with H the
        measurement Jacobian at the corrected body field."""
        m_ned = np.asarray(field_corrected_ned, dtype=float)
        mn, me = float(m_ned[0]), float(m_ned[1])
        h2 = mn * mn + me * me
        if h2 <= 0.0:
            return math.inf
        g = np.array([-me, mn, 0.0]) / h2
        c = np.asarray(c_bn, dtype=float)
        a = g @ c @ self._kept_inverse() @ self._jacobian(c.T @ m_ned)
        return float(a @ self.cov @ a)


    def level_heading_sigma_rad(self, field_ned_ut) -> float:
        """The largest heading 1σ the learned iron's uncertainty leaves on a level vehicle, over every heading
        (rad): what a calibration with this iron folded in can claim where it was learned."""
        return math.sqrt(self.level_heading_variance(field_ned_ut))

    def level_heading_variance(self, field_ned_ut) -> float:
        """`heading_variance` on a level vehicle at 16 headings, the largest (rad²). A property of what has been
        learned (the covariance) and of the Earth field, not of the heading the vehicle points at now: the
        covariance only shrinks while learning, so this never grows again until the iron is reset."""
        b = np.asarray(field_ned_ut, dtype=float)
        key = b.tobytes() + self.state[3:].tobytes() + self.cov.tobytes()
        if self._level_variance[0] != key:
            self._level_variance = (key, self._level_heading_variance(b))
        return self._level_variance[1]

    def _level_heading_variance(self, b: np.ndarray) -> float:
        h2 = b[0] * b[0] + b[1] * b[1]
        if h2 <= 0.0:
            return math.inf
        a = self.level_heading_rows(b, _LEVEL_HEADINGS)
        return float(np.max(np.einsum("ki,ij,kj->k", a, self.cov, a)))

    def level_heading_rows(self, field_ned_ut, yaw_rad) -> np.ndarray:
        """∂(magnetometer heading)/∂(b, D) of a level vehicle at each yaw (rad, true), one row of N_IRON a yaw:
        `heading_variance`'s a at those attitudes (a · cov · aᵀ is the heading variance the learned iron leaves
        there). The field must have a horizontal part."""
        # heading_variance for each c_bn at once: a = [w, w_i·(C_bnᵀ B)_j] with w = g C_bn (I + D)⁻¹
        g_c, field_body = _level_field_terms(field_ned_ut, yaw_rad)
        w = g_c @ self._kept_inverse()
        return np.concatenate([w, (w[:, :, None] * field_body[:, None, :]).reshape(len(field_body), 9)], axis=1)


def attitude_heading_variances(p_att_rad2, field_ned_ut) -> tuple[float, float]:
    """(the variance the filter's attitude error gives the magnetometer's innovation against the filter's yaw,
    the part of it the tilt error alone gives the magnetometer heading), rad²: NaN, NaN without a field that has
    a horizontal part. p_att: the filter's 3×3 attitude-error covariance (δθ_N, δθ_E, δθ_D, true − estimate);
    field: the Earth field (WMM, NED, µT), not the magnetometer's, so that a wrong magnetometer does not set its
    own gate.

    The magnetometer heading is the azimuth of the field turned into NED with the filter's attitude: with
    m = H u + Z e_D (u the horizontal field direction), the attitude error moves it by h·δθ,
    h = (Z u_N / H, Z u_E / H, −1), the row the kernel fuses it with (ins_core._mag_heading_row): a tilt
    error about the horizontal axis along the field reads as tan(dip) times as much heading error, and the
    innovation's variance is h P hᵀ (its yaw part P_DD and the tilt–yaw covariance with it). Against the GNSS yaw,
    which the bank levels on its own, only the tilt part counts: the filter's yaw error is not in that difference."""
    n, e, d = (float(v) for v in field_ned_ut)
    h2 = n * n + e * e
    if not h2 > 0.0:
        return math.nan, math.nan
    a_n, a_e = d * n / h2, d * e / h2
    p = p_att_rad2
    tilt = a_n * a_n * float(p[0, 0]) + 2.0 * a_n * a_e * float(p[0, 1]) + a_e * a_e * float(p[1, 1])
    cross = a_n * float(p[0, 2]) + a_e * float(p[1, 2])
    return max(tilt - 2.0 * cross + float(p[2, 2]), 0.0), max(tilt, 0.0)


@dataclass
class MonitorDecision:
    mag_use: bool
    mag_bias_var_rad2: float          # the magnetometer heading's slowly varying error variance for the filter
    yaw_var_floor_rad2: float         # raise the filter's yaw variance to at least this (0: leave it)
    reset_yaw_to_rad: float | None    # reset the filter's yaw (true) to this
    reset_yaw_var_rad2: float
    mag_step_rad: float = math.nan    # the step of the magnetometer heading the step test saw here (NaN: none)


@dataclass(frozen=True)
class HeadingCheckRecord:
    """What one heading check decided and left, as its estimator keeps it (`Ins.heading_checks`): a reader (a test,
    a diagnosis) sees each decision without reaching into the check."""

    t_s: float
    mag_use: bool                     # the magnetometer agrees (or has not failed long enough) and is used
    yaw_var_floor_rad2: float         # the yaw variance floor the monitor decided (0: none)
    yaw_var_rad2: float               # the filter's yaw variance when the check returned
    reset_yaw_to_rad: float | None    # the yaw a reset or the alignment to the GNSS yaw turned the attitude to
    iron_learned: bool                # the iron learner updated at this check
    mag_step_rad: float = math.nan    # the magnetometer heading's step the step test saw (mag_step.py; NaN: none)


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
    rejections: int = 0
    rejection_disagreement_rad: float = 0.0   # at the latest rejection: the largest of the magnetometer's
    # low-passed and latest innovation against the filter's heading and its disagreement with the GNSS yaw
    max_disagreement_rad: float = 0.0   # the largest rejection_disagreement_rad so far
    lowpassed_velocity_nis: float = 0.0
    step: MagStepDetector = field(default_factory=MagStepDetector)   # an iron that steps (mag_step.py)

    def mag_sigma_rad2(self, iron_var_rad2: float, noise_var_rad2: float) -> float:
        return self.calibration_sigma_rad ** 2 + iron_var_rad2 + noise_var_rad2

    def check(self, t_s: float, yaw_rad: float, yaw_var_rad2: float, mag_yaw_rad: float, mag_var_rad2: float,
              gsf_yaw_rad: float, gsf_var_rad2: float, gsf_valid: bool, heading_observable: bool,
              velocity_nis: float = math.nan, mag_bias_var_rad2: float = math.nan,
              iron_trust_var_rad2: float = math.nan, tilt_heading_var_rad2: float = math.nan,
              gyro_bias_var_rad2_s2: float = 0.0, gyro_arw_rad_s_sqrt_hz: float = 0.0,
              attitude_innovation_var_rad2: float = math.nan, mag_tilt_var_rad2: float = math.nan
              ) -> MonitorDecision:
        """One check at a fused GNSS fix. yaw: the filter's (true); mag_yaw: the heading the magnetometer (with
        the learned iron removed) gives at the filter's tilt, NaN when it has none; mag_var: its variance
        (calibration + learned iron + noise); gsf_*: the Gaussian-sum yaw; heading_observable: the filter's yaw
        σ is small enough that the GNSS holds the heading (iron learning needs it; re-entry needs `reentry_s` of
        agreement while it holds);
        velocity_nis: the filter's last GNSS velocity NIS (2–3 dof) — a reset to the GNSS yaw also needs the
        filter's own velocity fusion to show the heading is wrong (low-passed NIS above `reset_velocity_nis`),
        as EKF3's realignYawGPS needs a failing velocity test; mag_bias_var: the slowly varying part of mag_var
        (without the white noise of one sample), which decides whether the magnetometer is trusted;
        iron_trust_var: the learned iron's heading variance at its worst heading (Ins._magnetometer_trust_var),
        which decides whether the iron is still learned (NaN: mag_bias_var); tilt_heading_var, gyro_bias_var,
        gyro_arw: what the step test (MagStepDetector.add) needs of the filter — NaN tilt_heading_var: no step
        test; attitude_innovation_var, mag_tilt_var: what the filter's attitude error gives the innovation and
        the magnetometer heading (`attitude_heading_variances`), which the gate adds — NaN: the yaw variance
        alone and nothing (no field)."""
        bias_var = mag_var_rad2 if math.isnan(mag_bias_var_rad2) else mag_bias_var_rad2
        have_mag = math.isfinite(mag_yaw_rad)
        dt, k = self._advance(t_s)
        innovation = self._track_innovation(k, yaw_rad, mag_yaw_rad, gsf_yaw_rad, have_mag, gsf_valid)
        self._track_velocity_nis(k, velocity_nis)
        if self.lowpassed_velocity_nis > self.reset_velocity_nis:
            # the filter's GNSS velocity fusion fails: its attitude covariance does not cover its attitude error
            # (a start in a hard turn: the accelerometer levelled the turn's lean, far beyond the stated tilt σ),
            # so the disagreement is judged without the attitude's share, and a rejection can hand the yaw to the
            # GNSS yaw (docs/gnss.md, gate37)
            attitude_innovation_var_rad2 = mag_tilt_var_rad2 = math.nan
        bad = have_mag and self._disagrees(innovation, yaw_var_rad2, mag_var_rad2, gsf_var_rad2, gsf_valid,
                                           attitude_innovation_var_rad2, mag_tilt_var_rad2)
        self._count_agreement(bad, heading_observable, dt)
        step = None
        if not self.mag_rejected and have_mag and math.isfinite(tilt_heading_var_rad2):
            step = self.step.add(t_s, innovation, yaw_rad, yaw_var_rad2, bias_var, tilt_heading_var_rad2,
                                 gyro_bias_var_rad2_s2, gyro_arw_rad_s_sqrt_hz)
        floor = 0.0
        if not self.mag_rejected and have_mag and (self.failures >= self.reject_checks or step is not None):
            floor = self._reject(innovation, yaw_rad, yaw_var_rad2, gsf_yaw_rad, gsf_var_rad2, gsf_valid,
                                 0.0 if step is None else step)
        elif self.mag_rejected and have_mag and heading_observable and self.consistent_s >= self.reentry_s \
                and bias_var < self.trusted_sigma_rad ** 2:
            self.mag_rejected = False
        reset_to, reset_var = self._emergency_reset(t_s, yaw_rad, yaw_var_rad2, gsf_yaw_rad, gsf_var_rad2,
                                                    gsf_valid, have_mag, bias_var)
        # a reset here moves the yaw its σ was judged on: nothing is learned until the next check
        learn_var = bias_var if math.isnan(iron_trust_var_rad2) else iron_trust_var_rad2
        self.learning = heading_observable and reset_to is None and (
            self.mag_rejected or learn_var > self.trusted_sigma_rad ** 2)
        if self.mag_rejected or reset_to is not None or self.learning:
            # the innovation's reference moves by itself (a yaw reset, the learned iron changes the magnetometer
            # heading at the next check) or the magnetometer is not used: the step test starts again
            self.step.restart()
        return MonitorDecision(not self.mag_rejected, mag_var_rad2 if not self.mag_rejected else 0.0, floor,
                               reset_to, reset_var, math.nan if step is None else step)

    def _advance(self, t_s: float) -> tuple[float, float]:
        """The time since the last check and the low-pass gain over it (1 at the first check: no history)."""
        dt = 0.0 if math.isnan(self.last_t_s) else max(0.0, t_s - self.last_t_s)
        self.last_t_s = t_s
        k = 1.0 - math.exp(-dt / self.lowpass_tau_s) if dt > 0.0 else 1.0
        return dt, k

    def _track_innovation(self, k: float, yaw_rad: float, mag_yaw_rad: float, gsf_yaw_rad: float, have_mag: bool,
                          gsf_valid: bool) -> float:
        """The magnetometer's innovation against the filter's yaw (0 without a magnetometer heading), low-passed
        into `lowpassed_innovation_rad`; its disagreement with the GNSS yaw into `disagreement_rad`."""
        innovation = wrap_pi(mag_yaw_rad - yaw_rad) if have_mag else 0.0
        self.lowpassed_innovation_rad += k * (innovation - self.lowpassed_innovation_rad)
        self.disagreement_rad = wrap_pi(mag_yaw_rad - gsf_yaw_rad) if (have_mag and gsf_valid) else math.nan
        return innovation

    def _disagrees(self, innovation: float, yaw_var_rad2: float, mag_var_rad2: float, gsf_var_rad2: float,
                   gsf_valid: bool, attitude_innovation_var_rad2: float = math.nan,
                   mag_tilt_var_rad2: float = math.nan) -> bool:
        """The magnetometer heading fails this check: its innovation (latest or low-passed) beyond the gate, or
        the GNSS yaw beyond the gate from it while the innovation is beyond 1σ. The magnetometer heading is
        computed at the filter's tilt, so the filter's tilt error is in both, seen through the dip
        (`attitude_heading_variances`): in the innovation with the filter's yaw error (attitude_innovation_var,
        which holds the yaw variance), in the distance from the GNSS yaw alone (mag_tilt_var)."""
        att_var = attitude_innovation_var_rad2 if math.isfinite(attitude_innovation_var_rad2) else yaw_var_rad2
        s_ins = att_var + mag_var_rad2
        bad = innovation ** 2 > self.gate_sigma ** 2 * s_ins or \
            self.lowpassed_innovation_rad ** 2 > self.gate_sigma ** 2 * s_ins
        if gsf_valid:
            # the GNSS yaw alone does not reject the magnetometer (a bank whose tilt is wrong in a coordinated
            # turn is confidently wrong): it must agree with the filter's own innovation being beyond 1σ
            s_gsf = gsf_var_rad2 + mag_var_rad2 + (mag_tilt_var_rad2 if math.isfinite(mag_tilt_var_rad2) else 0.0)
            bad = bad or (self.disagreement_rad ** 2 > self.gate_sigma ** 2 * s_gsf and innovation ** 2 > s_ins)
        return bad

    def _track_velocity_nis(self, k: float, velocity_nis: float) -> None:
        """The filter's last GNSS velocity NIS, low-passed into `lowpassed_velocity_nis` (each capped at 100)."""
        if math.isfinite(velocity_nis):
            self.lowpassed_velocity_nis += k * (min(velocity_nis, 100.0) - self.lowpassed_velocity_nis)

    def _count_agreement(self, bad: bool, heading_observable: bool, dt: float) -> None:
        """Failures in a row (rejection needs `reject_checks`), and the time of agreement while the GNSS holds
        the heading (re-entry needs `reentry_s`)."""
        if bad:
            self.failures += 1
            self.consistent_s = 0.0
        else:
            self.failures = 0
            if heading_observable:
                # agreement with a heading the GNSS does not hold shows nothing (after an iron step the raised
                # yaw σ stays above heading_observable for seconds; counted, they let the magnetometer back
                # after a few seconds of learning, its iron half learned)
                self.consistent_s += dt

    def _reject(self, innovation: float, yaw_rad: float, yaw_var_rad2: float, gsf_yaw_rad: float,
                gsf_var_rad2: float, gsf_valid: bool, step_rad: float = 0.0) -> float:
        """Reject the magnetometer; returns the yaw variance floor the filter must take. step_rad: the step of
        the magnetometer heading the step test saw (0: none)."""
        # σ first: cover what the magnetometer may already have pulled the heading by (its low-passed
        # innovation: a step just seen has not moved the filter yet; a step the step test saw: the filter has
        # followed it for at most the test's windows, by less than the step) and the disagreement with the GNSS yaw
        self.mag_rejected = True
        self.rejections += 1
        seen = abs(self.disagreement_rad) if math.isfinite(self.disagreement_rad) else 0.0
        self.rejection_disagreement_rad = max(abs(self.lowpassed_innovation_rad), abs(innovation), seen,
                                              abs(step_rad))
        self.max_disagreement_rad = max(self.max_disagreement_rad, self.rejection_disagreement_rad)
        floor = max(self.lowpassed_innovation_rad ** 2, step_rad ** 2) + yaw_var_rad2
        if gsf_valid:
            floor = max(floor, wrap_pi(yaw_rad - gsf_yaw_rad) ** 2 + gsf_var_rad2)
        return floor

    def _emergency_reset(self, t_s: float, yaw_rad: float, yaw_var_rad2: float, gsf_yaw_rad: float,
                         gsf_var_rad2: float, gsf_valid: bool, have_mag: bool,
                         bias_var: float) -> tuple[float | None, float]:
        """(yaw to reset to or None, its variance): the GNSS yaw, when the magnetometer cannot hold the heading,
        the filter's own velocity fusion fails (low-passed NIS) and the GNSS yaw is beyond the gate from the
        filter's — at most `max_resets`, `reset_spacing_s` apart."""
        if gsf_valid and self.lowpassed_velocity_nis > self.reset_velocity_nis \
                and (self.mag_rejected or not have_mag or bias_var > self.trusted_sigma_rad ** 2):
            d = wrap_pi(gsf_yaw_rad - yaw_rad)
            if d * d > self.gate_sigma ** 2 * (yaw_var_rad2 + gsf_var_rad2) and self.resets < self.max_resets \
                    and t_s - self.last_reset_t_s >= self.reset_spacing_s:
                self.resets += 1
                self.last_reset_t_s = t_s
                return gsf_yaw_rad, gsf_var_rad2
        return None, 0.0

    def yaw_was_reset(self, t_s: float) -> None:
        """The filter's yaw was reset outside `check` (the GNSS-yaw alignment at this check): an emergency reset
        keeps its spacing from it, and nothing is learned on the σ `check` judged before it; the step test starts
        again (its innovations before the reset are against another yaw)."""
        self.last_reset_t_s = t_s
        self.learning = False
        self.step.restart()

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
