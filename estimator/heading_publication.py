"""What `ins` publishes about its heading: the heading state an estimate carries, its integrity figures and the
heading checks' report.

The heading checks (ins.Ins._check_heading, at the fused fixes) decide what the filter does with its yaw; this part
is told, at the end of each check, what they left (the published yaw σ, the GNSS yaw bank's output, the
magnetometer's step rejection, the learned iron, the lever-arm fit's verdict) and keeps what follows for the
outside: the heading state held at the check rate (heading_state_hold.py), the integrity record, the first step
rejection. When an estimate is built it answers the state to publish from the estimate's flags and yaw σ. It owns
that state and reads nothing of the filter: the filter's figures are arguments, and so is the heading monitor (read
through the `MonitorVerdicts` Protocol, which heading_monitor.HeadingMonitor satisfies), at each call: a new
calibration replaces the filter's monitor (Ins.set_mag_calibration_sigma) while this part's state goes on. The
figures it judges with come through `PublicationParams` (InsParams satisfies it).

Why the states are as they are: docs/gnss.md ("Heading state"), docs/estimator.md, heading_state_hold.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from ahrsd.core.estimate import HeadingIntegrity, HeadingState

from .heading_state_hold import HeadingStateHold
from .kernel_flags import F_GNSS_AIDED as _F_GNSS_AIDED, F_INITIALISING as _F_INITIALISING


@dataclass(frozen=True)
class HeadingReport:
    mag_rejections: int            # times the heading monitor rejected the magnetometer
    max_disagreement_deg: float    # the largest disagreement (with the GNSS-held heading or yaw) at a rejection
    yaw_resets: int                # resets of the yaw to the GNSS yaw
    mag_steps: int = 0             # of the rejections, those for a step of the magnetometer heading (mag_step.py)
    first_step_t_s: float = math.nan     # the first of those: its time (NaN: none)
    first_step_deg: float = math.nan     # ... and the step of the magnetometer heading it saw


class StepDetections(Protocol):
    detections: int     # the magnetometer heading steps found (mag_step.py)


class MonitorVerdicts(Protocol):
    """What the part reads of the heading monitor (heading_monitor.HeadingMonitor)."""

    mag_rejected: bool
    learning: bool
    disagreement_rad: float
    rejections: int
    max_disagreement_rad: float
    step: StepDetections

    def heading_state(self, yaw_sigma_rad: float, initialising: bool, aided: bool, unknown_sigma_rad: float,
                      mag_var_rad2: float) -> HeadingState: ...


class PublicationParams(Protocol):
    """The figures the part judges with (InsParams' fields of the same names)."""

    heading_unknown_sigma_rad: float
    heading_known_sigma_rad: float
    heading_state_hold_s: float
    mag_unavailable_s: float
    init_min_time_s: float
    heading_monitor: bool
    mag_enabled: bool


class HeadingPublication:
    """The published heading of one run of the filter (built again when the heading checks start again)."""

    def __init__(self, params: PublicationParams):
        self._unknown_sigma_rad = params.heading_unknown_sigma_rad
        self._mag_unavailable_s = params.mag_unavailable_s
        self._init_min_time_s = params.init_min_time_s
        self._heading_monitor = params.heading_monitor
        self._mag_enabled = params.mag_enabled
        self.state = HeadingState.UNKNOWN     # at the latest check, held (`publish`)
        self._hold = HeadingStateHold(params.heading_state_hold_s, params.heading_known_sigma_rad)
        self.integrity: HeadingIntegrity | None = None    # at the latest check
        self.rejection_step_rad = math.nan   # the step (mag_step.py) the current rejection is for (NaN: none)
        self.first_step: tuple[float, float] | None = None   # (t_s, step rad) of the first step rejection

    def note_step_rejection(self, t_s: float, step_rad: float, mag_rejected: bool) -> None:
        """Whether the magnetometer is rejected now for a step of its heading (the integrity says so, the daemon
        names it): from the check whose step test rejected it until it re-enters (mag_rejected: the monitor's
        verdict at this check); the first such step for the report."""
        if math.isfinite(step_rad):
            self.rejection_step_rad = step_rad
            if self.first_step is None:
                self.first_step = (t_s, step_rad)
        elif not mag_rejected:
            self.rejection_step_rad = math.nan

    def publish(self, t_s: float, monitor: MonitorVerdicts, yaw_sigma_rad: float, gsf_yaw: float, gsf_var: float,
                gsf_valid: bool, mag_trust_var_rad2: float, mag_since_update_s: float, iron_offset_ut, iron_sigma_ut,
                heading_bent: bool) -> None:
        """At the end of a heading check: the integrity figures and the heading state. monitor: the filter's heading
        monitor after this check's decision; yaw_sigma_rad: the yaw 1σ to
        publish (the filter's, at least the unconfirmed heading's floor); gsf_*: the GNSS yaw bank's output;
        mag_trust_var_rad2: the magnetometer heading's variance the monitor trusts it with; mag_since_update_s: the
        time since the kernel last fused a field; iron_*: the learned iron; heading_bent: the lever-arm fit's
        verdict (lever_arm_fit.py)."""
        m = monitor
        self.integrity = HeadingIntegrity(gsf_yaw, math.sqrt(gsf_var) if math.isfinite(gsf_var) else math.nan,
                                          gsf_valid, m.disagreement_rad, iron_offset_ut, iron_sigma_ut,
                                          self.rejection_step_rad, heading_bent)
        raw = m.heading_state(yaw_sigma_rad, False, True, self._unknown_sigma_rad, mag_trust_var_rad2)
        if raw == HeadingState.MAGNETOMETER and mag_since_update_s > self._mag_unavailable_s:
            # the monitor lets the magnetometer back, but the kernel's field check still rejects every field (its
            # norm/dip reference was learned on the field before the iron was learned, and is re-learned only
            # after mag_new_time_s of rotation): the GNSS still holds the heading, as the flags say
            raw = HeadingState.LEARNING if m.learning else HeadingState.GNSS_ONLY
        # held at the check rate, so the state does not depend on how often estimates are built
        self.state = self._hold.update(t_s, raw, yaw_sigma_rad)

    def published(self, f: int, yaw_sigma_rad: float, t_run_s, mag_use, monitor: MonitorVerdicts) -> HeadingState:
        """The state an estimate carries: f, its flags; yaw_sigma_rad, its yaw 1σ; t_run_s, the filter's run time,
        and mag_use, the kernel's magnetometer use (0: not fused), as one-element arrays (the filter's views);
        monitor, the heading monitor (its verdict `mag_rejected`). Called for every estimate built: the run time,
        the use and the verdict are read only on the branches that need them (an aided filter past its start needs
        none)."""
        if not yaw_sigma_rad <= self._unknown_sigma_rad:
            return HeadingState.UNKNOWN
        if f & _F_INITIALISING:
            # INITIALISING also stands for a yaw σ above `converged_yaw_rad` (3°) or a tilt σ above 1°. Aided, a
            # GNSS-held heading with σ up to `heading_unknown_sigma_rad` is what GNSS_ONLY and LEARNING say (the
            # boat's GNSS yaw is 5–6° for minutes; the published σ covers its error): only the start-up time or a
            # heading the magnetometer alone would claim keep it UNKNOWN (the flag itself stays: no VPE yet)
            aided = f & _F_GNSS_AIDED and t_run_s[0] >= self._init_min_time_s
            if not (aided and self._heading_monitor
                    and self.state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING)):
                return HeadingState.UNKNOWN
        if not f & _F_GNSS_AIDED:
            # unaided the magnetometer is the only heading reference: trusted only when it is in use and not
            # rejected (a rejected one may still be fused at its learned iron's σ, `iron_heading_corr_rad`)
            if not self._mag_enabled or mag_use[0] <= 0.0 or monitor.mag_rejected:
                return HeadingState.UNKNOWN
            return HeadingState.MAGNETOMETER
        return self.state if self._heading_monitor else HeadingState.MAGNETOMETER

    def report(self, monitor: MonitorVerdicts, yaw_resets: int) -> HeadingReport:
        """What the heading checks did so far (replay's summary, the daemon's warning): the monitor's counts, the
        filter's yaw resets and the first step rejection."""
        m = monitor
        t_step, step = self.first_step if self.first_step is not None else (math.nan, math.nan)
        return HeadingReport(m.rejections, math.degrees(m.max_disagreement_rad), yaw_resets,
                             m.step.detections, t_step, math.degrees(step))
