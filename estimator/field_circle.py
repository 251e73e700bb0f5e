"""A magnetometer calibration checked without GNSS: the levelled field of a vehicle that turns sweeps a circle.

Without GNSS the magnetometer is the only heading reference and its calibration's own figure (calibration_
heading.py) is all the published σ knows of the iron. A calibration that claims to be good but is wrong (the hard
iron moved after calibrating — a battery, a winch, a load — or a bad fit accepted) would be believed: σ stays
small while the heading is off. This part is the classic compass swing done in operation. The body field levelled
by the filter's tilt, m_lev = R_y(θ)·R_x(φ)·m (the body frame turned about its own vertical only), has a
horizontal part that, as the vehicle turns, sweeps a circle of radius H (the horizontal Earth field) about a
centre:

* with a right calibration the centre is 0 and the circle round;
* a hard iron the calibration did not remove, Δb, moves the centre by its horizontal part, and the heading
  error is a sinusoid in the heading of amplitude asin(|Δb_h| / H);
* a soft-iron error makes it an ellipse: m = (I + E)·h with E's traceless symmetric part (e₁, e₂) gives a heading
  error sin(2ψ + …) of amplitude √(e₁² + e₂²) rad (E's isotropic part only scales the radius; its antisymmetric
  part is a constant heading offset no rotation can show).

The fit is linear least squares of the conic |m|² + β(x² − y²) + γ·2xy + d·m + F = 0 (Kåsa's circle fit with two
ellipse terms; the radius is fitted, so a WMM magnitude error or a local anomaly does not move the centre),
over an exponentially forgetting window. Its uncertainty comes from the residuals themselves (floored at the
magnetometer noise and the tilt σ times the vertical field, the horizontal field error a tilt error makes), each
levelled field weighted as one `correlation_s`-th of an independent one (tilt errors and waves are correlated
over seconds). A straight leg gives no evidence either way: the centre is judged only once the field has
covered `min_sectors` of 8 heading sectors within the window; until then and while the centre and the ellipse
are within their χ² gate, the check adds nothing. Beyond it, the heading error the fit implies (the sinusoids'
RMS, √((A_h² + A_s²)/2), so 3σ covers their sum A_h + A_s) replaces the calibration's own figure in the published
variance's consider term (calibration_heading.py) where it is the larger: a calibration that stated the error it
leaves is not wrong, one that claims less than the circle shows is (`finds_wrong`).

An iron that moves within the window mixes two circles: where the vehicle has kept to a few headings since, the
fit may take the moved one for an ellipse and stay within its gate, but its residual grows far beyond its floor
(`scatter_gate`); that is flagged too, with the heading error such a mixture implies. Before it comes to that,
new fields that sit off the fitted circle by more than their noise allows are a change point (field_circle_
change.py, Page's CUSUM): the fit restarts from the fields after it, its centre is fitted on the old radius (a
hard iron moves the circle, not its radius) until the restarted fit covers the turns again (`moved`), and the
vertical iron the move left — the levelled field's vertical shift — widens the fields' error and σ through the
tilt (`vertical_ut`).

Sources: W. Premerlani, "Automatic nulling of magnetometer offsets" (DIY Drones, 2010) and "Magnetometer offsets
revisited" (2011): offsets rotate with the body while the Earth field does not, so rotation separates them;
ArduPilot's `CompassLearn` (libraries/AP_Compass/Compass_learn.cpp) learns offsets in flight against the EKF-GSF
yaw, which needs GNSS — this check needs none. It says how far the calibration can be trusted; mekf then removes
the hard iron it shows from the field (field_circle_correction.py: `correction_ut`, judged against). What it
cannot see: a vertical hard iron on a level vehicle (it never leaves the vertical; a move of it shows as the
levelled vertical's shift, field_circle_change.py), the antisymmetric soft iron (a constant heading offset), and
anything while the vehicle does not turn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import IntEnum

import numpy as np

from ahrsd.core.estimate import EstimateFlags

from .field_circle_change import CircleChange, LevelledField, centre_on_known_radius, heading_sector

SKIPPED_FLAGS = int(EstimateFlags.INITIALISING)
"""A filter's estimate flags whose field the check does not take. It takes every field after start-up, also those
the norm/dip check rejects: a wrong hard iron swings the field's norm as the vehicle turns, and the fields it
pushes beyond the norm tolerance are the ones that show the circle off-centre (a 9 µT error on the simulated car:
never judged without them). A passing disturbance widens the fit's residual (its σ) rather than moving a centre
seen from every heading."""
N_SECTORS = 8
"""Heading sectors the coverage counts (45° each)."""


def hard_iron_heading_var_rad2(offset_ut: float, radius_ut: float) -> float:
    """A hard iron of `offset_ut` left in a horizontal field of `radius_ut` turns the heading by a sinusoid of
    amplitude asin(offset/H) in the heading: its mean square, rad²."""
    a = math.asin(min(1.0, offset_ut / radius_ut))
    return 0.5 * a * a


def vertical_heading_var_rad2(vertical_ut: float, tilt_rms_rad: float, radius_ut: float) -> float:
    """A vertical hard iron the calibration does not remove shows in the levelled horizontal field through the
    vehicle's tilt, up to |b_z|·sin τ: the heading error (b_z·sin τ / H)², τ the tilt's RMS (a consider term; 0 on
    a level vehicle, and without a vertical iron)."""
    return (vertical_ut * math.sin(tilt_rms_rad) / radius_ut) ** 2


class CalibrationVerdict(IntEnum):
    """What the check says of the calibration in force (`FieldCircleResult.verdict`; replay's mag_cal_check column)."""

    NOT_JUDGED = 0     # the field has not swept min_sectors sectors within the window: the vehicle did not turn enough
    CONSISTENT = 1     # judged: the circle shows no more heading error than the calibration states
    WRONG = 2          # judged: it shows more (finds_wrong)
    CORRECTED = 3      # not wrong now, with a correction learned from the turns applied (field_circle_correction.py)


def wrong_calibration_text(offset_ut: float, corrected: bool = False) -> str:
    """The cause a wrong calibration is named by (the daemon's STATUSTEXT, the replay's summary); `corrected`: the
    correction learned from the turns is applied and the field is consistent again."""
    if corrected:
        return (f"magnetometer field off-centre by {offset_ut:.1f} µT in turns: learned correction applied, "
                "recalibrate to confirm")
    return f"magnetometer field off-centre by {offset_ut:.1f} µT in turns: calibration wrong or iron changed"


@dataclass(frozen=True)
class FieldCircleParams:
    """The check's tuning. SI units, angles rad, fields µT."""

    period_s: float = 0.1
    """One levelled field per this long (the fit needs the heading's sweep, not the sample rate)."""
    solve_period_s: float = 1.0
    """The fit is solved and judged every this long."""
    window_s: float = 300.0
    """Forgetting time constant of the fit's sums: an iron change is seen within about this long."""
    correlation_s: float = 5.0
    """The levelled field's errors (tilt, waves, turn lean) are correlated over this long: each field counts as
    period_s / correlation_s of an independent one."""
    min_sector_s: float = 1.0
    """A heading sector counts as covered with this much (forgotten as the sums are) of field in it, s."""
    min_sectors: int = 6
    """The fit is judged once this many of the N_SECTORS heading sectors are covered (270°)."""
    gate_chi2: float = 18.4
    """The centre (2 dof) or the ellipse (2 dof) is significant beyond this χ² (a false alarm of 1e-4 for
    independent errors)."""
    scatter_gate: float = 3.0
    """The fields are not on one circle when the fit's residual variance exceeds this many times its floor (the
    noise's and the tilt σ's): the iron moved within the window (the old and the new circle mixed)."""
    mag_noise_ut: float = 0.7
    """Magnetometer noise per axis, µT (the floor of the residual's spread with the tilt's)."""


@dataclass(frozen=True)
class FieldCircleResult:
    """What the check found (µT, rad; NaN where not known)."""

    centre_ut: tuple = (math.nan, math.nan)   # the circle's centre in the levelled body frame (x fwd, y right)
    centre_sigma_ut: float = math.nan         # its 1σ, largest axis
    radius_ut: float = math.nan               # the fitted horizontal field
    anisotropy: float = math.nan              # the soft-iron heading error's amplitude, rad
    covered: bool = False                     # the field has swept min_sectors sectors within the window
    significant: bool = False                 # the centre or the ellipse is beyond its χ² gate, or the fields
                                              # are not on one circle (scatter beyond scatter_gate)
    heading_var_rad2: float = 0.0             # the heading variance to add to the published σ (0: nothing)
    correction_ut: tuple = (0.0, 0.0)         # the learned correction the centre was judged against (levelled)
    tilt_rms_rad: float = math.nan            # the filter's tilt over the window, RMS (how far levelled is from body)
    moved: bool = False                       # the iron moved and the fit restarted, not yet covering the turns
                                              # again: the centre is the fields' since the move on the old radius
                                              # (field_circle_change.py), its σ as wide as they leave it
    restarts: int = 0                         # how often the fit restarted after its iron moved (since reset)
    vertical_ut: float = 0.0                  # the vertical hard iron the moves left (the levelled field's vertical
                                              # shifts at the restarts): not removed, seen through the tilt

    @property
    def offset_ut(self) -> float:
        """|centre| of the field as the calibration gives it, µT (NaN while not fitted)."""
        return math.hypot(*self.centre_ut)

    @property
    def corrected(self) -> bool:
        """A correction learned from the turns is applied (field_circle_correction.py)."""
        return self.correction_ut != (0.0, 0.0)

    def finds_wrong(self, claimed_var_rad2: float) -> bool:
        """The circle shows more heading error than the calibration claims (its heading variance, rad²)."""
        return self.significant and self.heading_var_rad2 > claimed_var_rad2

    def verdict(self, claimed_var_rad2: float) -> CalibrationVerdict:
        """Not judged (too little turning), consistent, or wrong (finds_wrong) against the claimed variance, rad²."""
        if self.finds_wrong(claimed_var_rad2):
            return CalibrationVerdict.WRONG
        if self.corrected:
            return CalibrationVerdict.CORRECTED
        return CalibrationVerdict.CONSISTENT if self.covered else CalibrationVerdict.NOT_JUDGED

    def checked_var_rad2(self, claimed_var_rad2: float) -> float:
        """The calibration's heading variance as the published σ carries it: what it claims, or what the circle
        shows when that is more."""
        return max(claimed_var_rad2, self.heading_var_rad2)


class FieldCircleCheck:
    """`add(t_s, roll_rad, pitch_rad, mag_body_ut, tilt_sigma_rad, estimate_flags)` from `due_t_s` on (it takes one
    per period_s, none of an estimate flagged SKIPPED_FLAGS); True when a new `result` was judged. `reset()` forgets
    everything (a new calibration). `correction_ut`: a correction (levelled x, y) the filter subtracts from the
    field (field_circle_correction.py); the fit goes on with the fields as the calibration gives them and judges
    its centre minus it."""

    def __init__(self, params: FieldCircleParams | None = None):
        self.params = params or FieldCircleParams()
        self.reset()

    def reset(self) -> None:
        self._clear_sums()
        self._change = CircleChange()       # the iron moved: the fields left the circle (field_circle_change.py)
        self._moved: list | None = None     # the fields since it moved, while the restarted fit does not cover
        self._moved_radius_ut = math.nan
        self._moved_prior_ut = np.zeros(2)
        self._theta = np.zeros(5)           # the conic last solved
        self._resid = 0.0                   # its residual's variance per independent field
        self.restarts = 0
        self.vertical_ut = 0.0              # the vertical iron the moves left, µT (the levelled z's shifts)
        self.due_t_s = -math.inf          # the next field is taken from this time on
        self._next_solve_t_s = -math.inf
        self.correction_ut = (0.0, 0.0)
        self.result = FieldCircleResult()

    def _clear_sums(self) -> None:
        self._n = np.zeros((5, 5))         # Σ w u uᵀ, u = [x² − y², 2xy, x, y, 1]
        self._b = np.zeros(5)              # Σ w u t, t = −(x² + y²)
        self._tt = 0.0                     # Σ w t²
        self._w = 0.0                      # Σ w
        self._floor = 0.0                  # Σ w · (the residual's variance floor)
        self._tilt2 = 0.0                  # Σ w · (roll² + pitch²)
        self._z = 0.0                      # Σ w · (the levelled vertical field)
        self._zz = 0.0                     # Σ w · its square
        self._sector_s = np.zeros(N_SECTORS)
        self._last_t_s = math.nan

    def add(self, t_s: float, roll_rad: float, pitch_rad: float, mag_body_ut, tilt_sigma_rad: float,
            estimate_flags: int = 0) -> bool:
        if t_s < self.due_t_s:
            return False
        p = self.params
        if estimate_flags & SKIPPED_FLAGS:
            self.due_t_s = t_s + p.period_s
            return False
        mx, my, mz = float(mag_body_ut[0]), float(mag_body_ut[1]), float(mag_body_ut[2])
        if not (math.isfinite(mx) and math.isfinite(my) and math.isfinite(mz)
                and math.isfinite(roll_rad) and math.isfinite(pitch_rad)):
            return False
        self.due_t_s = t_s + p.period_s
        # levelled: the body frame turned about its own vertical only (C_bn = R_z(ψ)·R_y(θ)·R_x(φ))
        cr, sr = math.cos(roll_rad), math.sin(roll_rad)
        cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
        v = sr * my + cr * mz
        x = cp * mx + sp * v
        y = cr * my - sr * mz
        z = -sp * mx + cp * v
        w = p.period_s / p.correlation_s
        # a residual of the conic is ≈ 2·(m − c)·δm: the horizontal field error of the noise and of a tilt error
        # (the vertical field turned into the horizontal by it)
        tilt = tilt_sigma_rad if math.isfinite(tilt_sigma_rad) else 0.0
        var = p.mag_noise_ut ** 2 + (z * tilt) ** 2
        # a body-z iron b shows in the levelled horizontal as b·(sin θ cos φ, −sin φ): its gain
        # the levelled vertical's error: the noise and the horizontal field turned into the vertical by a tilt error
        var_z = p.mag_noise_ut ** 2 + (x * x + y * y) * tilt * tilt
        field = LevelledField(t_s, x, y, var, w, roll_rad * roll_rad + pitch_rad * pitch_rad, z,
                              math.hypot(sp * cr, sr), var_z)
        if self._change.see(field, self.vertical_ut):
            self._restart()
        else:
            self._take(field)
            if self._moved is not None:
                self._moved.append(field)
        if t_s < self._next_solve_t_s:
            return False
        self._next_solve_t_s = t_s + p.solve_period_s
        self.result = self._judge()
        if self.correction_ut != (0.0, 0.0) or self.restarts:
            self.result = replace(self.result, correction_ut=self.correction_ut, restarts=self.restarts,
                                  vertical_ut=self.vertical_ut)
        return True

    def _restart(self) -> None:
        """The iron moved (field_circle_change.py): the fit starts again from the fields since the change, and its
        centre is judged on the old radius until the restarted fit covers the turns again."""
        change = self._change
        fields = list(change.since)
        self._moved_radius_ut = change.radius_ut
        self._moved_prior_ut = change.centre_ut.copy()
        # the vertical iron moved by the levelled field's vertical shift (the Earth's vertical field is the same)
        w = np.array([f.weight for f in fields])
        self.vertical_ut += float(np.sum(w * np.array([f.z_ut for f in fields])) / np.sum(w)) - change.z_mean_ut
        change.reset()                      # no reference until the restarted fit judges
        self._clear_sums()
        for field in fields:
            self._take(field)
        self._moved = fields
        self.restarts += 1

    def _take(self, field: LevelledField) -> None:
        """One levelled field into the fit's sums; the vertical iron the moves left, seen through the tilt, widens
        its error."""
        p = self.params
        t_s, x, y, var, w, tilt2, z, gain, _ = field
        dt = p.period_s if not math.isfinite(self._last_t_s) else min(t_s - self._last_t_s, p.window_s)
        self._last_t_s = t_s
        self._forget(math.exp(-dt / p.window_s))
        u = np.array([x * x - y * y, 2.0 * x * y, x, y, 1.0])
        t = -(x * x + y * y)
        self._n += w * np.outer(u, u)
        self._b += w * t * u
        self._tt += w * t * t
        self._w += w
        self._tilt2 += w * tilt2
        self._z += w * z
        self._zz += w * z * z
        self._floor += w * 4.0 * (x * x + y * y) * (var + (self.vertical_ut * gain) ** 2)
        self._sector_s[heading_sector(x, y, N_SECTORS)] += p.period_s

    def _forget(self, f: float) -> None:
        self._n *= f
        self._b *= f
        self._tt *= f
        self._w *= f
        self._floor *= f
        self._tilt2 *= f
        self._z *= f
        self._zz *= f
        self._sector_s *= f

    def _judge(self) -> FieldCircleResult:
        p = self.params
        covered = int(np.count_nonzero(self._sector_s >= p.min_sector_s)) >= p.min_sectors
        if not covered or self._w <= 5.0:
            return FieldCircleResult(covered=False) if self._moved is None else self._judge_moved()
        self._moved = None
        result = self._judge_covered()
        if result.covered:
            self._change.set_reference(self._theta, result.radius_ut, result.centre_ut, result.centre_sigma_ut,
                                       self._resid, self._sector_s >= p.min_sector_s, self._z / self._w,
                                       max(self._zz / self._w - (self._z / self._w) ** 2, 0.0))
        return result

    def _judge_moved(self) -> FieldCircleResult:
        """After the iron moved, before the restarted fit covers the turns: the new centre from the fields since
        the move on the old radius, and the heading error it implies against the correction applied — the
        sinusoid of |c − correction| plus the centre's own σ over H (as wide as the circle where the fields since
        have not shown it), never more than π²."""
        r = self._moved_radius_ut
        c, cov, _ = centre_on_known_radius(self._moved, r, self._moved_prior_ut, self.vertical_ut)
        sigma_c = min(math.sqrt(float(np.max(np.linalg.eigvalsh(cov)))), r)
        left = float(np.hypot(*(c - np.asarray(self.correction_ut))))
        tilt_rms = math.sqrt(self._tilt2 / self._w) if self._w > 0.0 else 0.0
        var = min(hard_iron_heading_var_rad2(left, r) + (sigma_c / r) ** 2
                  + vertical_heading_var_rad2(self.vertical_ut, tilt_rms, r), math.pi ** 2)
        return FieldCircleResult((float(c[0]), float(c[1])), sigma_c, r, 0.0, False, True, var,
                                 tilt_rms_rad=tilt_rms, moved=True)

    def _judge_covered(self) -> FieldCircleResult:
        p = self.params
        try:
            theta = np.linalg.solve(self._n, self._b)
            n_inv = np.linalg.inv(self._n)
        except np.linalg.LinAlgError:
            return FieldCircleResult(covered=False)
        self._theta = theta
        beta, gamma, dx, dy, f0 = theta
        m = np.array([[1.0 + beta, gamma], [gamma, 1.0 - beta]])
        try:
            m_inv = np.linalg.inv(m)
        except np.linalg.LinAlgError:
            return FieldCircleResult(covered=False)
        c = -0.5 * m_inv @ np.array([dx, dy])
        r2 = float(c @ m @ c - f0)
        if not r2 > 0.0:
            return FieldCircleResult(covered=False)
        radius = math.sqrt(r2)
        # the residual's variance per independent field: the fit's own, never below the noise's and tilt's
        resid = max(self._tt - float(self._b @ theta), 0.0) / max(self._w - 5.0, 1.0)
        self._resid = resid
        floor = self._floor / self._w
        s2 = max(resid, floor)
        cov = s2 * n_inv
        # c = −½ M⁻¹ d: ∂c/∂β = −M⁻¹ diag(1, −1) c, ∂c/∂γ = −M⁻¹ [[0, 1], [1, 0]] c, ∂c/∂d = −½ M⁻¹
        jac = np.zeros((2, 5))
        jac[:, 0] = -m_inv @ np.array([c[0], -c[1]])
        jac[:, 1] = -m_inv @ np.array([c[1], c[0]])
        jac[:, 2:4] = -0.5 * m_inv
        cov_c = jac @ cov @ jac.T
        cov_e = cov[:2, :2]
        c_left = c - np.asarray(self.correction_ut)         # what the filter's field still has
        try:
            chi2_c = float(c_left @ np.linalg.solve(cov_c, c_left))
            chi2_e = float(theta[:2] @ np.linalg.solve(cov_e, theta[:2]))
        except np.linalg.LinAlgError:
            return FieldCircleResult(covered=False)
        left_ut = float(np.hypot(*c_left))
        a_hard = math.asin(min(1.0, left_ut / radius))
        a_soft = 0.5 * math.hypot(beta, gamma)          # β = −2e₁, γ = −2e₂ to first order
        fitted = chi2_c > p.gate_chi2 or chi2_e > p.gate_chi2
        var = 0.5 * (a_hard ** 2 + a_soft ** 2) if fitted else 0.0
        # not one circle: a field scattered by δm (RMS, beyond the floor) about the fitted one. Two circles mixed
        # (an iron that moved within the window) scatter by at most half their distance Δ (less where the fit's
        # centre and ellipse take some of it up), and the newer one's heading error is a sinusoid of amplitude Δ/r
        # whose phase the vehicle's few recent headings do not show: its amplitude 2δm/r as the 1σ, with
        # δm = √(resid − floor)/(2r)
        scattered = resid > p.scatter_gate * floor
        if scattered:
            var = max(var, (resid - floor) / radius ** 4)
        significant = fitted or scattered
        tilt_rms = math.sqrt(self._tilt2 / self._w)
        vertical_var = vertical_heading_var_rad2(self.vertical_ut, tilt_rms, radius)
        if significant:
            var += vertical_var
        sigma_c = math.sqrt(float(np.max(np.linalg.eigvalsh(cov_c))))
        if self.restarts:
            # the iron is known to have moved: a restarted fit too young to show its centre beyond the gate does not
            # make the calibration right again — its centre against the correction, and its own σ, stay in σ
            var = max(var, hard_iron_heading_var_rad2(left_ut, radius) + (sigma_c / radius) ** 2 + vertical_var)
        return FieldCircleResult((float(c[0]), float(c[1])), sigma_c, radius, a_soft, True, significant, var,
                                 tilt_rms_rad=tilt_rms)
