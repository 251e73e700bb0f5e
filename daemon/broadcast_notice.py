"""Say why a command broadcast to every component (target_component 0) was not acted on, when a handler for it
exists but is not allowed to act on broadcasts (MAVProxy's `magcal start` goes to component 0, which would start
the autopilot's own calibration too: docs/magcal-field.md). Logged once per sender and command, with a
STATUSTEXT the ground station shows, so the operator learns what to change instead of seeing nothing."""

from __future__ import annotations

import logging

from ahrsd.daemon.mavlink_io import mavlink

log = logging.getLogger(__name__)


def command_name(command_id: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command_id)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else str(command_id)


class BroadcastNotice:
    """`note(command_id, source)`: one log line and one STATUSTEXT per (source, command)."""

    def __init__(self, statustext, component_id: int):
        self._statustext = statustext          # (severity, text) -> None
        self._component_id = component_id
        self._told: set[tuple[tuple[int, int], int]] = set()

    def note(self, command_id: int, source: tuple[int, int]) -> None:
        key = (source, int(command_id))
        if key in self._told:
            return
        self._told.add(key)
        name = command_name(command_id)
        log.warning("ignored %s broadcast to component 0 by %d/%d: send it to component %d, or allow broadcasts "
                    "([magcal] accept_broadcast = true)", name, source[0], source[1], self._component_id)
        self._statustext(mavlink.MAV_SEVERITY_WARNING,
                         f"ahrsd: {name} ignored: send to comp {self._component_id}")
