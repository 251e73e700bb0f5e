"""The GNSS fixes fused into ins.Ins's state: a usable fix (gnss_intake.py) fused against the state history at its
time of validity through the antenna arm in use (ins_core.fuse_gnss), its velocity kept for a yaw reset and handed
to the GNSS yaw bank, and the lever-arm check (lever_arm_fit.py) fed with the velocity innovation before the fix
and the correction it made; an arm the check adopts is fused at from then on.

The part owns the lever-arm check, the last fix's velocity and what that fix's update added to the velocity. It
writes the kernel's state, covariance and history and the GNSS yaw bank's arrays it is built with (the filter's
own, in place); the fix intake (its queue and counters) is the filter's, lent for reading a fix and counting what
became of it. What a fused velocity starts next — the heading checks — is the filter's to call (Ins._fuse).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ahrsd.core.gnss import GnssFix

from . import ins_core as core
from .filter_output import float_field_slice
from .gnss_intake import GnssFixIntake
from .gsf_yaw import gsf_fuse_velocity_of, gsf_reset
from .history_rows import bracket
from .kernel_entry import argument_types, entry_point
from .lever_arm_fit import RATE_MEAN_S, LeverArmFit, LeverArmFitResult
from .lever_arm_kernel import fix_innovation
from .rotations import quat_to_dcm

log = logging.getLogger("ahrsd.estimator.ins")    # the filter's own log: what the daemon's operator reads as ins's
_HIST_Q, _HIST_VEL, _HIST_RATE = (float_field_slice(core.INS_HISTORY_DTYPE, name)
                                  for name in ("q", "vel_ned_m_s", "rate_rad_s"))


class InsGnssFusion:
    """A fix into the filter's state, with the lever-arm check and the velocity a yaw reset sets (see the module
    docstring). `x_arr`, `P`, `hist`, `par_arr`: the kernel's 1-element state and parameter record arrays, its
    covariance and history; `gsf_arr`, `gsf_par_arr`: the GNSS yaw bank's; `told_arm_m`: the antenna arm the
    filter was told (body FRD, m); `gnss_yaw`: the bank runs; `adopt_arm`: the lever-arm check may adopt its fit."""

    def __init__(self, x_arr: np.ndarray, P: np.ndarray, hist: np.ndarray, par_arr: np.ndarray, gsf_arr: np.ndarray,
                 gsf_par_arr: np.ndarray, intake: GnssFixIntake, *, told_arm_m, gnss_yaw: bool,
                 adopt_arm: bool) -> None:
        self._x_arr, self._P, self._hist, self._par_arr = x_arr, P, hist, par_arr
        self._x, self._par = x_arr[0], par_arr[0]
        self._gsf_arr, self._gsf_par_arr = gsf_arr, gsf_par_arr
        self._gsf, self._gsf_par = gsf_arr[0], gsf_par_arr[0]
        # the bank's arm, written at every velocity fix: through a view of the field (a record's field assignment
        # costs several µs)
        self._gsf_arm_m = gsf_par_arr["lever_arm_m"][0]
        self._intake = intake
        self._told_arm_m = told_arm_m
        self._gnss_yaw = gnss_yaw
        # what each fix reads of the history (`state_at`, `_add_to_lever_arm_fit`): its times as a view, its rows as
        # flat float64 rows (one interpolation for the attitude, velocity and rate)
        self._hist_t_s = hist["t_s"]
        self._hist_rows = hist.view(np.float64).reshape(core.H_LEN, -1)
        # the bank's per-fix kernel called with its 1-element arrays through its entry point (kernel_entry.py:
        # these arrays only): a record argument costs several µs to unbox, an array a fraction of one
        fuse_args = (gsf_arr, gsf_par_arr, 0.0, np.zeros(3), 0.0)
        self._gsf_fuse_velocity = entry_point(gsf_fuse_velocity_of, argument_types(gsf_fuse_velocity_of, fuse_args))
        # the kernel's fix update through its entry point for these arrays, float and bool arguments (kernel_entry.py:
        # the dispatcher resolves 18 argument types at every call); `fuse` passes exactly these types
        gnss_args = (x_arr, P, hist, par_arr) + (0.0,) * 10 + (False,) * 4
        self._fuse_gnss = entry_point(core.fuse_gnss, argument_types(core.fuse_gnss, gnss_args))
        # the lever-arm check's innovation at a fix through its entry point for the rows, ints, floats and 3-vectors
        innovation_args = (self._hist_rows, 0, 0, 0.0, np.zeros(3), np.zeros(3), 0.0)
        self._fix_innovation = entry_point(fix_innovation, argument_types(fix_innovation, innovation_args))
        # can the told antenna arm explain the velocity innovations? (and adopt the fitted one, if asked)
        self.lever_arm_fit = LeverArmFit(adopt=adopt_arm)
        self.last_fix_velocity = None     # (t_fix, NED m/s with the vertical NaN when not used, speed 1σ)
        self._fix_velocity_step = None    # (t_fix, m/s) what the last fix's own update added to the velocity

    def reset(self) -> None:
        """The filter's reset: the lever-arm check forgets, and an arm adopted in the run before is not kept."""
        self.lever_arm_fit.reset()
        self.use_arm(self._told_arm_m)

    def restart(self) -> None:
        """The filter (re)started: no fix velocity for a yaw reset."""
        self.last_fix_velocity = None
        self._fix_velocity_step = None

    def fuse(self, fix: GnssFix) -> tuple[int, bool]:
        """Fuse one fix whose time the IMU samples have reached: its usable parts (position, height, velocity,
        vertical velocity), each weighted by the fix's own 1σ; then count what the kernel did. Returns the core.R_*
        bits (0 when nothing was usable) and whether the lever-arm check adopted its fitted arm at this fix."""
        parts = self._intake.read(fix)
        if parts is None:
            return 0, False
        _, lat, lon, alt, v, sig_h, sig_v, sig_s, use_pos, use_alt, use_vel, use_vd = parts
        if use_vel:
            self._keep_fix_velocity(float(fix.t_s), v, use_vd, sig_s)
            self._add_to_lever_arm_fit(float(fix.t_s), v, use_vd, sig_s)
        x = self._x
        vel_before = x["vel_ned_m_s"].copy()
        res = self._fuse_gnss(
            self._x_arr, self._P, self._hist, self._par_arr, float(fix.t_s),
            math.radians(lat) if use_pos else 0.0, math.radians(lon) if use_pos else 0.0,
            alt if use_alt else 0.0, v[0] if use_vel else 0.0, v[1] if use_vel else 0.0,
            v[2] if use_vd else 0.0, sig_h, sig_v, sig_s, use_pos, use_alt, use_vel, use_vd,
        )
        velocity_step = x["vel_ned_m_s"] - vel_before
        adopted = False
        if use_vel:
            adoptions = self.lever_arm_fit.adoptions
            self.lever_arm_fit.fused(velocity_step, bool(res & core.R_VEL_REJECTED))
            if self.lever_arm_fit.adoptions != adoptions:
                self._adopt_fitted_arm()
                adopted = True
            else:
                self._gsf_arm_m[:] = self.lever_arm_fit.bank_arm(self._told_arm_m)
        # the update corrected the state and the history rows after the fix's time, not those up to it: kept for
        # a yaw reset at this fix (`reset_velocity_to_fix`). The resets from a first fix or after an outage
        # correct the row at the fix's time as well, so they leave nothing to add
        step_rows = not res & (core.R_NAV_INIT | core.R_OUTAGE_RESET)
        self._fix_velocity_step = (float(fix.t_s), velocity_step) if step_rows else None
        # the gates' NIS only for a rejection's log line (a nested record read costs a few µs)
        self._intake.count(res, fix, x["vel_gate"]["nis"] if res & core.R_VEL_REJECTED else math.nan,
                           x["pos_gate"]["nis"] if res & core.R_POS_REJECTED else math.nan)
        return res, adopted

    def _keep_fix_velocity(self, t_s: float, v: np.ndarray, use_vd: bool, sig_s: float) -> None:
        """Keep the fix's velocity (vertical NaN when not used) for a yaw reset, which sets the velocity to it, and
        give it to the GNSS yaw bank."""
        vel = np.array([v[0], v[1], v[2] if use_vd else math.nan], dtype=np.float64)
        self.last_fix_velocity = (t_s, vel, sig_s)
        if self._gnss_yaw:
            self._gsf_fuse_velocity(self._gsf_arr, self._gsf_par_arr, float(t_s), vel, float(sig_s))

    def _add_to_lever_arm_fit(self, t_s: float, v: np.ndarray, use_vd: bool, sig_s: float) -> None:
        """The fix's velocity innovation at the antenna arm the filter fuses with (`arm_in_use`), before the fix is
        fused, from the history interpolated at its time of validity as the kernel reads it (`state_at`), for the
        lever-arm check (lever_arm_fit.py): lever_arm_kernel.fix_innovation, compiled (the same floats as the
        Python of `state_at` and tests/lever_arm_reference.py)."""
        found, innovation, rate_cross, vel = self._fix_innovation(
            self._hist_rows, int(self._x["hist_newest"]), int(self._x["hist_count"]), t_s,
            np.array([v[0], v[1], v[2] if use_vd else math.nan]), self.arm_in_use(), 0.5 * RATE_MEAN_S)
        if found:
            self.lever_arm_fit.add(t_s, innovation, rate_cross, sig_s, vel)

    def _kept_history_rows(self) -> np.ndarray:
        """The indices of the history's kept rows (hist_count ≤ H_LEN), newest first."""
        return (int(self._x["hist_newest"]) - np.arange(int(self._x["hist_count"]))) % core.H_LEN

    def state_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The attitude (body → NED DCM), velocity (NED m/s) and body rate (rad/s) the history holds at t_s,
        interpolated between its two rows as the kernel does for a fix (core._history_at); None before any row.
        For the lever-arm check's innovation and a yaw reset's velocity at the fix: one reading for both."""
        i0, i1, w = bracket(self._hist_t_s, int(self._x["hist_newest"]), int(self._x["hist_count"]), t_s)
        if i0 < 0:
            return None
        a, b = self._hist_rows[i0], self._hist_rows[i1]
        row = a + w * (b - a)
        q, vel, rate = row[_HIST_Q], row[_HIST_VEL], row[_HIST_RATE]
        # |q| as `np.linalg.norm` computes it for a float vector (√ of its dot with itself), without its wrapper
        return quat_to_dcm(q / math.sqrt(q.dot(q))), vel, rate

    def arm_in_use(self) -> np.ndarray:
        """The antenna arm the filter fuses with: the told one plus what the lever-arm check adopted."""
        return self.lever_arm_fit.arm_in_use(self._told_arm_m)

    def use_arm(self, arm_m) -> None:
        """Fuse the velocities (the filter's and the GNSS yaw bank's) at this antenna arm (body FRD, m)."""
        self._par["lever_arm_m"] = np.asarray(arm_m, dtype=float)
        self._gsf_par["lever_arm_m"] = np.asarray(arm_m, dtype=float)

    def _adopt_fitted_arm(self) -> None:
        """The lever-arm check adopted its fitted error (lever_arm_fit.py `_adopt`): the filter and the GNSS yaw
        bank fuse at the corrected arm; the bank starts again (its hypotheses took the velocities through the
        wrong arm). The heading, bent by the wrong arm, is found again as at the start: the filter's to say
        (HeadingConfirmation.arm_adopted). Nothing is persisted: the arm is the operator's configuration."""
        arm = self.arm_in_use()
        self.use_arm(arm)
        gsf_reset(self._gsf, self._gsf_par, float(self._x["t_last_s"]), np.full(4, np.nan))
        log.warning("ins: the GNSS velocities fit an antenna at %s m (body FRD), told %s m: fusing at the fitted arm "
                    "(adoption %d); set lever_arm_m", ",".join(f"{v:.2f}" for v in arm),
                    ",".join(f"{v:g}" for v in self._told_arm_m), self.lever_arm_fit.adoptions)

    def reset_velocity_to_fix(self) -> None:
        """Set the velocity to the last fix's (at its time of validity, through the lever arm with the reset
        attitude), its variance to the fix's: while the yaw was wrong the GNSS velocities were rejected and the
        velocity integrated accelerations rotated by the wrong yaw; fusing that error after the reset would turn
        the new yaw away again (ArduPilot's emergency yaw reset likewise resets velocity and position to GPS)."""
        if self.last_fix_velocity is None:
            return
        t_fix, v_fix, sig_s = self.last_fix_velocity
        x, hist = self._x, self._hist
        # every kept row once: one indexed add, not a Python loop over up to H_LEN rows
        rows = self._kept_history_rows()
        step = self._fix_velocity_step
        if step is not None and step[0] == t_fix:
            # this fix's own update (fuse_gnss, just before the heading checks that reset the yaw) moved the
            # velocity of the state and of the rows after the fix's time, not of the rows up to it: without the
            # same step there, the velocity at the fix's time read below is the one before the update, and the
            # reset keeps the update's step as a velocity error. Computed with the wrong yaw's covariance, that
            # step can be large; the next fixes' velocities are then rejected while the tilt the wrong yaw left
            # drives the velocity off, and what is fused after that turns the new yaw away again (docs/gnss.md,
            # "The velocity a yaw reset sets")
            older = rows[hist["t_s"][rows] <= t_fix]
            hist["vel_ned_m_s"][older] += step[1]
            self._fix_velocity_step = None     # the rows now carry it: a second reset at this fix adds nothing
        at = self.state_at(t_fix)
        if at is None:
            return          # the fix is older than the history (no row up to it took the step above either)
        c_bn, vel, rate = at
        v_ant = vel + c_bn @ np.cross(rate, self.arm_in_use())
        m = 3 if math.isfinite(v_fix[2]) else 2
        dv = np.zeros(3)
        dv[:m] = v_fix[:m] - v_ant[:m]
        x["vel_ned_m_s"] += dv
        hist["vel_ned_m_s"][rows] += dv
        P = self._P
        for i in range(m):
            e = core.E_V + i
            P[e, :] = 0.0
            P[:, e] = 0.0
            P[e, e] = sig_s ** 2
        x["vel_gate"]["rejected_since_s"] = math.nan

    def result(self) -> LeverArmFitResult | None:
        """The lever-arm check over the latest velocity fixes (lever_arm_fit.py), None before it has enough."""
        return self.lever_arm_fit.result()
