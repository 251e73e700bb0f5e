"""The compact live status line `ahrsd run` prints when stdout is a terminal."""

from __future__ import annotations

import math

from ahrsd.daemon.health import STATE_NAMES


def format_status(*, estimate, rate_hz: float | None, state: int, samples: dict, link: dict,
                  gnss: str | None, autopilot, heading: str | None = None) -> str:
    """One line: sample rate, attitude, true heading, state, and the counters a user should watch. `samples`
    is daemon.run_stats.sample_accounting (missed, late, corrupt), `gnss` the GNSS task's status (None without
    one), `autopilot` the daemon.autopilot.AutopilotState, `heading` the heading state (daemon.heading_status)."""
    est = estimate
    parts = [f"{rate_hz:6.1f} SPS" if rate_hz is not None else f"{'--':>6} SPS"]   # None: not measured yet
    if est is None:
        parts.append("attitude --")
    else:
        parts.append(f"roll {math.degrees(est.roll_rad):+6.1f} pitch {math.degrees(est.pitch_rad):+6.1f}")
        parts.append(f"hdg {math.degrees(est.heading_true_rad) % 360.0:5.1f}T "
                     f"±{math.degrees(float(est.sigma_rpy_rad[2])):4.1f}")
    parts.append(STATE_NAMES.get(state, "?"))
    if heading is not None:
        parts.append(heading)          # the heading state (daemon.heading_status): "hdg GNSS-only ±1.2°"
    parts.append(f"missed {samples['missed']} late {samples['late']} corrupt {samples['corrupt']} "
                 f"tx {link['tx']} rx {link['rx']} bad {link['bad']}")
    if gnss is not None:
        parts.append(gnss)
    if autopilot.system_id is not None:
        parts.append(f"AP {autopilot.system_id}{' ARMED' if autopilot.armed else ''}")
    return " | ".join(parts)


class StatusLine:
    def __init__(self, stream):
        self.stream = stream
        self.shown = False

    def install_log_filter(self) -> None:
        """Clear the status line before any log record is written, so log lines never land on it."""
        import logging

        line = self

        class _ClearFirst(logging.Filter):
            def filter(self, record):
                line.clear()
                return True

        for handler in logging.getLogger().handlers:
            handler.addFilter(_ClearFirst())

    def update(self, text: str) -> None:
        self.stream.write("\r" + text + "\x1b[K")
        self.stream.flush()
        self.shown = True

    def clear(self) -> None:
        if self.shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self.shown = False
