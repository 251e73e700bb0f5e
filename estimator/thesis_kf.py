"""`thesis`: the attitude filter of the ADIS16405 AHRS thesis (docs/estimator.md says which), reproduced faithfully
as a baseline.

A 9-state Kalman filter estimates the **body-frame** magnetic field and gravity vectors and the gyro bias;
the gyros only propagate those vectors; the attitude then comes algebraically from the filtered vectors by
the thesis's two-vector Wahba solution (C_n^b = B N⁻¹ from stacked vectors, `wahba.py`) and its
re-orthonormalisation C ← 1.5C − 0.5CCᵀC.

Model, with the sign of the bias, which the thesis leaves ambiguous, resolved as
ω_true = ω_meas − b − δω
(so ``gyro_bias_rad_s`` is what is subtracted from the gyro, as in every other ahrsd estimator)::

    x = [mᵇ (µT), gᵇ = −fᵇ (m/s²), b (rad/s)]                       (state holds −f = g)
    ṁᵇ = −[ω×]mᵇ − [mᵇ×]b − [mᵇ×]δω,   ω = ω_meas
    ġᵇ = −[ω×]gᵇ − [gᵇ×]b − [gᵇ×]δω
    ḃ  = −b/τ_w + w_b/τ_w                                              (Gauss–Markov)
    A = [[−[ω×], 0, −[m×]], [0, −[ω×], −[g×]], [0, 0, −I/τ_w]]          (bias sign as above)
    B = [[−[m×], 0], [−[g×], 0], [0, I/τ_w]]
    F = I + AΔt + ½A²Δt²                                               (second-order transition matrix)
    Q_d = B Q B^T Δt   (Q a PSD in rad²/s; the printed GQGᵀ, G = ΔtB, scales as Δt²)
    z = [m̃ᵇ, −f̃ᵇ],  H = [I₆ 0]
    standard KF predict / update
    Cₙᵇ = B_b N_n⁻¹ (version 2 by default, version 1 selectable), C_b^n = (Cₙᵇ)ᵀ, then C ← 1.5C − 0.5CCᵀC.

Choices where the thesis is silent, each a field of `ThesisKfParams`:

* **Δt** — from consecutive ``sample.t_s`` (any rate). Gaps above ``large_dt_s`` are propagated in sub-steps
  of at most ``max_substep_s`` with the last rate held (flag LARGE_DT); gaps above ``reinit_dt_s`` (or time
  going backwards) re-initialise the vectors from the measurement (flags LARGE_DT | REINITIALISED); a repeated
  time stamp (Δt = 0) gets the measurement update only.
* **τ_w** — 1000 s: long against the filter's settling so a learned bias is kept (the thesis folds it back into
  the calibration); with the thesis's bias-driving noise this is a slow random walk.
* **x̂₀, P₀** — the first sample's m̃, −f̃ with P₀ = R; bias ``initial_bias_rad_s`` with σ ``initial_bias_sigma_rad_s``.
* **H** — [I₆ 0] with −f̃ as the measurement (equivalent to H = [[I,0,0],[0,−I,0]] on f̃).
* **Units of Q and R** — Q as the thesis prints it, rad²/s; R read as mG and mg (the ADIS16405's display
  units; the thesis does not state them) and converted to µT² and (m/s²)².
* **Reference vectors** — fⁿ = [0, 0, −g]; mⁿ is taken in the *magnetic* NED frame, [H, 0, Z], so the yaw is
  magnetic (heading_true adds the declination, ahrsd's contract). Its dip is learned from the filtered vectors
  while INITIALISING (``settle_time_s``) unless ``mag_reference_ned_ut`` gives it (e.g. WMM), then frozen.
  Vectors are normalised before the Wahba step (Wahba's problem is posed on unit vectors).
* **1σ outputs** — the attitude covariance of the optimal two-vector solution given the filtered vectors'
  direction variances (from P), mapped to ZYX Euler angles; a lower bound for the algebraic solutions.

Cost: plain numpy for the 9×9 Kalman algebra, scalar maths for the 3×3 Wahba step (shared with
`wahba.thesis_dcm_from_floats` and `rotations.reorthonormalize_rows`); `bench/speed.py` measures it beside the
other estimators (figures in docs/estimator.md).

No gating: the thesis assumes f = −g (its future work names linear acceleration as the open problem).
Samples flagged invalid (or non-finite) skip that sensor's update; an invalid gyro holds the last rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv as _dposv

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.core.sample import ImuSample, SampleFlags

from ahrsd.core.estimate import AttitudeEstimate, EstimateFlags
from .params import with_overrides
from .rotations import dcm_rows_to_quat, reorthonormalize_rows
from .wahba import thesis_dcm_from_floats, thesis_matrix

DEG = math.pi / 180.0
MGAUSS_TO_UT = 0.1           # 1 mgauss = 0.1 µT
TWO_PI = 2.0 * math.pi

# Plain ints: IntFlag arithmetic costs a microsecond per operation on the per-sample path.
_GYRO_BAD = int(SampleFlags.GYRO_INVALID)
_ACC_BAD = int(SampleFlags.ACCEL_INVALID | SampleFlags.ACCEL_SATURATED)
_MAG_BAD = int(SampleFlags.MAG_INVALID | SampleFlags.MAG_SATURATED)
_F_INITIALISING = int(EstimateFlags.INITIALISING)
_F_LARGE_DT = int(EstimateFlags.LARGE_DT)
_F_REINITIALISED = int(EstimateFlags.REINITIALISED)
_F_ACCEL_REJECTED = int(EstimateFlags.ACCEL_REJECTED)
_F_MAG_REJECTED = int(EstimateFlags.MAG_REJECTED)
_FLAGS: dict[int, EstimateFlags] = {}   # int → EstimateFlags, filled on first use (the enum call is slow)


@dataclass(frozen=True)
class ThesisKfParams:
    """Tuning of the thesis filter. Defaults reproduce the thesis's tuning where it gives numbers."""

    gyro_arw_rad_sqrt_s: tuple[float, float, float] = (0.05 * DEG, 0.05 * DEG, 0.06 * DEG)
    """Gyro white noise δω (angle random walk) per axis x, y, z, rad/√s: 0.05, 0.05, 0.06 °/√s
    (the thesis's Allan figures)."""
    gyro_bias_drive_rad_sqrt_s: tuple[float, float, float] = (0.005 * DEG, 0.005 * DEG, 0.006 * DEG)
    """Bias-driving noise w_b of the Gauss–Markov bias, rad/√s: ARW/10 (the thesis's rule)."""
    q_inflation: float = 3.0
    """Factor on the noise densities above before squaring: Q = diag((3·ARW)², (3·w_b)²) (the thesis's
    inflation for correlated axes)."""
    mag_noise_ut: tuple[float, float, float] = (0.74 * MGAUSS_TO_UT, 0.66 * MGAUSS_TO_UT, 0.52 * MGAUSS_TO_UT)
    """Magnetometer measurement noise 1σ per axis, µT: 0.74, 0.66, 0.52 read as mG (the thesis's R)."""
    accel_noise_m_s2: tuple[float, float, float] = (3.65e-3 * STANDARD_GRAVITY_M_S2, 3.44e-3 * STANDARD_GRAVITY_M_S2,
                                                     3.72e-3 * STANDARD_GRAVITY_M_S2)
    """Accelerometer measurement noise 1σ per axis, m/s²: 3.65, 3.44, 3.72 read as mg (the thesis's R)."""
    bias_time_constant_s: float = 1000.0
    """Gauss–Markov time constant τ_w of the gyro bias, s. Not in the thesis (chosen, see module doc)."""
    initial_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Gyro bias at start, rad/s (the calibration removes the bias; the filter estimates the residual)."""
    initial_bias_sigma_rad_s: float = 0.5 * DEG
    """1σ of the residual gyro bias at start, rad/s. Not in the thesis."""
    wahba_version: int = 2
    """Wahba step: 2 = [m, f×m, (f×m)×m] (orthogonal columns, magnetometer anchor; "more accurate" per the thesis),
    1 = three-vector inversion with [m, f, f×m]."""
    reorthonormalize_iterations: int = 1
    """Steps of C ← 1.5C − 0.5CCᵀC per sample (the thesis applies one per program step)."""
    mag_reference_ned_ut: tuple[float, float, float] | None = None
    """Earth field in NED, µT (e.g. WMM). Only its dip is used (yaw stays magnetic). None: learn the dip from
    the filtered vectors while initialising."""
    settle_time_s: float = 1.0
    """Time after start (or re-initialisation) flagged INITIALISING, during which the dip is learned, s."""
    converged_sigma_rad: float = 2.0 * DEG
    """INITIALISING is also kept while any 1σ of roll, pitch or yaw exceeds this, rad."""
    large_dt_s: float = 0.05
    """A sample interval above this is a time gap (flag LARGE_DT), s."""
    max_substep_s: float = 0.01
    """Gaps are propagated in sub-steps of at most this (F = I + AΔt + ½A²Δt² is accurate for small Δt), s."""
    reinit_dt_s: float = 1.0
    """A gap above this re-initialises the vectors from the measurement (flag REINITIALISED), s."""

    def __post_init__(self):
        for name in ("gyro_arw_rad_sqrt_s", "gyro_bias_drive_rad_sqrt_s", "mag_noise_ut", "accel_noise_m_s2",
                     "initial_bias_rad_s"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be three finite numbers, got {getattr(self, name)!r}")
            if name != "initial_bias_rad_s" and np.any(v <= 0):
                raise ValueError(f"{name} must be positive")
        for name in ("q_inflation", "bias_time_constant_s", "initial_bias_sigma_rad_s", "settle_time_s",
                     "converged_sigma_rad", "large_dt_s", "max_substep_s", "reinit_dt_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.wahba_version not in (1, 2):
            raise ValueError("wahba_version must be 1 or 2")
        if int(self.reorthonormalize_iterations) < 0:
            raise ValueError("reorthonormalize_iterations must be ≥ 0")
        if self.mag_reference_ned_ut is not None:
            m = np.asarray(self.mag_reference_ned_ut, dtype=float)
            if m.shape != (3,) or not np.all(np.isfinite(m)) or math.hypot(m[0], m[1]) <= 0:
                raise ValueError("mag_reference_ned_ut must be a finite NED vector with a horizontal part")

    @property
    def q_diag(self) -> np.ndarray:
        """The 6 diagonal entries of Q (rad²/s): (q_inflation · [ARW, w_b])²."""
        return (self.q_inflation * np.concatenate((self.gyro_arw_rad_sqrt_s, self.gyro_bias_drive_rad_sqrt_s))) ** 2

    @property
    def r_diag(self) -> np.ndarray:
        """The 6 diagonal entries of R (µT², (m/s²)²): σ², mag first."""
        return np.concatenate((self.mag_noise_ut, self.accel_noise_m_s2)) ** 2


DEFAULT_THESIS_KF_PARAMS = ThesisKfParams()

# the state x = [mᵇ, gᵇ, b]: where each 3-vector starts; the noise input w = [δω, w_b]: where each starts
X_MAG, X_GRAV, X_BIAS, N_STATE = 0, 3, 6, 9
W_GYRO_NOISE, W_BIAS_DRIVE, N_NOISE = 0, 3, 6
_M = slice(X_MAG, X_MAG + 3)
_G = slice(X_GRAV, X_GRAV + 3)
_B = slice(X_BIAS, X_BIAS + 3)
_VECTORS = slice(X_MAG, X_GRAV + 3)     # the measured part: z = [m̃, −f̃], H = [I₆ 0]


def _skew_entries(row: int, col: int) -> list[tuple[int, int]]:
    """The six off-diagonal (row, column) entries of a 3×3 cross-product block whose corner is (row, col), in
    the order (0,1) (0,2) (1,0) (1,2) (2,0) (2,1): −[v×] there is (v_z, −v_y, −v_z, v_x, v_y, −v_x)."""
    return [(row + r, col + c) for r in range(3) for c in range(3) if r != c]


# Flat indices into the 9×9 A of the entries `_predict` writes: −[ω×] on both vectors, then their coupling to
# the bias −[m×], −[g×]; and into the 9×6 B: its −[m×], −[g×] blocks, in the same order as A's coupling.
_A_INDEX = np.array([N_STATE * r + c for r, c in (
    _skew_entries(X_MAG, X_MAG) + _skew_entries(X_GRAV, X_GRAV)
    + _skew_entries(X_MAG, X_BIAS) + _skew_entries(X_GRAV, X_BIAS))])
_B_INDEX = np.array([N_NOISE * r + c for r, c in (
    _skew_entries(X_MAG, W_GYRO_NOISE) + _skew_entries(X_GRAV, W_GYRO_NOISE))])
_MAG = np.arange(X_MAG, X_MAG + 3)
_ACC = np.arange(X_GRAV, X_GRAV + 3)
_BOTH = np.arange(X_MAG, X_GRAV + 3)


# after a calibration change the reference dip follows the filtered field this long: the field state
# converges with a time constant of several seconds at the thesis tuning (tests/test_calibration_change.py)
RELEARN_DIP_S = 30.0


class ThesisKf:
    """The thesis's vector Kalman filter + Wahba (Estimator protocol): `update(sample) -> AttitudeEstimate`."""

    name = "thesis"

    def __init__(self, declination_rad: float = 0.0, params: ThesisKfParams | None = None, **overrides):
        self.params = with_overrides(params or DEFAULT_THESIS_KF_PARAMS, overrides, "thesis")
        p = self.params
        self._declination = float(declination_rad)
        self._r = np.diag(p.r_diag)
        self._inv_tau = 1.0 / p.bias_time_constant_s
        self._x = np.zeros(N_STATE)
        self._p = np.zeros((N_STATE, N_STATE))
        self._a = np.zeros((N_STATE, N_STATE))      # preallocated continuous-time A
        self._b = np.zeros((N_STATE, N_NOISE))      # preallocated noise input matrix B
        for i in range(3):                          # Gauss–Markov bias: −b/τ_w + w_b/τ_w
            self._a[X_BIAS + i, X_BIAS + i] = -self._inv_tau
            self._b[X_BIAS + i, W_BIAS_DRIVE + i] = self._inv_tau
        self._q_diag = p.q_diag
        self._qdt_dt, self._qdt = math.nan, self._q_diag
        self._n_updates = 0
        self._cov_ned = (math.nan,) * 4
        self._n_sigma = 0
        self._eye9 = np.eye(N_STATE)
        self._fixed_dip = None
        if p.mag_reference_ned_ut is not None:
            n, e, d = p.mag_reference_ned_ut
            self._fixed_dip = math.atan2(d, math.hypot(n, e))
        self.reset()

    # ------------------------------------------------------------------------------ Estimator protocol
    def reset(self) -> None:
        """Forget everything: the next sample re-initialises the filter (flag INITIALISING)."""
        self._initialised = False
        self._t_last = math.nan
        self._t_init = math.nan
        self._settled = False
        self._relearning = False
        self._relearn_t0 = math.nan
        self._rate_list = [0.0, 0.0, 0.0]
        self._x[:] = 0.0
        self._x[_B] = self.params.initial_bias_rad_s
        self._p[:] = 0.0
        self._set_dip(self._fixed_dip if self._fixed_dip is not None else 0.0)

    def set_declination(self, declination_rad: float) -> None:
        self._declination = float(declination_rad)

    def relearn_field_reference(self, heading_change_rad: float = math.nan) -> None:
        """After a magnetometer calibration change (`heading_change_rad`: how far it moves the heading; this
        filter's heading comes from its filtered field state, which has no heading variance to widen, so it is
        not used): the filtered field state follows the new field by itself
        (it has no disturbance gate), but the dip of the Wahba reference was learned from the old field, so
        it is re-learned from the filtered field for the next RELEARN_DIP_S (as after initialisation, without
        flagging INITIALISING). Attitude state and gyro bias are kept. No-op with a fixed reference field."""
        if self._fixed_dip is None:
            self._relearn_t0 = math.nan
            self._relearning = True

    # ------------------------------------------------------------------------------ state (read-only)
    @property
    def state(self) -> np.ndarray:
        """[mᵇ (µT), gᵇ (m/s²), b (rad/s)], a copy."""
        return self._x.copy()

    @property
    def covariance(self) -> np.ndarray:
        """9×9 state covariance, a copy."""
        return self._p.copy()

    @property
    def dip_rad(self) -> float:
        """Inclination of the reference field used by the Wahba step, rad (positive down)."""
        return self._dip

    # ------------------------------------------------------------------------------ the filter
    def update(self, sample: ImuSample) -> AttitudeEstimate:
        gyro, accel, mag = sample.gyro_rad_s.tolist(), sample.accel_m_s2.tolist(), sample.mag_ut.tolist()
        sflags = int(sample.flags)
        # A NaN or inf anywhere makes the sum non-finite: one check per sensor.
        gyro_ok = not (sflags & _GYRO_BAD) and math.isfinite(gyro[0] + gyro[1] + gyro[2])
        acc_ok = not (sflags & _ACC_BAD) and math.isfinite(accel[0] + accel[1] + accel[2])
        mag_ok = not (sflags & _MAG_BAD) and math.isfinite(mag[0] + mag[1] + mag[2])
        t = float(sample.t_s)
        flags = 0
        if gyro_ok:
            self._rate_list = gyro
        if not self._initialised:
            if not (acc_ok and mag_ok and self._initialise(t, accel, mag)):
                return self._uninitialised(t)
            flags = _F_INITIALISING
        else:
            dt = t - self._t_last
            p = self.params
            if not (dt >= 0.0) or dt > p.reinit_dt_s:  # time went backwards / NaN / long gap: start again
                flags = _F_LARGE_DT | _F_REINITIALISED
                if not (acc_ok and mag_ok and self._initialise(t, accel, mag, keep_bias=True)):
                    self._initialised = False
                    return self._uninitialised(t, flags)
            else:
                if dt > p.large_dt_s:
                    flags = _F_LARGE_DT
                    n = int(math.ceil(dt / p.max_substep_s))
                    for _ in range(n):
                        self._predict(dt / n)
                elif dt > 0.0:  # a repeated time stamp: measurement update only
                    self._predict(dt)
                self._t_last = t
                if acc_ok and mag_ok:
                    self._correct(_BOTH, mag, accel)
                elif mag_ok:
                    self._correct(_MAG, mag, accel)
                    flags |= _F_ACCEL_REJECTED
                elif acc_ok:
                    self._correct(_ACC, mag, accel)
                    flags |= _F_MAG_REJECTED
                else:
                    flags |= _F_ACCEL_REJECTED | _F_MAG_REJECTED
        return self._estimate(t, flags)

    def _initialise(self, t: float, accel, mag, keep_bias: bool = False) -> bool:
        g = -np.asarray(accel, dtype=float)
        m = np.asarray(mag, dtype=float)
        gn, mn = np.linalg.norm(g), np.linalg.norm(m)
        if not (gn > 0.1 * STANDARD_GRAVITY_M_S2 and mn > 0.0) or np.linalg.norm(np.cross(g, m)) < 1e-3 * gn * mn:
            return False  # no usable gravity, or field parallel to gravity: attitude undefined
        p = self.params
        self._x[_M] = m
        self._x[_G] = g
        if not keep_bias:
            self._x[_B] = p.initial_bias_rad_s
        bias_var = self._p[_B, _B].copy() if keep_bias else np.eye(3) * p.initial_bias_sigma_rad_s**2
        self._p[:] = 0.0
        self._p[_VECTORS, _VECTORS] = self._r   # P₀ = R for the vectors (they come straight from one measurement)
        self._p[_B, _B] = bias_var
        self._t_last = t
        self._t_init = t
        self._settled = False
        self._initialised = True
        if self._fixed_dip is None:
            self._learn_dip()
        return True

    def _predict(self, dt: float) -> None:
        """KF time update x ← F x, P ← F P Fᵀ + Q_d over dt with the held measured rate.

        A uses the measured rate; the bias enters through A's coupling blocks (so F·x applies ω_meas − b̂).
        """
        x, a = self._x, self._a
        wx, wy, wz = self._rate_list
        mx, my, mz, gx, gy, gz = x[_VECTORS].tolist()
        # A: −[ω×] on both vector blocks, −[v×] coupling each vector to the bias (one `put`).
        coupling = (mz, -my, -mz, mx, my, -mx, gz, -gy, -gz, gx, gy, -gx)
        a.put(_A_INDEX, (wz, -wy, -wz, wx, wy, -wx, wz, -wy, -wz, wx, wy, -wx) + coupling)
        ad = a * dt
        f = ad @ (0.5 * ad + self._eye9)
        f += self._eye9                                             # F = I + AΔt + ½A²Δt²
        self._x = f @ x                                             # x ← F x
        # Q_d = B Q Bᵀ Δt (Q a PSD): B has A's coupling blocks −[m×], −[g×] and I/τ for w_b.
        b = self._b
        b.put(_B_INDEX, coupling)
        if dt != self._qdt_dt:
            self._qdt_dt, self._qdt = dt, self._q_diag * dt
        p = f @ self._p @ f.T                                       # F P Fᵀ
        p += (b * self._qdt) @ b.T
        self._p = p

    def _correct(self, idx: np.ndarray, mag, accel) -> None:
        """KF measurement update with z = [m̃, −f̃] (rows idx), H = [I₆ 0]."""
        x, p = self._x, self._p
        if len(idx) == 6:
            m0, m1, m2 = mag
            a0, a1, a2 = accel
            y = np.array((m0, m1, m2, -a0, -a1, -a2)) - x[_VECTORS]
            pht = p[_VECTORS]                                       # H P (6×9)
            s = p[_VECTORS, _VECTORS] + self._r
        else:
            y = np.array(mag if idx[0] == X_MAG else [-v for v in accel]) - x[idx]
            pht = p[idx]
            s = p[np.ix_(idx, idx)] + self._r[np.ix_(idx, idx)]
        _, k_t, info = _dposv(s, pht)                               # Kᵀ = S⁻¹ H P (S symmetric positive definite)
        if info != 0:
            return                                                  # S not positive definite: skip this update
        x += y @ k_t
        p -= k_t.T @ pht                                             # P − K H P = P − K S Kᵀ
        self._n_updates += 1
        if not self._n_updates & 31:                                 # keep P symmetric against rounding
            p += p.T
            p *= 0.5

    # ------------------------------------------------------------------------------ Wahba step and output
    def _set_dip(self, dip: float) -> None:
        self._dip = dip
        ref_mag = (math.cos(dip), 0.0, math.sin(dip))   # magnetic NED: yaw is magnetic
        ref_f = (0.0, 0.0, -1.0)                          # fⁿ = [0, 0, −g], unit
        self._n_inv_t = np.linalg.inv(thesis_matrix(ref_mag, ref_f, self.params.wahba_version)).T.tolist()

    def _learn_dip(self) -> None:
        m, g = self._x[_M], self._x[_G]
        s = float(m @ g) / (math.sqrt(float(m @ m) * float(g @ g)))
        self._set_dip(math.asin(max(-1.0, min(1.0, s))))

    def attitude_dcm(self) -> np.ndarray:
        """C_b^n from the filtered vectors: C_b^n = (B_b N_n⁻¹)ᵀ, version 1 or 2, then
        C ← 1.5C − 0.5CCᵀC."""
        return np.array(self._attitude_rows())

    def _attitude_rows(self):
        """`attitude_dcm` as three row tuples (scalar maths: a 3×3 is cheaper in floats than in numpy)."""
        mx, my, mz, gx, gy, gz = self._x[_VECTORS].tolist()
        mn = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
        gn = -1.0 / math.sqrt(gx * gx + gy * gy + gz * gz)          # f = −g
        c = thesis_dcm_from_floats(mx * mn, my * mn, mz * mn, gx * gn, gy * gn, gz * gn, self._n_inv_t,
                                   self.params.wahba_version)          # C_b^n = (B_b N_n⁻¹)ᵀ
        for _ in range(self.params.reorthonormalize_iterations):
            c = reorthonormalize_rows(c)                              # C ← 1.5C − 0.5CCᵀC
        return c

    def _estimate(self, t: float, flags: int) -> AttitudeEstimate:
        p = self.params
        if not self._settled and self._fixed_dip is None:
            self._learn_dip()
        elif self._relearning:
            if math.isnan(self._relearn_t0):
                self._relearn_t0 = t
            self._learn_dip()
            self._relearning = t - self._relearn_t0 < RELEARN_DIP_S
        # Normalised quaternion: removes what one re-orthonormalisation step leaves of the non-orthonormality.
        w, qx, qy, qz = dcm_rows_to_quat(self._attitude_rows())
        roll = math.atan2(2.0 * (qy * qz + w * qx), 1.0 - 2.0 * (qx * qx + qy * qy))
        pitch = -math.asin(max(-1.0, min(1.0, 2.0 * (qx * qz - w * qy))))
        yaw = math.atan2(2.0 * (qx * qy + w * qz), 1.0 - 2.0 * (qy * qy + qz * qz))
        sigma = self._sigma_rpy(pitch, yaw)
        if not self._settled:
            if t - self._t_init >= p.settle_time_s and max(sigma) <= p.converged_sigma_rad:
                self._settled = True
            else:
                flags |= _F_INITIALISING
        b0, b1, b2 = self._x[_B].tolist()
        r0, r1, r2 = self._rate_list
        flags_enum = _FLAGS.get(flags)
        if flags_enum is None:
            flags_enum = _FLAGS[flags] = EstimateFlags(flags)
        return AttitudeEstimate(
            t_s=t,
            q_wxyz=np.array((w, qx, qy, qz)),
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            heading_mag_rad=yaw % TWO_PI,
            heading_true_rad=(yaw + self._declination) % TWO_PI,
            rate_body_rad_s=np.array((r0 - b0, r1 - b1, r2 - b2)),
            gyro_bias_rad_s=np.array((b0, b1, b2)),
            sigma_rpy_rad=np.array(sigma),
            flags=flags_enum,
        )

    def _sigma_rpy(self, pitch: float, yaw: float) -> tuple[float, float, float]:
        """1σ roll, pitch, yaw (rad): the NED attitude covariance (`_attitude_cov_ned`, refreshed every 8th
        sample once settled: it changes slowly) mapped to ZYX Euler angles at the current attitude."""
        self._n_sigma += 1
        if not self._settled or not self._n_sigma & 7:
            self._cov_ned = self._attitude_cov_ned()
        pxx, pxz, pzz, pyy = self._cov_ned
        # δ[roll, pitch, yaw] = E⁻¹ δφⁿ with E⁻¹ = [[cψ/cθ, sψ/cθ, 0], [−sψ, cψ, 0], [cψ tθ, sψ tθ, 1]].
        cy, sy = math.cos(yaw), math.sin(yaw)
        cp = max(math.cos(pitch), 1e-6)
        tp = math.sin(pitch) / cp
        horiz = cy * cy * pxx + sy * sy * pyy
        var_roll = horiz / (cp * cp)
        var_pitch = sy * sy * pxx + cy * cy * pyy
        var_yaw = tp * tp * horiz + 2.0 * tp * cy * pxz + pzz
        return math.sqrt(var_roll), math.sqrt(var_pitch), math.sqrt(max(var_yaw, 0.0))

    def _attitude_cov_ned(self) -> tuple[float, float, float, float]:
        """Covariance (pxx, pxz, pzz, pyy; rad²) of the NED rotation error of the optimal two-vector solution
        given the filtered vectors' direction variances (from P), reference mⁿ = [cos δ, 0, sin δ], gⁿ = [0, 0, 1]."""
        mx, my, mz, gx, gy, gz = self._x[_VECTORS].tolist()
        (p00, p01, p02, _, _, _), (_, p11, p12, _, _, _), (_, _, p22, _, _, _), \
            (_, _, _, p33, p34, p35), (_, _, _, _, p44, p45), (_, _, _, _, _, p55) = \
            self._p[_VECTORS, _VECTORS].tolist()
        mm = mx * mx + my * my + mz * mz
        gg = gx * gx + gy * gy + gz * gz
        # Direction variance per perpendicular axis: (tr P − radial part vᵀPv/|v|²) / 2 / |v|².
        rad_m = (mx * mx * p00 + my * my * p11 + mz * mz * p22 + 2.0 * (mx * my * p01 + mx * mz * p02 + my * mz * p12)) / mm
        rad_g = (gx * gx * p33 + gy * gy * p44 + gz * gz * p55 + 2.0 * (gx * gy * p34 + gx * gz * p35 + gy * gz * p45)) / gg
        var_m = (p00 + p11 + p22 - rad_m) / (2.0 * mm)
        var_g = (p33 + p44 + p55 - rad_g) / (2.0 * gg)
        wm, wg = 1.0 / max(var_m, 1e-30), 1.0 / max(var_g, 1e-30)
        cd, sd = math.cos(self._dip), math.sin(self._dip)
        # Information Σ wᵢ (I − rᵢrᵢᵀ): y decouples; x–z block [[a, c], [c, d]].
        iyy = wm + wg
        ia, ic, idd = wm * (1.0 - cd * cd) + wg, -wm * cd * sd, wm * (1.0 - sd * sd)
        det = ia * idd - ic * ic
        return idd / det, -ic / det, ia / det, 1.0 / iyy

    def _uninitialised(self, t: float, extra: int = 0) -> AttitudeEstimate:
        nan3 = np.full(3, math.nan)
        return AttitudeEstimate(
            t_s=t, q_wxyz=np.array([1.0, 0.0, 0.0, 0.0]), roll_rad=math.nan, pitch_rad=math.nan,
            yaw_rad=math.nan, heading_mag_rad=math.nan, heading_true_rad=math.nan, rate_body_rad_s=nan3,
            gyro_bias_rad_s=self._x[_B].copy(), sigma_rpy_rad=np.full(3, math.pi),
            flags=EstimateFlags.INITIALISING | EstimateFlags(extra),
        )


__all__ = ["ThesisKf", "ThesisKfParams", "DEFAULT_THESIS_KF_PARAMS"]
