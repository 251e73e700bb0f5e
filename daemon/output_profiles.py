"""Which outputs each endpoint gets: a profile (the message set) plus per-endpoint rate overrides.

* `gcs` (the default): every output of daemon.output_registry at the daemon-wide rate (`[outputs]`, `SR_*`).
* `autopilot`: only what an autopilot uses — VISION_POSITION_ESTIMATE (the heading ArduPilot's EKF3 and
  PX4's EKF2 fuse) and SYS_STATUS, at the daemon-wide rates. HEARTBEAT (always 1 Hz) and the event messages
  (STATUSTEXT, COMMAND_ACK, PARAM_VALUE, TIMESYNC answers, and MAG_CAL_PROGRESS / MAG_CAL_REPORT while a
  mag-cal session runs) go to every endpoint whatever its profile: they are answers and session traffic, not
  streams, so a ground station talking to us through the autopilot still gets them.

An endpoint's rate for an output is its override (`[[endpoint]] outputs = {key = Hz}`) if given, else the
daemon-wide rate if the profile includes the output, else 0 (off). SET_MESSAGE_INTERVAL from a peer changes
the schedule of the endpoint it came in on only.
"""

from __future__ import annotations

from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.output_registry import OUTPUTS

AUTOPILOT_OUTPUTS = frozenset({mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE, mavlink.MAVLINK_MSG_ID_SYS_STATUS})

# profile name -> the message ids it follows at the daemon-wide rate (None = every output of the registry)
PROFILES: dict[str, frozenset[int] | None] = {"gcs": None, "autopilot": AUTOPILOT_OUTPUTS}
DEFAULT_PROFILE = "gcs"


def profile_includes(profile: str, message_id: int) -> bool:
    ids = PROFILES[profile]
    return ids is None or message_id in ids


def endpoint_rates_hz(profile: str, overrides_hz: dict[int, float], base_rates_hz: dict[int, float]) -> dict[int, float]:
    """The rate of every output on one endpoint (message id -> Hz), in registry order."""
    out = {}
    for o in OUTPUTS:
        mid = o.message_id
        if mid in overrides_hz:
            out[mid] = overrides_hz[mid]
        elif profile_includes(profile, mid):
            out[mid] = base_rates_hz.get(mid, 0.0)
        else:
            out[mid] = 0.0
    return out


def follows_base_rate(profile: str, overrides_hz: dict[int, float], message_id: int) -> bool:
    """Does this endpoint's rate for `message_id` follow the daemon-wide rate (`SR_*`)?"""
    return message_id not in overrides_hz and profile_includes(profile, message_id)
