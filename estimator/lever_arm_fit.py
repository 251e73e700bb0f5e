"""Can a wrong antenna lever arm explain the GNSS velocities an aided filter rejects? The check the rejection warning
needs before it names the lever arm (issue 28: "not the lever arm, when the lever-arm check cannot explain it"), and
before it names the heading while the heading is only not yet known (estimator/velocity_rejection_cause.py).

The receiver measures the antenna's velocity, v_ant = v + C (ω × r) (Groves, Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems, 2nd ed., eq. 14.123): v the IMU's velocity, C body → NED, ω the body
rate, r the antenna's place from the IMU (body FRD). The filter predicts it with the arm it was told, r_told, so
its velocity innovation holds C (ω × δr) = C [ω×] δr with δr = r − r_told, plus its own velocity error and the
receiver's noise. A wrong heading or tilt makes a velocity error that follows the vehicle's accelerations; the arm's
term follows the body rate, which on a rolling boat or a turning vehicle changes from fix to fix. So the check fits
δr to the *differences* of consecutive innovations (which remove the slowly changing part) against the differences
of C [ω×], beside what an attitude error makes of the velocity change over each interval (a heading error turns
it: in a car's or a plane's turns that follows the yaw rate as the arm's term does, and a heading 100° off was
taken for an arm tens of metres long), with a prior on δr (PRIOR_SIGMA_M) and only along the directions the
rotation observes (a car's arm height is not: it is left at the told arm instead of going into a lateral offset).
It says the arm explains the innovations when δr is significant against its own covariance (χ², as many degrees
of freedom as directions fitted), removes a real share of what the attitude's part leaves, and the gate is
rejecting fixes. The last is what keeps a right arm from being found
wrong: in a car's or a plane's turns the filter's own velocity error follows the yaw rate too, and a fit to it can
come out significant at a tenth of the variance with nothing rejected. A vehicle that does not rotate leaves δr
unobservable: no direction is fitted and the check does not claim it.

Once it has explained them the arm stays **found wrong** (`arm_wrong`) until a fit finds no significant error and
rules out the error found (each by χ² against the fit's covariance): the arm is configuration, it does not heal within a run, and a window that explains less (a calm spell) does not make
the heading the wrong arm bent (through the GNSS yaw bank's resets and the velocity updates) right again. While it is
found wrong, the aided filter publishes its heading as unknown (ins.py `_build_estimate`), and the GNSS yaw bank
takes the velocities through the arm the check found (`bank_arm`), not through the wrong one: a bank fed through
the wrong arm has its yaw bent as the filter's, and one not let reset the filter's yaw leaves that yaw held by
nothing, wandering until the fit over it is the filter's error (docs/gnss.md). The latch is released only while the
gate fuses the fixes: a fit over a filter whose heading the wrong arm let wander far is that filter's own error.

The fitted error is adopted once the fit is sure of it (its total 1σ at most ADOPT_SIGMA_SHARE of it), as VectorNav and SBG
units estimate or adopt the antenna arm: the filter and the bank then fuse at told + `correction_m` (`arm_in_use`),
and the check goes on fitting the error of that arm (adopting again when it explains the rejections). The heading
stays unknown (`heading_bent`) until the arm in use has left a full window's rejections at the right-arm level
(RIGHT_ARM_REJECTED_SHARE); the told arm stays found wrong (`arm_wrong`: the configuration is the operator's, and
nothing is persisted). Every consumer reads these latches through `result()`, not the momentary `explains`.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

WINDOW_PAIRS = 100             # fix-to-fix differences fitted: 20 s at 5 Hz
MIN_PAIRS = 30                 # fewer: no verdict
MAX_PAIR_GAP_S = 0.6           # consecutive velocity fixes further apart than this are not differenced
PRIOR_SIGMA_M = 2.0            # 1σ per axis of the told arm's error: a receiver's antenna on these vehicles (a boat's
                               # mast, a car's roof, a plane's spine) sits within a few metres of the IMU; a direction
                               # the fixes observe less well than this is left at the told arm (docs/gnss.md)
CHI2_P999 = (math.inf, 10.83, 13.82, 16.27)   # δr significant: its χ² against its covariance beyond the 99.9 % point
                               # of χ²(k), k the directions fitted (none: no verdict)
MIN_EXPLAINED_SHARE = 0.1      # and the fitted arm removes at least this share of what the attitude's part leaves
MIN_REJECTED_SHARE = 0.1       # and the gate rejected at least this share of the window's fixes: an arm explains
                               # rejections; a filter that rejects none is not bent by its arm beyond its noise
RATE_MEAN_S = 0.1              # the body rate of the arm's term is the gyro's mean over this span about the fix: one
                               # sample's noise (ADIS16405 0.5°/s at 204.8 SPS, twice that at 819.2), doubled by
                               # the differencing, is a third of a boat's roll-rate change between fixes and shrinks
                               # the fitted arm towards zero (errors in the regressor; docs/gnss.md), while a
                               # vehicle's rotation does not change within it (a boat rolls in seconds)
ADOPT_SIGMA_SHARE = 0.25       # a fitted error is adopted once its total 1σ (√ trace of its covariance) is at most
                               # this share of its size
RIGHT_ARM_REJECTED_SHARE = 0.02   # an adopted arm is right once a full window's rejections are at most this share:
                               # a right arm leaves the gate rejecting next to none (docs/gnss.md)


class LeverArmFitResult(NamedTuple):
    """The fitted error of the told arm (`offset_m`, body FRD, m: the antenna is at told + offset) with its 1σ
    (`sigma_m`), the share of the innovation differences' sum of squares it removes (`explained_share`), whether
    the arm explains the innovations (`explains`) and the offset's χ² against its covariance (`chi2`)."""

    offset_m: np.ndarray
    sigma_m: np.ndarray
    explained_share: float
    explains: bool
    chi2: float = 0.0
    arm_wrong: bool = False                 # LeverArmFit.arm_wrong: the told arm found wrong (the latch)
    told_error_m: np.ndarray | None = None  # the told arm's error as best known (LeverArmFit.result)
    arm_adopted: bool = False               # the filter uses told + told_error_m (LeverArmFit.correction_m)
    heading_bent: bool = False              # LeverArmFit.heading_bent: the arm in use not shown right
    adopted_m: np.ndarray | None = None     # LeverArmFit.correction_m: the arm in use is the told one plus this
    cov_m2: np.ndarray | None = None        # the fitted offset's covariance over the directions fitted (m²)
    directions: int = 3                     # how many directions of δr the fixes observe (the rest left at 0)

    def antenna_m(self, told_m) -> np.ndarray:
        """Where the check puts the antenna (body FRD, m): the told arm plus its error as best known."""
        err = self.offset_m if self.told_error_m is None else self.told_error_m
        return np.asarray(told_m, dtype=float) + err


class LeverArmFit:
    """The lever-arm check over the last WINDOW_PAIRS fix-to-fix differences. `add` each offered velocity fix's
    innovation (fix less the filter's prediction at the antenna it was told, NED m/s; a NaN component is not used)
    with C [ω×] at its time of validity (lever_arm_kernel.fix_innovation makes both) and its 1σ, then `fused` with
    what the filter did with it; `result()` is the latest fit."""

    def __init__(self, adopt: bool = True, prior_sigma_m: float = PRIOR_SIGMA_M):
        self.prior_sigma_m = float(prior_sigma_m)
        self._pairs: deque = deque(maxlen=WINDOW_PAIRS)
        self._rejected: deque = deque(maxlen=WINDOW_PAIRS)     # per velocity fix: the gate rejected it
        self._last = None
        self._segment = 0          # counts the filter's yaw resets: each starts another attitude error (`_fit`)
        self._result: LeverArmFitResult | None = None
        self._dirty = False
        self.arm_wrong = False     # latched: a fit explained the innovations, none since found the arm right
        self._found_offset_m = np.zeros(3)
        self.adopt = adopt
        self.correction_m = np.zeros(3)  # adopted: the innovations are taken at told + correction_m (`arm_in_use`)
        self.adoptions = 0
        self.in_use_wrong = False  # the arm in use explains the rejections (before an adoption: arm_wrong)
        self._in_use_offset_m = np.zeros(3)  # the arm in use's error the last explaining fit found
        self.in_use_right = False  # an adopted arm left a full window's rejections at the right-arm level

    def reset(self) -> None:
        self.__init__(self.adopt, self.prior_sigma_m)

    def heading_reset(self) -> None:
        """The filter's yaw was reset (its velocity set to a fix, its biases set back): the pairs after it hold
        another attitude error than those before it, so they get their own attitude columns (`_fit`), and no pair is
        taken across the reset (its velocity step is not the arm's). The arm's columns are the same on both sides:
        the pairs before it still say where the antenna is. The latches and an adopted arm are kept."""
        self._segment += 1
        self._last = None
        self._dirty = True

    @property
    def heading_bent(self) -> bool:
        """The heading is bent by an antenna arm error: the told arm found wrong and no adopted arm shown right
        (the aided filter publishes its heading unknown)."""
        return self.arm_wrong and not self.in_use_right

    def arm_in_use(self, told_m) -> np.ndarray:
        """The arm the innovations are taken at and the filter fuses with: the told arm plus what was adopted."""
        return np.asarray(told_m, dtype=float) + self.correction_m

    def bank_arm(self, told_m) -> np.ndarray:
        """The arm the GNSS yaw bank takes the velocities through: the arm in use, or, while that is found wrong,
        the arm in use plus the error the last explaining fit found (not yet sure enough to be adopted by the
        filter, but a bank fed through the arm found wrong has its yaw bent as the filter's)."""
        arm = self.arm_in_use(told_m)
        return arm + self._in_use_offset_m if self.in_use_wrong else arm

    def add(self, t_s: float, innovation_ned_m_s: np.ndarray, rate_cross: np.ndarray, sigma_m_s: float,
            velocity_ned_m_s=None) -> None:
        """One offered fix: its innovation, C [ω×] and 1σ, and the filter's (IMU's) velocity at its time (NED m/s;
        None: not known, the heading's part of the innovations is then not modelled)."""
        nu = np.asarray(innovation_ned_m_s, dtype=float).reshape(3)
        vel = None if velocity_ned_m_s is None else np.asarray(velocity_ned_m_s, dtype=float).reshape(3)
        last, self._last = self._last, (float(t_s), nu, np.asarray(rate_cross, dtype=float), float(sigma_m_s), vel)
        if last is None or not (0.0 < t_s - last[0] <= MAX_PAIR_GAP_S):
            return
        d_nu = nu - last[1]
        use = np.isfinite(d_nu)
        every = use.all()
        if not (every or use.any()):
            return
        d_rc = rate_cross - last[2]
        att = _attitude_columns(None if vel is None or last[4] is None else vel - last[4], float(t_s) - last[0])
        if not every:       # every component used (the vertical fused): the rows as they are, not a masked copy
            d_nu, d_rc, att = d_nu[use], d_rc[use], att[use]
        # the difference of two fixes' noise: variance the sum of theirs
        self._pairs.append((d_nu, d_rc, math.hypot(sigma_m_s, last[3]), att, self._segment))
        self._dirty = True

    def fused(self, velocity_correction_ned_m_s: np.ndarray, rejected: bool) -> None:
        """What the filter did with the latest fix: corrected its velocity by this (fused, or reset to it) and
        whether its gate `rejected` the velocity. The next difference is taken against the innovation the
        corrected state would have had, so that the correction, which is not the antenna's, does not enter the
        fit; then the fit and the latch (`arm_wrong`) are brought up to date."""
        self._rejected.append(bool(rejected))
        self._dirty = True
        if self._last is not None:
            # and the filter's velocity change to the next fix is the one it integrates, not this step
            step = np.asarray(velocity_correction_ned_m_s, dtype=float)
            t_s, nu, rate_cross, sigma, vel = self._last
            self._last = (t_s, nu - step, rate_cross, sigma, None if vel is None else vel + step)
        if not self.arm_wrong and not self._rejecting():
            # nothing to latch, adopt or release: an arm explains only while the gate rejects, and is adopted or
            # released only once latched (the fit is made when asked, `result`: the daemon's and replay's warnings
            # ask on rejections)
            return
        result = self._fit()
        if result is None:
            return
        if result.explains:
            self.in_use_wrong, self.in_use_right = True, False
            self._in_use_offset_m = result.offset_m
            if not self.adoptions:
                self.arm_wrong, self._found_offset_m = True, result.offset_m
            if self.adopt and _confident(result):
                self._adopt(result.offset_m)
        elif self.arm_wrong and not self.adoptions and result.chi2 <= CHI2_P999[result.directions] and _chi2(
                self._found_offset_m - result.offset_m, result) > CHI2_P999[result.directions] \
                and not self._rejecting():
            # the arm is right after all: this fit rules out the error found, and the gate fuses the fixes (a fit
            # over a filter whose heading a wrong arm let wander far is its own error, not the arm's)
            self.arm_wrong = self.in_use_wrong = False
        elif self.adoptions and not self.in_use_wrong and len(self._rejected) == WINDOW_PAIRS \
                and sum(self._rejected) <= RIGHT_ARM_REJECTED_SHARE * WINDOW_PAIRS:
            self.in_use_right = True    # the adopted arm leaves the gate rejecting as a right arm does

    def _adopt(self, offset_m: np.ndarray) -> None:
        """Take the fitted error into the arm in use (told + correction_m): the kept differences become those the
        new arm would have given (each less its ΔC[ω×] δr), the rejections start again (they were the old arm's)."""
        offset_m = np.asarray(offset_m, dtype=float)
        self.correction_m = self.correction_m + offset_m
        self.adoptions += 1
        self.in_use_wrong, self.in_use_right = False, False
        self._in_use_offset_m = np.zeros(3)
        self._pairs = deque(((d_nu - d_rc @ offset_m, d_rc, sig, att, seg) for d_nu, d_rc, sig, att, seg
                             in self._pairs), maxlen=WINDOW_PAIRS)
        if self._last is not None:
            t_s, nu, rate_cross, sigma, vel = self._last
            self._last = (t_s, nu - rate_cross @ offset_m, rate_cross, sigma, vel)
        self._rejected.clear()
        self._dirty = True

    def _rejecting(self) -> bool:
        """The gate rejected at least MIN_REJECTED_SHARE of the window's velocity fixes."""
        return sum(self._rejected) >= MIN_REJECTED_SHARE * max(len(self._rejected), 1)

    def result(self) -> LeverArmFitResult | None:
        """The fit over the window with the latch and the arm's error as best known (what every consumer reads:
        `arm_wrong`, `antenna_m`), or None with fewer than MIN_PAIRS differences."""
        fit = self._fit()
        if fit is None:
            return None
        if self.adoptions:
            told_error = self.correction_m + (fit.offset_m if self.in_use_wrong else 0.0)
        else:
            told_error = self._found_offset_m if self.arm_wrong else fit.offset_m
        return fit._replace(arm_wrong=self.arm_wrong, told_error_m=told_error, arm_adopted=self.adoptions > 0,
                            heading_bent=self.heading_bent, adopted_m=self.correction_m)

    def _fit(self) -> LeverArmFitResult | None:
        """The fit over the window, or None with fewer than MIN_PAIRS differences.

        The model of a difference of innovations: ΔC[ω×] δr (the arm) plus what an attitude error makes of the
        vehicle's velocity change over the interval (`_attitude_columns`: a heading error turns it, a tilt error or
        an accelerometer bias adds g·Δt-like constants; Groves eq. 14.69's specific-force term) plus the receivers'
        noise. The attitude's part is fitted beside the arm and marginalised out (the arm's information is its Schur
        complement), so a heading not yet known, whose error follows the accelerations of a car's or a plane's turns,
        is not taken for an arm. The arm is fitted only along the directions the fixes observe better than the prior
        (PRIOR_SIGMA_M: eigen-decomposition of its information); the others stay at the told arm with the prior's
        variance (a car turns about its vertical only: its arm's height is left alone, not put into a lateral
        offset). Along the fitted directions the prior is added to the information (a Gaussian prior on δr)."""
        if not self._dirty:
            return self._result
        self._dirty = False
        if len(self._pairs) < MIN_PAIRS:
            self._result = None
            return None
        # once per fix over the whole window: each pair's rows are (k, 3) already (what vstack would make of them),
        # and each difference's noise variance is repeated over its k components in one call, not one array a pair
        y = np.concatenate([p[0] for p in self._pairs])
        a = np.concatenate([p[1] for p in self._pairs])
        n = _per_segment(self._pairs)
        noise_var = np.repeat([p[2] ** 2 for p in self._pairs], [len(p[0]) for p in self._pairs])
        n = n[:, np.linalg.norm(n, axis=0) > 1e-9 * max(1.0, float(np.abs(n).max(initial=0.0)))]
        # the attitude's columns projected out of the arm's and of the innovations (least squares on both)
        if n.shape[1]:
            proj = np.linalg.lstsq(n, np.column_stack([a, y]), rcond=None)[0]
            rest = np.column_stack([a, y]) - n @ proj
            a_r, y_r = rest[:, :3], rest[:, 3]
        else:
            a_r, y_r = a, y
        ata = a_r.T @ a_r
        # the residual's own scale, never below the receiver's: the filter's own error left after differencing
        free = np.linalg.lstsq(a_r, y_r, rcond=None)[0]
        residual_free = y_r - a_r @ free
        dof = max(len(y) - 3 - n.shape[1], 1)
        scale_var = max(float(residual_free @ residual_free) / dof, float(np.mean(noise_var)))
        info = ata / scale_var                    # the arm's information from the fixes, 1/m²
        prior_info = 1.0 / self.prior_sigma_m ** 2
        eig, vec = np.linalg.eigh(info)
        fitted = eig > prior_info                 # the fixes say more than the prior along these
        k = int(np.sum(fitted))
        if k == 0:                                # no rotation: the arm is not observable
            self._result = LeverArmFitResult(np.full(3, math.nan), np.full(3, math.inf), 0.0, False, math.nan,
                                             directions=0)
            return self._result
        v = vec[:, fitted]
        post = eig[fitted] + prior_info
        offset = v @ ((v.T @ (a_r.T @ y_r / scale_var)) / post)
        cov = (v / post) @ v.T
        full_cov = cov + prior_info ** -1 * (np.eye(3) - v @ v.T)     # the unfitted directions: the prior's
        chi2 = float(np.sum((v.T @ offset) ** 2 * post))
        residual = y_r - a_r @ offset
        total = float(y_r @ y_r)
        share = 1.0 - float(residual @ residual) / total if total > 0.0 else 0.0
        rejecting = self._rejecting()
        self._result = LeverArmFitResult(offset, np.sqrt(np.diag(full_cov)), share,
                                         chi2 > CHI2_P999[k] and share >= MIN_EXPLAINED_SHARE and rejecting, chi2,
                                         cov_m2=cov, directions=k)
        return self._result


def _attitude_columns(dv_ned_m_s: np.ndarray | None, dt_s: float) -> np.ndarray:
    """What an attitude error makes of the velocity change between two fixes, per unit of each of its parameters
    (3 × 5, NED rows): the horizontal velocity change turned by a heading error ψ (its (cos ψ − 1) and sin ψ parts,
    exact for any ψ: a heading not yet known can be 100° off) and constants over the interval (a tilt error turns
    gravity into a horizontal acceleration, an accelerometer bias adds one). The filter's velocity change stands
    for the specific force's integral; its vertical part is gravity's and a heading does not turn it. Not known
    (None): the heading's columns are zero (and not fitted)."""
    dn, de = (0.0, 0.0) if dv_ned_m_s is None else (float(dv_ned_m_s[0]), float(dv_ned_m_s[1]))
    return np.array([[dn, -de, dt_s, 0.0, 0.0],
                     [de, dn, 0.0, dt_s, 0.0],
                     [0.0, 0.0, 0.0, 0.0, dt_s]])


def _per_segment(pairs) -> np.ndarray:
    """The attitude's columns of every pair's rows, one block of them per segment between the filter's yaw resets
    (`LeverArmFit.heading_reset`): a reset sets the heading, the velocity and the biases anew, so each segment has
    its own heading error, tilt and accelerometer bias."""
    att = np.concatenate([p[3] for p in pairs])
    seg = np.repeat([p[4] for p in pairs], [len(p[0]) for p in pairs])
    segments, which = np.unique(seg, return_inverse=True)
    if len(segments) == 1:
        return att
    width = att.shape[1]
    n = np.zeros((len(att), width * len(segments)))
    cols = which[:, None] * width + np.arange(width)
    n[np.arange(len(att))[:, None], cols] = att
    return n


def _confident(fit: LeverArmFitResult) -> bool:
    """The fitted error is known well enough to be adopted: its total 1σ (√ of the trace of its covariance over the
    directions fitted: the full covariance, whatever the axes, and never below its 1σ along its own direction) at
    most ADOPT_SIGMA_SHARE of its size."""
    if not np.all(np.isfinite(fit.offset_m)) or fit.cov_m2 is None:
        return False
    return math.sqrt(max(float(np.trace(fit.cov_m2)), 0.0)) <= ADOPT_SIGMA_SHARE * float(np.linalg.norm(fit.offset_m))


def _chi2(offset_m: np.ndarray, fit: LeverArmFitResult) -> float:
    """χ² of an offset against the fit's covariance, over the directions the fit observes (the others are not
    compared: the fit says nothing of them)."""
    offset_m = np.asarray(offset_m, dtype=float)
    if fit.cov_m2 is None:
        return float(np.sum((offset_m / np.asarray(fit.sigma_m)) ** 2))
    return float(offset_m @ np.linalg.pinv(fit.cov_m2, hermitian=True) @ offset_m)
