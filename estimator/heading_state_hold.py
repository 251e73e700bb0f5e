"""The published heading state's hysteresis: worse at once, better only once it has clearly held.

The raw heading state (ins: HeadingMonitor.heading_state and the published σ against
`heading_unknown_sigma_rad`) follows quantities that hover at their thresholds while the heading converges: the
yaw σ of a GNSS-held heading sits at 14–15° against the 15° limit for tens of seconds, the learning flag turns with
each fix. Published as it is, the state (and with it the daemon's STATUSTEXT, its VISION_POSITION_ESTIMATE and
the replay summary) flips many times a minute. A product enters a state when its condition holds and leaves it
when it fails: ArduPilot EKF3 aligns to its GSF yaw only after 5 consecutive valid fixes
(GSF_YAW_VALID_HISTORY_THRESHOLD) and lets the compass back after 50 agreeing samples in a row
(learnMagBiasFromGPS); PX4 EKF2 starts magnetometer fusion only after its field checks have passed for a
minimum time (../shared/anchors/heading-integrity.md).

Honesty first, so the hysteresis only ever delays a *better* state, never a worse one:
* a worse state (UNKNOWN < GNSS_ONLY = LEARNING < MAGNETOMETER) is published at the sample it is seen;
* a better or an equally good other state is published only after it has held `hold_s` without a break;
* UNKNOWN is left only when the yaw σ is at most `enter_sigma_rad` (below the `heading_unknown_sigma_rad` that
  makes it UNKNOWN), so a σ hovering at the limit does not re-enter it each time it dips.

ins updates it at each heading check (the GNSS rate), not when an estimate is built, so the state does not depend
on how often estimates are built; between checks a σ beyond `heading_unknown_sigma_rad` still makes the published
state UNKNOWN at once (heading_publication.HeadingPublication.published).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ahrsd.core.estimate import HeadingState

RANK = {HeadingState.UNKNOWN: 0, HeadingState.GNSS_ONLY: 1, HeadingState.LEARNING: 1,
        HeadingState.MAGNETOMETER: 2}
"""How much each state claims about the heading (GNSS_ONLY and LEARNING: both GNSS-held)."""


@dataclass
class HeadingStateHold:
    """`update(t_s, raw_state, yaw_sigma_rad)` → the state to publish (times non-decreasing)."""

    hold_s: float
    enter_sigma_rad: float
    published: HeadingState = HeadingState.UNKNOWN
    candidate: HeadingState | None = None       # a better (or equally good other) state waiting to be published
    candidate_since_s: float = math.nan

    def reset(self) -> None:
        self.published = HeadingState.UNKNOWN
        self.candidate = None
        self.candidate_since_s = math.nan

    def update(self, t_s: float, raw: HeadingState, yaw_sigma_rad: float) -> HeadingState:
        if raw != HeadingState.UNKNOWN and self.published == HeadingState.UNKNOWN \
                and not yaw_sigma_rad <= self.enter_sigma_rad:
            raw = HeadingState.UNKNOWN           # not clearly known yet
        if RANK[raw] < RANK[self.published]:
            self.published = raw                 # worse: at once
            self.candidate = None
        elif raw == self.published:
            self.candidate = None
        else:
            if raw != self.candidate:
                self.candidate, self.candidate_since_s = raw, t_s
            if t_s - self.candidate_since_s >= self.hold_s:
                self.published = raw
                self.candidate = None
        return self.published
