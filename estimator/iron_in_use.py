"""The iron learned on top of the magnetometer calibration, as the filter holds it (ins.Ins): the learner
(heading_monitor.IronLearner), its learning window's yaw error (learned_iron.WindowYawShare), whether the iron was
restored from an earlier run, the time of the last learning step, and whether the kernel's field reference is the
one this iron set.

Ins tells it its inputs — the magnetometer sample, the attitude and its covariance, the WMM field at the filter's
position, the kernel's field-check state — and writes the learned iron into the kernel's parameters itself. What
a learned iron changes elsewhere (the magnetometer heading's variance, the harmonic states' prior, the kernel's use
of the magnetometer) reads `learned` and the learner from here.
"""

from __future__ import annotations

import math

import numpy as np

from . import mag_heading as mag
from .heading_monitor import IronLearner
from .learned_iron import WindowYawShare

FIRST_STEP_S = 0.2
"""The span the first learning step counts (no step before it): the heading checks' rate, one per fused fix at 5 Hz."""


class IronInUse:
    """The learned iron and its bookkeeping (see the module docstring)."""

    def __init__(self, prior_sigma_ut: float, soft_prior_sigma: float) -> None:
        self.learner = IronLearner(prior_sigma_ut, soft_prior_sigma)
        self.yaw_share = WindowYawShare()     # the learning window's yaw error in the learned iron
        self.last_t_s: float | None = None    # the last learning step's time
        self.restored = False                 # the iron was restored from an earlier run (`restore`)
        self.field_reference_from_iron = False   # the kernel's field reference is this iron's (WMM)

    @property
    def learned(self) -> bool:
        """An iron was learned (at least one step) or restored: its covariance, not the calibration's figure,
        states the hard iron's error."""
        return self.learner.updates > 0 or self.restored

    def restore(self, offset_ut, cov_ut2, soft_iron=None, soft_cov=None) -> None:
        """Start from a learned iron persisted earlier (IronLearner.set; raises ValueError as it does). What its
        window's yaw was is not persisted: the share starts at zero."""
        self.learner.set(offset_ut, cov_ut2, soft_iron, soft_cov)
        self.yaw_share.reset()
        self.restored = True

    def forget(self) -> None:
        """Back to the prior: nothing learned, nothing restored."""
        self.learner.reset()
        self.yaw_share.reset()
        self.restored = False

    def new_calibration(self, soft_prior_sigma: float) -> None:
        """A new calibration is in force with this soft-iron prior 1σ: a learned iron's takes effect at its reset;
        with nothing learned yet the learner starts from the new prior, as when built."""
        self.learner.soft_prior_sigma = soft_prior_sigma
        if not self.learned:
            self.yaw_share.reset()
            self.learner.reset()

    def learn(self, t_s: float, mag_ut: np.ndarray, c_bn: np.ndarray, field_ned_ut: np.ndarray,
              attitude_cov_rad2: np.ndarray, yaw_var_rad2: float, unmodelled_ut: float, tau_s: float,
              magnetometer_fused: bool = False) -> None:
        """One learning step at t_s: the magnetometer sample (µT, body, calibration applied, learned iron not),
        against the WMM field with the filter's attitude c_bn and its 3×3 covariance; the filter's yaw variance
        (rad²) at the step feeds the window's yaw share. The attitude error is counted as new every `tau_s` (s),
        so a step `dt` apart inflates its noise by tau_s / dt (at least 1). `magnetometer_fused`: the kernel fuses
        the magnetometer while its iron is learned (Ins._set_magnetometer_use: only a rejected magnetometer that can
        never be trusted here): the filter reads the learned offset back as heading, and learned on, the offset
        would follow the filter's yaw; once known as well as the filter knows its yaw it is held
        (IronLearner.hold_offset)."""
        if magnetometer_fused:
            self.learner.hold_offset(field_ned_ut, float(yaw_var_rad2))
        last = self.last_t_s if self.last_t_s is not None else t_s - FIRST_STEP_S
        dt = max(t_s - last, 1e-3)
        self.last_t_s = t_s
        self.learner.update(mag_ut, c_bn, field_ned_ut, attitude_cov_rad2, unmodelled_ut, max(1.0, tau_s / dt))
        self.yaw_share.step(*self.learner.last_gain, math.sqrt(max(yaw_var_rad2, 0.0)))

    def release_offset(self) -> None:
        """The magnetometer was rejected: the iron may have changed, its heading offset is learned again."""
        self.learner.release_offset()

    def harmonic_cov(self) -> np.ndarray:
        """The learned iron's error covariance (N_IRON×N_IRON): the learner's, which averages the filter's yaw
        error down over the window's updates, plus the window's common yaw error (learned_iron.py)."""
        return self.learner.cov + self.yaw_share.cov()

    def follow_field_reference(self, mag_state, field_ned_ut: np.ndarray | None) -> None:
        """The kernel's field check (mag_heading._track_field) compares the magnitude and dip of the field it
        fuses — the iron-corrected one — with a reference it took from the first field and adopts a new one only
        after 20 s of rotation faster than 20 °/s, which a boat or a car never turns. A learned iron changes the
        field the kernel fuses, so a reference taken before it is of another field: on a vehicle started without
        a calibration, the raw field's (strong iron: ~25 % off the Earth's), against which the corrected field
        read as disturbed from the end of the learning on, and the magnetometer went unused for
        `mag_reject_max_s` and then fused with 100 times its noise for the rest of the run. The learner maps the
        field onto the WMM's (IronLearner), so with a learned iron the reference is the WMM field's magnitude and
        dip at the filter's position (the check then follows the accepted field as before, `mag_ref_tau_s`);
        forgotten again (the next field sets it) when the learned iron is reset. `mag_state` is the kernel's
        MAG_HEADING_STATE_DTYPE record (written in place), `field_ned_ut` the WMM field (None: not known)."""
        if self.learned and field_ned_ut is not None:
            field = field_ned_ut
            horizontal_ut = math.hypot(float(field[0]), float(field[1]))
            mag_state["ref_norm_ut"] = mag_state["cand_norm_ut"] = float(np.linalg.norm(field))
            mag_state["ref_dip_rad"] = mag_state["cand_dip_rad"] = math.atan2(float(field[2]), horizontal_ut)
            self.field_reference_from_iron = True
        elif not self.learned and self.field_reference_from_iron:
            mag.relearn_reference(mag_state, 0.0)
            self.field_reference_from_iron = False
