"""What the daemon says about its heading: the estimator's heading state (core.estimate.HeadingState) on the
status line, a STATUSTEXT naming the cause at every change, the magnetometer and AHRS health bits, whether
"heading good" may be said, and the yaw resets VISION_POSITION_ESTIMATE.reset_counter must announce.

The estimator decides the state (estimator/heading_monitor.py); this part only reports it, with its cause:
* UNKNOWN: no heading is published (VISION_POSITION_ESTIMATE withheld by its builder). Without GNSS this is
  also the state of a magnetometer with no calibration (or one of unknown quality): the estimator's σ then
  carries an unknown calibration error (estimator/calibration_heading.py).
* MAGNETOMETER: the magnetometer holds the heading and agrees with the GNSS yaw where there is one; without GNSS
  its σ includes the calibration's predicted heading error (and, unaided, the lean of a turn: it widens in turns).
* GNSS_ONLY / LEARNING: the magnetometer is rejected or not trusted and the GNSS velocity holds the heading
  (LEARNING: while the iron left after the calibration is learned).
"Heading good" (MAV_STATE ACTIVE, SYS_STATUS AHRS healthy) in any known state only while its 1σ is below
`good_sigma_rad` ([outputs] heading_good_sigma_deg): bad at once, good again only once the σ held below it
ANNOUNCE_AFTER_S, so a σ that swings with each turn does not flip MAV_STATE each time. A magnetometer heading
that becomes good by its state (the estimator holds a state change itself) is good at once, as before.

Without GNSS the estimator checks the calibration by the circle the levelled field sweeps in turns
(estimator/field_circle.py, `on_estimate(..., field_circle=)`): a circle off-centre (or elliptic) beyond its
uncertainty is a calibration that is wrong or an iron that changed. It is said as such ("magnetometer field
off-centre by X µT in turns: calibration wrong or iron changed", STATUSTEXT at the change), the magnetometer is
unhealthy in SYS_STATUS, and "heading good" is not said while it lasts (the estimator's σ carries the heading error
it implies; the heading is no better than that σ says). mekf then learns the hard iron the circle shows and removes
it from the field (estimator/field_circle_correction.py); once the corrected field is consistent again that is said
("… off-centre by X µT in turns: learned correction applied, recalibrate to confirm"), the magnetometer stays
unhealthy (the calibration in force is still wrong) and the heading may be good again by its σ, which carries what
the correction leaves.

An iron that steps (a battery or a load moved: the magnetometer heading steps while the gyro saw no turn,
estimator/mag_step.py) is named as such while the magnetometer is rejected for it (`HeadingIntegrity.mag_step_rad`):
"iron changed: mag heading stepped +4°, the gyro saw no turn; heading GNSS-held while the iron is relearned" — its
first 50 characters (one STATUSTEXT, what a receiver that does not join chunks shows) say what happened and by how
much; "heading good" is not said until the magnetometer re-enters (the relearned iron is not yet confirmed).

The magnetometer disagreement is named only when it is beyond what both sides' uncertainties explain: the GSF
yaw's 1σ and the calibration's predicted heading error (`calibration_sigma_rad`, NaN = no calibration), the
same 3σ test as the estimator's heading monitor.
"""

from __future__ import annotations

import math
from typing import Callable

from ahrsd.core.estimate import EstimateFlags, HeadingState
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.estimator.calibration_heading import calibration_heading_variance_rad2
from ahrsd.estimator.field_circle import CalibrationVerdict, wrong_calibration_text
from ahrsd.estimator.velocity_rejection_cause import heading_rejection_cause

STATE_LABELS = {HeadingState.UNKNOWN: "hdg unknown", HeadingState.MAGNETOMETER: "hdg mag",
                HeadingState.GNSS_ONLY: "hdg GNSS-only", HeadingState.LEARNING: "hdg learning"}
DISAGREEMENT_GATE_SIGMA = 3.0         # as the estimator's heading monitor (HeadingMonitor.gate_sigma)
UNCALIBRATED_SIGMA_RAD = math.radians(20.0)   # InsParams.mag_uncalibrated_sigma_rad: how far ins weighs an unknown calibration
TRUSTED_CALIBRATION_RAD = math.radians(3.0)   # HeadingMonitor.trusted_sigma_rad: a calibration ins trusts to hold the heading
ANNOUNCE_AFTER_S = 2.0                # a state must hold this long to be announced (no STATUSTEXT per flicker)
# An estimator that flags INITIALISING within this long after a calibration change is converging on the new
# calibration, not restarting: the swap widens its heading variance to cover the change (relearn_field_reference),
# and INITIALISING holds while the filter's own heading 1σ is above its convergence threshold (kernel_flags.py)
CALIBRATION_CONVERGE_WINDOW_S = 1.0


class HeadingStatus:
    """Reports the heading state. Inputs are explicit:

    statustext(severity, text): sends one text to the ground station (daemon.outbound: chunked when longer than one
    STATUSTEXT, rate limited).
    good_sigma_rad: largest yaw 1σ of a heading that is still "good" (magnetometer or GNSS-held).
    calibration_sigma_rad: the calibration's predicted heading error, 1σ (NaN: none); `set_calibration_sigma`.
    calibration_in_force: a magnetometer calibration is in force (with a NaN σ: one that states no heading error,
    said as such rather than "not calibrated").

    `on_estimate(est, now, yaw_resets)` at the housekeeping rate (the estimator's `yaw_resets` counter: each
    new reset is announced; the published yaw does not step, see estimator/published_heading.py, so
    VISION_POSITION_ESTIMATE.reset_counter is not touched); `status_text()`, `unhealthy_bits()`, `heading_good`,
    `rejection_cause(now)` for the status line, SYS_STATUS, MAV_STATE and the GNSS gate warning.
    """

    def __init__(self, statustext: Callable[[int, str], None], *, good_sigma_rad: float,
                 calibration_sigma_rad: float = math.nan, calibration_in_force: bool = False):
        self.statustext = statustext
        self.good_sigma_rad = float(good_sigma_rad)
        self.calibration_sigma_rad = float(calibration_sigma_rad)
        self.calibration_in_force = bool(calibration_in_force)
        self.state: HeadingState | None = None       # the latest estimate's state (None: no estimate yet)
        self.sigma_rad = math.nan
        self.disagreement_rad = math.nan              # magnetometer − GNSS yaw (NaN: no valid GNSS yaw)
        self.mag_inconsistent = False                 # the magnetometer disagrees with the GNSS(-held) heading
        self.mag_step_rad = math.nan                  # the magnetometer is rejected for this step of its heading
        self.lever_arm_bent = False                   # the heading is bent by an antenna arm found wrong (_take_estimate)
        self.initialising = True
        self.gnss_checked = False                     # the estimator checks its heading against GNSS (ins, fixes)
        self.announced: HeadingState | None = None
        self.announced_key: tuple | None = None      # (state, why it is UNKNOWN): a new cause is news too
        self.announcements = 0
        self._candidate: tuple[HeadingState, float] | None = None
        self._resets_announced = 0
        self._alignments_announced = 0
        self._last_reset_at = -math.inf
        self._good_since: float | None = None        # when the heading last became good enough
        self._wide_magnetometer = False               # it last stopped being good by a magnetometer heading's σ
        self._now = -math.inf
        self.field_off_centre_ut = math.nan           # the circle check's centre offset while it finds the calibration wrong
        self.field_corrected_ut = math.nan            # ... while a correction learned from the turns makes it consistent
        self.converging_on_calibration = False        # INITIALISING since a calibration change: converging on it
        self._calibration_changed_at: float | None = None

    def set_calibration_sigma(self, sigma_rad: float, in_force: bool | None = None) -> None:
        """A calibration in force (at start) or changed (after the first estimate: then an INITIALISING that
        follows is its convergence, `converging_on_calibration`)."""
        if self.state is not None:
            self._calibration_changed_at = self._now
        self.calibration_sigma_rad = float(sigma_rad)
        if in_force is not None:
            self.calibration_in_force = bool(in_force)

    def _no_figure(self, short: bool) -> str:
        """A calibration's heading error unknown (NaN σ): none in force, or one that states no figure."""
        if self.calibration_in_force:
            return "mag cal states no error" if short else "magnetometer calibration states no heading error"
        return "mag not calibrated" if short else "magnetometer not calibrated"

    # ------------------------------------------------------------------ inputs
    def on_estimate(self, est, now: float, yaw_resets: int = 0, gnss_yaw_alignments: int = 0,
                    field_circle=None) -> None:
        """The latest estimate (and the estimator's yaw reset count, and how many of those were the planned
        alignment to the GNSS yaw, and its circle check's FieldCircleResult or None) at `now`; announces a state
        that held ANNOUNCE_AFTER_S and every yaw reset: an alignment as news (INFO), a reset of a heading found wrong
        as a WARNING."""
        if est is None:
            return
        self._take_circle_verdict(field_circle)
        self._take_estimate(est, now)
        self._track_good(now)
        self._announce_yaw_resets(yaw_resets, gnss_yaw_alignments, now)
        self._announce_state_that_held(est, now)

    def _take_circle_verdict(self, field_circle) -> None:
        """The circle check's centre offset while it finds the calibration wrong, or consistent with the correction
        learned from the turns (NaN otherwise). The check runs only while a calibration states its heading error:
        its variance as the estimator states it."""
        claimed_var = calibration_heading_variance_rad2(self.calibration_sigma_rad)
        verdict = field_circle.verdict(claimed_var) if field_circle is not None else CalibrationVerdict.NOT_JUDGED
        self.field_off_centre_ut = field_circle.offset_ut if verdict == CalibrationVerdict.WRONG else math.nan
        self.field_corrected_ut = field_circle.offset_ut if verdict == CalibrationVerdict.CORRECTED else math.nan

    def _take_estimate(self, est, now: float) -> None:
        """The estimate's state, yaw σ and flags, and whether the magnetometer disagrees with the GNSS(-held)
        heading."""
        state = HeadingState(est.heading_state)
        self.state = state
        self.sigma_rad = float(est.sigma_rpy_rad[2])
        self.initialising = bool(est.flags & EstimateFlags.INITIALISING)
        self._track_calibration_convergence(now)
        self.gnss_checked = est.integrity is not None
        self.disagreement_rad, significant = self._disagreement(est.integrity)
        self.mag_step_rad = float(est.integrity.mag_step_rad) if est.integrity is not None else math.nan
        # the lever-arm check finds the arm the GNSS yaw bank takes the velocities through wrong, or not yet shown
        # right: a yaw reset then is no heading found (`_announce_yaw_resets`)
        self.lever_arm_bent = est.integrity is not None and bool(est.integrity.lever_arm_wrong)
        # a trusted calibration rejected by ins (GNSS-held state) disagreed with the heading GNSS holds
        self.mag_inconsistent = significant or self._iron_stepped() or (state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING)
                                                and self.calibration_sigma_rad <= TRUSTED_CALIBRATION_RAD)
        self._now = now

    def _track_calibration_convergence(self, now: float) -> None:
        """INITIALISING within CALIBRATION_CONVERGE_WINDOW_S of a calibration change is the convergence on it, until
        it ends (an estimate taken before the swap may come first: not initialising, it waits)."""
        changed = self._calibration_changed_at
        if self.initialising and changed is not None and now - changed <= CALIBRATION_CONVERGE_WINDOW_S:
            self.converging_on_calibration = True
        elif not self.initialising:
            self.converging_on_calibration = False
        if changed is not None and (self.converging_on_calibration or now - changed > CALIBRATION_CONVERGE_WINDOW_S):
            self._calibration_changed_at = None

    def _track_good(self, now: float) -> None:
        """Since when the heading is good enough (`heading_good` waits ANNOUNCE_AFTER_S), and whether a
        magnetometer heading's own σ made it not good (it then waits too)."""
        if not self._good_now():
            self._good_since = None
            self._wide_magnetometer = self.state == HeadingState.MAGNETOMETER and not self.initialising
        elif self._good_since is None:
            self._good_since = now

    def _announce_yaw_resets(self, yaw_resets: int, gnss_yaw_alignments: int, now: float) -> None:
        """Each new yaw reset: a planned alignment to the GNSS yaw as news (INFO), a reset of a heading found
        wrong as a WARNING. A count that went back is a restarted estimator: counting starts again."""
        if yaw_resets < self._resets_announced:
            self._resets_announced = yaw_resets
            self._alignments_announced = gnss_yaw_alignments
        if yaw_resets <= self._resets_announced:
            return
        wrong_headings = (yaw_resets - self._resets_announced) - (gnss_yaw_alignments - self._alignments_announced)
        self._resets_announced = yaw_resets
        self._alignments_announced = gnss_yaw_alignments
        self._last_reset_at = now
        if self.lever_arm_bent:
            # a reset or alignment while the antenna arm is found wrong (or a fitted one is on trial) finds no
            # heading: it stays unknown, as its own STATUSTEXT says (`_unknown_cause`)
            return
        if wrong_headings > 0:
            self.statustext(mavlink.MAV_SEVERITY_WARNING,
                            f"ahrsd: heading reset to the GNSS yaw (±{math.degrees(self.sigma_rad):.1f}°)")
        else:
            self.statustext(mavlink.MAV_SEVERITY_INFO,
                            f"ahrsd: heading aligned to the GNSS yaw (±{math.degrees(self.sigma_rad):.1f}°): "
                            "no trusted magnetometer calibration")

    def _announce_state_that_held(self, est, now: float) -> None:
        """A state (with its cause: why it is UNKNOWN, a circle found off-centre or corrected) is announced once it
        held ANNOUNCE_AFTER_S, the first one at once; a flicker back to the announced one is forgotten."""
        state = self.state
        key = (state, self._unknown_cause(est)[0] if state == HeadingState.UNKNOWN
               else "off-centre" if self._off_centre() else "corrected" if self._corrected()
               else "iron step" if self._iron_stepped() else "")
        if key == self.announced_key:
            self._candidate = None
            return
        if self._candidate is None or self._candidate[0] != key:
            self._candidate = (key, now)
        if self.announced is None or now - self._candidate[1] >= ANNOUNCE_AFTER_S:
            self._announce(key, est)

    # ------------------------------------------------------------------ outputs
    @property
    def heading_good(self) -> bool:
        """May the daemon say "heading good"? Never on a calibration the circle check finds wrong. A heading with
        1σ ≤ good_sigma_rad for ANNOUNCE_AFTER_S (a σ
        hovering at the limit, or swinging with each turn, does not flip MAV_STATE each second); a MAGNETOMETER
        heading at once unless its own σ was what made it not good; never UNKNOWN, never before the first
        estimate. Bad at once, good only once it held."""
        if not self._good_now():
            return False
        at_once = self.state == HeadingState.MAGNETOMETER and not self._wide_magnetometer
        return at_once or self._now - self._good_since >= ANNOUNCE_AFTER_S

    def _good_now(self) -> bool:
        if self.state is None or self.initialising or self.state == HeadingState.UNKNOWN or self._off_centre() \
                or self._iron_stepped():
            return False
        return self.sigma_rad <= self.good_sigma_rad

    def unhealthy_bits(self) -> int:
        """SYS_STATUS health bits to clear: 3D_MAG while the magnetometer is rejected or being learned (or
        disagrees with the GNSS yaw), or holds the heading alone on an untrusted calibration
        (`calibration_caveat`: an autopilot's own "compass not calibrated"), AHRS while the heading is not good."""
        bits = 0
        if self.state in (HeadingState.GNSS_ONLY, HeadingState.LEARNING) or self.mag_inconsistent \
                or self.calibration_caveat() is not None:
            bits |= msgs.SENSOR_MAG
        if self.state is not None and not self.heading_good:
            bits |= msgs.SENSOR_AHRS
        return bits

    def status_text(self) -> str:
        """For the status line: "hdg GNSS-only ±1.2°"; "hdg mag uncal ±6.1°" / "hdg unknown uncal ±180.0°" for a
        heading that rests on an untrusted calibration alone (`calibration_caveat`)."""
        if self.state is None:
            return "hdg --"
        label = STATE_LABELS[self.state] + (" uncal" if self.calibration_caveat() else "")
        if self._iron_stepped():
            label += f" iron step {math.degrees(self.mag_step_rad):+.0f}°"
        return f"{label} ±{math.degrees(self.sigma_rad):.1f}°"

    def calibration_caveat(self) -> str | None:
        """Why the heading is no better: a magnetometer heading with no GNSS fix to check it rests on the calibration
        alone, and the estimator's σ includes the calibration's predicted heading error (estimator/
        calibration_heading.py). With no calibration (or one of unknown quality) that error is unknown and the
        state UNKNOWN (ArduPilot refuses to arm then: "Compass not calibrated"); a calibration predicting more
        than 3° leaves a MAGNETOMETER heading with a σ that says so. A short phrase, or None when the calibration
        is trusted or GNSS checks the heading (ins learns the iron and its σ includes the calibration's)."""
        if self.state not in (HeadingState.MAGNETOMETER, HeadingState.UNKNOWN) or self.gnss_checked \
                or self.state is None or self.initialising:
            return None
        if self._off_centre():
            return f"mag field off-centre {self.field_off_centre_ut:.1f} µT"
        if self._corrected():
            return f"mag field corrected {self.field_corrected_ut:.1f} µT in turns"
        cal = self.calibration_sigma_rad
        if not math.isfinite(cal):
            return self._no_figure(short=True)
        if cal > TRUSTED_CALIBRATION_RAD:
            return f"mag cal ±{math.degrees(cal):.0f}°"
        return None

    def active_detail(self) -> str:
        """The MAV_STATE ACTIVE STATUSTEXT's detail: "heading good", or what the heading rests on when the
        calibration is untrusted (`calibration_caveat`)."""
        caveat = self.calibration_caveat()
        return "heading good" if caveat is None else f"heading: {caveat}"

    def standby_detail(self) -> str:
        """Why the daemon is not ACTIVE although the estimator runs (the MAV_STATE STATUSTEXT)."""
        if self.initialising and self.converging_on_calibration:
            # no σ figure: the estimate of that moment may still carry the old calibration's σ, not the new one's
            return "heading converging on the new calibration, no heading out"
        if self.initialising or self.state is None:
            return "initialising, no heading out"
        caveat = self.calibration_caveat()
        if self.state == HeadingState.UNKNOWN:
            return "heading unknown, no heading out" if caveat is None else f"heading unknown ({caveat}), no heading out"
        because = "" if caveat is None else f", {caveat}"
        return f"heading not good ({STATE_LABELS[self.state][4:]} ±{math.degrees(self.sigma_rad):.0f}°{because})"

    def rejection_cause(self, now: float, lever_arm_explains: bool = False) -> str | None:
        """When the aided filter rejects GNSS velocities: the heading as the cause (a short phrase for the
        STATUSTEXT: "mag vs GNSS 36°") when the iron stepped, the magnetometer disagrees with the GNSS yaw, the
        heading was just reset to it or is not known yet — the last three only while the lever-arm check
        (`lever_arm_explains`, estimator/lever_arm_fit.py) does not find a wrong arm — else None (then the lever
        arm or latency, as the GNSS task says). The rule is estimator/velocity_rejection_cause.py's, shared with
        `calibrate mag --gnss` and `replay --gnss`."""
        cause = heading_rejection_cause(iron_step_rad=self.mag_step_rad, mag_inconsistent=self.mag_inconsistent,
                                        disagreement_rad=self.disagreement_rad,
                                        since_yaw_reset_s=now - self._last_reset_at,
                                        heading_unknown=self.state == HeadingState.UNKNOWN and not self.initialising,
                                        lever_arm_explains=lever_arm_explains)
        return None if cause is None else cause.text

    # ------------------------------------------------------------------ internals
    def _off_centre(self) -> bool:
        """The circle check finds the calibration wrong (without GNSS: with it ins checks the heading itself)."""
        return math.isfinite(self.field_off_centre_ut) and not self.gnss_checked

    def _iron_stepped(self) -> bool:
        """The magnetometer is rejected now for a step of its heading the gyro did not see (an iron that changed)."""
        return math.isfinite(self.mag_step_rad)

    def _off_centre_cause(self) -> str:
        return wrong_calibration_text(self.field_off_centre_ut)

    def _corrected(self) -> bool:
        """The circle check finds the field consistent with a correction learned from the turns (without GNSS)."""
        return math.isfinite(self.field_corrected_ut) and not self.gnss_checked

    def _disagreement(self, integrity) -> tuple[float, bool]:
        """(magnetometer − GNSS yaw or NaN, whether it is beyond both uncertainties)."""
        if integrity is None or not integrity.gsf_valid:
            return math.nan, False
        d = float(integrity.mag_disagreement_rad)
        if not math.isfinite(d):
            return math.nan, False
        cal = self.calibration_sigma_rad if math.isfinite(self.calibration_sigma_rad) else UNCALIBRATED_SIGMA_RAD
        gsf = float(integrity.gsf_sigma_rad) if math.isfinite(integrity.gsf_sigma_rad) else math.pi
        return d, d * d > DISAGREEMENT_GATE_SIGMA ** 2 * (gsf * gsf + cal * cal)

    def _unknown_cause(self, est) -> tuple[str, str]:
        """Why the heading is UNKNOWN: (a stable key, the phrase for the STATUSTEXT)."""
        sig = f"±{math.degrees(self.sigma_rad):.1f}°"
        integrity = est.integrity
        caveat = self.calibration_caveat()
        if integrity is not None and integrity.lever_arm_wrong:
            # before a magnetometer disagreeing with the GNSS yaw: a wrong arm bends that yaw too
            return "lever arm", ("the GNSS velocities fit another antenna place than [gnss] lever_arm_m; measure it "
                                 "and set it")
        if self.mag_inconsistent:
            return "disagrees", ""
        if self._off_centre() and not self.initialising:
            return "off-centre", self._off_centre_cause()
        if self.initialising and self.converging_on_calibration:
            return "converging", "converging on the new calibration"
        if self.initialising and self.announced in (None, HeadingState.UNKNOWN):
            return "initialising", "initialising"
        if self.initialising:
            return "sigma", f"uncertainty {sig} too large (magnetometer rejected?)"
        if est.flags & EstimateFlags.MAG_UNAVAILABLE:
            if caveat is not None and not self.calibration_in_force and not math.isfinite(self.calibration_sigma_rad):
                # the estimator's norm/dip check rejects an uncalibrated field whose iron makes it disagree with
                # the Earth's: the magnetometer is there, its calibration is what is missing
                return "no mag uncal", ("magnetometer not calibrated, its field rejected against the Earth's, and "
                                        "no GNSS yaw; calibrate it (magcal)")
            return "no mag", "no magnetometer and no GNSS yaw"
        if caveat is not None:
            return "uncal", (f"{self._no_figure(short=False) if not math.isfinite(self.calibration_sigma_rad) else caveat} and no "
                             "GNSS fix to check it, the vehicle's iron may turn it by any angle; calibrate it "
                             "(magcal)")
        if integrity is None:
            return "no gnss", "magnetometer not trusted, no GNSS yet"
        if not integrity.gsf_valid:
            return "gsf", "magnetometer not trusted, GNSS yaw not valid yet (turn or change speed)"
        return "sigma", f"uncertainty {sig} too large"

    def _announce(self, key: tuple, est) -> None:
        state = key[0]
        self.announced, self.announced_key = state, key
        self._candidate = None
        self.announcements += 1
        severity, text = self._text(state, est)
        self.statustext(severity, text)

    def _text(self, state: HeadingState, est) -> tuple[int, str]:
        """The announcement of `state`: (severity, text)."""
        if state == HeadingState.MAGNETOMETER:
            return self._magnetometer_text()
        cause = self._magnetometer_cause()
        if state == HeadingState.UNKNOWN:
            key, unknown_why = self._unknown_cause(est)
            why = unknown_why if key == "lever arm" or not self.mag_inconsistent else cause
            return mavlink.MAV_SEVERITY_WARNING, f"ahrsd: heading unknown: {why}; no heading sent"
        doing = ("heading GNSS-held while the iron is relearned" if self._iron_stepped()
                 else "learning its iron" if state == HeadingState.LEARNING else "heading from GNSS only")
        good = "" if self.heading_good else ", not good yet"
        return mavlink.MAV_SEVERITY_WARNING, f"ahrsd: {cause}; {doing} (±{math.degrees(self.sigma_rad):.1f}°{good})"

    def _magnetometer_text(self) -> tuple[int, str]:
        """A magnetometer heading: plain (INFO) on a trusted calibration, else a WARNING naming what it rests on."""
        sig = f"±{math.degrees(self.sigma_rad):.1f}°"
        caveat = self.calibration_caveat()
        if self._off_centre():
            return mavlink.MAV_SEVERITY_WARNING, (f"ahrsd: {self._off_centre_cause()}; heading from magnetometer "
                                                  f"({sig}), no GNSS fix to check it")
        if self._corrected():
            return mavlink.MAV_SEVERITY_WARNING, (
                f"ahrsd: {wrong_calibration_text(self.field_corrected_ut, corrected=True)}; heading from "
                f"magnetometer ({sig}), no GNSS fix to check it")
        if caveat is None:
            wide = ", not good" if not self.sigma_rad <= self.good_sigma_rad else ""
            return mavlink.MAV_SEVERITY_INFO, f"ahrsd: heading from magnetometer ({sig}{wide})"
        if not math.isfinite(self.calibration_sigma_rad):     # an estimator whose σ cannot carry it
            return mavlink.MAV_SEVERITY_WARNING, (
                f"ahrsd: heading from magnetometer ({sig}), {self._no_figure(short=True)} and no GNSS fix to check it: the "
                "vehicle's iron may turn it by any angle; calibrate it (magcal)")
        return mavlink.MAV_SEVERITY_WARNING, (
            f"ahrsd: heading from magnetometer ({sig}, of it {caveat}), no GNSS fix to check it; a better "
            "calibration gives a better heading (magcal)")

    def _magnetometer_cause(self) -> str:
        """Why the magnetometer does not hold the heading alone: its heading stepped while the gyro saw no turn
        (the iron changed), it disagrees with GNSS (by how much, and whether
        for want of a calibration), it has no calibration (or one stating no figure), or its calibration is
        uncertain."""
        if self._iron_stepped():
            # "ahrsd: iron changed: mag heading stepped +180°" is 49 ASCII characters: one STATUSTEXT's worth
            return f"iron changed: mag heading stepped {math.degrees(self.mag_step_rad):+.0f}°, the gyro saw no turn"
        d = self.disagreement_rad
        by = f" by {abs(math.degrees(d)):.0f}°" if math.isfinite(d) else ""
        if not math.isfinite(self.calibration_sigma_rad):
            return f"magnetometer disagrees with GNSS{by}: {self._no_figure(short=False)}" if self.mag_inconsistent \
                else self._no_figure(short=False)
        if self.mag_inconsistent:
            return f"magnetometer disagrees with GNSS{by}: calibration wrong or iron changed"
        return f"magnetometer calibration uncertain (±{math.degrees(self.calibration_sigma_rad):.1f}°)"
