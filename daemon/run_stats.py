"""`ahrsd run --stats-file FILE`: every counter of a run as JSON, written when the daemon stops.

For the soak benchmark and the reliability tests (and for a user who wants the figures of a field run): what
was processed, lost, rejected and refused, per layer — simulated chip (ground truth of produced/lost samples
and injected faults), driver, reader, pipeline, MAVLink links, command router and parameters.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from pathlib import Path

from ahrsd.calibration.atomic_file import write_atomic
from ahrsd.daemon.mavlink_io import mavlink

log = logging.getLogger(__name__)


def sample_accounting(service) -> dict:
    """Samples delivered, and the three ways a sample fails to be: `missed` (the chip produced it and it never
    reached the estimator: not read in time, dropped in a hand-over or a kernel buffer — the index gaps the
    source flagged), `late` (used more than daemon.sample_reader.LATE_AFTER_S after it became ready) and
    `corrupt` (frames the driver rejected: garbage, short reads)."""
    src = service.source
    c = src.counters() if src is not None else {}
    pc = service.pipeline.counters if service.pipeline is not None else None
    return {"delivered": pc.samples if pc else 0, "missed": pc.lost_samples if pc else 0,
            "late": service.counters.late_samples,
            "corrupt": int(c.get("garbage_frames", 0)) + int(c.get("short_reads", 0))}


def schedule_accounting(schedule) -> dict:
    """Beside what a link sent: per message, the deadlines its schedule skipped after long stalls (daemon.outputs)
    and the latest restarts as [message, first skipped deadline on CLOCK_MONOTONIC s, period s, count]; the
    deadlines served that sent nothing, withheld (nothing trustworthy: VISION_POSITION_ESTIMATE while the heading
    is not trusted) or unchanged (no new estimate for a once-per-estimate output), and the latest runs of them as
    [message, reason, first on CLOCK_MONOTONIC s, last s, count]."""
    if schedule is None:
        return {}
    name = lambda mid: mavlink.mavlink_map[mid].msgname   # noqa: E731
    return {"dropped_slots": {name(mid): n for mid, n in schedule.dropped_slots().items()},
            "skips": [[name(k.message_id), k.first_due_s, k.period_s, k.count] for k in schedule.skips],
            "withheld_slots": {name(mid): n for mid, n in schedule.withheld_slots().items()},
            "unchanged_slots": {name(mid): n for mid, n in schedule.unchanged_slots().items()},
            "held_runs": [[name(h.message_id), h.reason, h.first_s, h.last_s, h.count] for h in schedule.held_runs]}


def collect_stats(service) -> dict:
    """A JSON-ready snapshot of the service's counters."""
    out: dict = {"exit_code": service.exit_code, "reset_counter": service.reset_counter}
    out["service"] = dataclasses.asdict(service.counters)
    if service.pipeline is not None:
        out["pipeline"] = dataclasses.asdict(service.pipeline.counters)
    out["samples"] = sample_accounting(service)
    src = service.source
    if src is not None:
        out["source"] = {k: v for k, v in src.counters().items() if isinstance(v, (int, float))}
    chip = src.chip if src is not None else None
    if chip is not None:
        out["chip"] = dict(chip.stats)
        out["chip"]["sample_index"] = chip.sample_index
        out["faults_injected"] = dict(chip.faults.injected)
    out["links"] = {ep.url: dataclasses.asdict(ep.counters) | schedule_accounting(ep.schedule)
                    for ep in service.endpoints}
    out["commands"] = dataclasses.asdict(service.commands.counters)
    out["params"] = {"rejected_writes": service.params.rejected_writes, "rejected_reads": service.params.rejected_reads}
    out["logs"] = service.logs.counters()
    out["autopilot"] = {"rejected_positions": service.autopilot.rejected_positions,
                        "rejected_courses": service.autopilot.rejected_courses}
    if service.positions.memory is not None:
        out["position_memory"] = service.positions.memory.counters()
    if service.gnss is not None:
        out["gnss"] = service.gnss.stats()
    return out


def write_stats(service, path: str | os.PathLike) -> None:
    """Write the snapshot atomically (temp file + rename); errors are logged, never raised."""
    path = Path(path)
    try:
        data = json.dumps(collect_stats(service), indent=1, sort_keys=True, default=str)
        write_atomic(path, data.encode(), mode=0o644)
    except (OSError, TypeError, ValueError) as exc:
        log.warning("cannot write the stats file %s: %s", path, exc)
