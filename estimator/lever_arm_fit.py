"""Can a wrong antenna lever arm explain the GNSS velocities an aided filter rejects? The check the rejection warning
needs before it names the lever arm (issue 28: "not the lever arm, when the lever-arm check cannot explain it"), and
before it names the heading while the heading is only not yet known (estimator/velocity_rejection_cause.py).

The receiver measures the antenna's velocity, v_ant = v + C (ω × r) (Groves, Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems, 2nd ed., eq. 14.123): v the IMU's velocity, C body → NED, ω the body
rate, r the antenna's place from the IMU (body FRD). The filter predicts it with the arm it was told, r_told, so
its velocity innovation holds C (ω × δr) = C [ω×] δr with δr = r − r_told, plus its own velocity error and the
receiver's noise. A wrong heading or tilt makes a velocity error that follows the vehicle's accelerations and
changes slowly against the 5 Hz fixes; the arm's term follows the body rate, which on a rolling boat or a turning
vehicle changes from fix to fix. So the check fits δr by least squares to the *differences* of consecutive
innovations (which remove the slowly changing part) against the differences of C [ω×], and says the arm explains
the innovations when δr is significant against its own covariance (χ², three degrees of freedom), removes a real
share of their variance, and the gate is rejecting fixes. The last is what keeps a right arm from being found
wrong: in a car's or a plane's turns the filter's own velocity error follows the yaw rate too, and a fit to it can
come out significant at a tenth of the variance with nothing rejected. A vehicle that does not rotate leaves δr unobservable: the covariance says so and
the check does not claim it.

Once it has explained them the arm stays **found wrong** (`arm_wrong`) until a fit finds no significant error and
rules out the error found (each by χ² against the fit's covariance): the arm is configuration, it does not heal within a run, and a window that explains less (a calm spell) does not make
the heading the wrong arm bent (through the GNSS yaw bank's resets and the velocity updates) right again. While it is
found wrong, the aided filter publishes its heading as unknown (ins.py `_build_estimate`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from .rotations import skew

WINDOW_PAIRS = 100             # fix-to-fix differences fitted: 20 s at 5 Hz
MIN_PAIRS = 30                 # fewer: no verdict
MAX_PAIR_GAP_S = 0.6           # consecutive velocity fixes further apart than this are not differenced
CHI2_3DOF_P999 = 16.27         # δr significant: its χ² against its covariance beyond the 99.9 % point of χ²(3)
MIN_EXPLAINED_SHARE = 0.1      # and the fitted arm removes at least this share of the differences' sum of squares
MIN_REJECTED_SHARE = 0.1       # and the gate rejected at least this share of the window's fixes: an arm explains
                               # rejections; a filter that rejects none is not bent by its arm beyond its noise


class LeverArmFitResult(NamedTuple):
    """The fitted error of the told arm (`offset_m`, body FRD, m: the antenna is at told + offset) with its 1σ
    (`sigma_m`), the share of the innovation differences' sum of squares it removes (`explained_share`), whether
    the arm explains the innovations (`explains`) and the offset's χ² against its covariance (`chi2`)."""

    offset_m: np.ndarray
    sigma_m: np.ndarray
    explained_share: float
    explains: bool
    chi2: float = 0.0

    def antenna_m(self, told_m) -> np.ndarray:
        """Where the fit puts the antenna (body FRD, m): the told arm plus the fitted error."""
        return np.asarray(told_m, dtype=float) + self.offset_m


def rate_cross_ned(c_bn: np.ndarray, rate_b_rad_s: np.ndarray) -> np.ndarray:
    """C [ω×]: the NED velocity of an antenna offset δr (body) per metre of δr, as a 3 × 3 matrix."""
    return c_bn @ skew(rate_b_rad_s)


class LeverArmFit:
    """The lever-arm check over the last WINDOW_PAIRS fix-to-fix differences. `add` each offered velocity fix's
    innovation (fix less the filter's prediction at the antenna it was told, NED m/s; a NaN component is not used)
    with C [ω×] at its time of validity (`rate_cross_ned`) and its 1σ, then `fused` with what the filter did with
    it; `result()` is the latest fit."""

    def __init__(self):
        self._pairs: deque = deque(maxlen=WINDOW_PAIRS)
        self._rejected: deque = deque(maxlen=WINDOW_PAIRS)     # per velocity fix: the gate rejected it
        self._last = None
        self._result: LeverArmFitResult | None = None
        self._dirty = False
        self.arm_wrong = False     # latched: a fit explained the innovations, none since found the arm right
        self._found_offset_m = np.zeros(3)

    def reset(self) -> None:
        self.__init__()

    def add(self, t_s: float, innovation_ned_m_s: np.ndarray, rate_cross: np.ndarray, sigma_m_s: float) -> None:
        nu = np.asarray(innovation_ned_m_s, dtype=float).reshape(3)
        last, self._last = self._last, (float(t_s), nu, np.asarray(rate_cross, dtype=float), float(sigma_m_s))
        if last is None or not (0.0 < t_s - last[0] <= MAX_PAIR_GAP_S):
            return
        d_nu = nu - last[1]
        use = np.isfinite(d_nu)
        if not use.any():
            return
        # the difference of two fixes' noise: variance the sum of theirs
        self._pairs.append((d_nu[use], (rate_cross - last[2])[use], math.hypot(sigma_m_s, last[3])))
        self._dirty = True

    def fused(self, velocity_correction_ned_m_s: np.ndarray, rejected: bool) -> None:
        """What the filter did with the latest fix: corrected its velocity by this (fused, or reset to it) and
        whether its gate `rejected` the velocity. The next difference is taken against the innovation the
        corrected state would have had, so that the correction, which is not the antenna's, does not enter the
        fit; then the fit and the latch (`arm_wrong`) are brought up to date."""
        self._rejected.append(bool(rejected))
        self._dirty = True
        if self._last is not None:
            t_s, nu, rate_cross, sigma = self._last
            self._last = (t_s, nu - np.asarray(velocity_correction_ned_m_s, dtype=float), rate_cross, sigma)
        result = self.result()
        if result is None:
            return
        if result.explains:
            self.arm_wrong, self._found_offset_m = True, result.offset_m
        elif self.arm_wrong and result.chi2 <= CHI2_3DOF_P999 and _chi2(self._found_offset_m - result.offset_m,
                                                                          result.sigma_m) > CHI2_3DOF_P999:
            self.arm_wrong = False      # the arm is right after all: this fit rules out the error found before

    def result(self) -> LeverArmFitResult | None:
        """The fit over the window, or None with fewer than MIN_PAIRS differences."""
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
        noise_var = np.repeat([p[2] ** 2 for p in self._pairs], [len(p[0]) for p in self._pairs])
        ata = a.T @ a
        if np.linalg.cond(ata) > 1e12:        # no rotation: the arm is not observable
            self._result = LeverArmFitResult(np.full(3, math.nan), np.full(3, math.inf), 0.0, False, math.nan)
            return self._result
        offset = np.linalg.solve(ata, a.T @ y)
        residual = y - a @ offset
        # the residual's own scale, never below the receiver's: the filter's own error left after differencing
        scale_var = max(float(residual @ residual) / max(len(y) - 3, 1), float(np.mean(noise_var)))
        cov = np.linalg.inv(ata) * scale_var
        chi2 = float(offset @ np.linalg.solve(cov, offset))
        total = float(y @ y)
        share = 1.0 - float(residual @ residual) / total if total > 0.0 else 0.0
        rejecting = sum(self._rejected) >= MIN_REJECTED_SHARE * max(len(self._rejected), 1)
        self._result = LeverArmFitResult(offset, np.sqrt(np.diag(cov)), share,
                                         chi2 > CHI2_3DOF_P999 and share >= MIN_EXPLAINED_SHARE and rejecting, chi2)
        return self._result


def _chi2(offset_m: np.ndarray, sigma_m: np.ndarray) -> float:
    """χ² of an offset against independent 1σ per axis (a bound: the fit's axes correlate a little)."""
    return float(np.sum((np.asarray(offset_m) / np.asarray(sigma_m)) ** 2))
