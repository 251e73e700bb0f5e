"""The MAVLink parameter protocol: the stable parameter set (one SR_ rate per output of the registry, the
mounting, the declination), PARAM_REQUEST_LIST/READ and PARAM_SET (signed when signing is required; always
answered with the value in force). What a change does is wired in daemon.service (`on_change`)."""

from __future__ import annotations

import asyncio
import logging
from typing import Callable, Coroutine

from ahrsd.daemon.learned_iron import ACTION_PARAM as LEARNED_IRON_ACTION
from ahrsd.daemon.learned_iron import MAX_PARAM_SOFT, MAX_PARAM_UT, NOT_LEARNING_SD, PARAM_NAMES as LEARNED_IRON_PARAMS
from ahrsd.daemon.learned_iron import SOFT_PARAM_NAMES as LEARNED_SOFT_PARAMS, SOFT_SD_PARAM as LEARNED_SOFT_SD
from ahrsd.daemon.learned_iron import SOURCE_CODES as LEARNED_IRON_SOURCES, SOURCE_PARAM as LEARNED_IRON_SOURCE
from ahrsd.daemon import messages as msgs
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.mavlink_io import Endpoint, mavlink
from ahrsd.daemon.output_registry import OUTPUTS
from ahrsd.daemon.params import ParamSpec, ParamStore, decode_param_id, printable_param_id

log = logging.getLogger(__name__)

PARAM_STREAM_PAUSE_S = 0.002                     # pause between PARAM_VALUEs of a list
PARAM_INDEX_BY_NAME = -1                          # PARAM_REQUEST_READ.param_index: "use param_id"
# PARAM_SET.param_type: any MAV_PARAM_TYPE is taken as a C-cast float (PARAM_ENCODE_C_CAST); others are refused
PARAM_TYPES = frozenset(mavlink.enums["MAV_PARAM_TYPE"]) - {max(mavlink.enums["MAV_PARAM_TYPE"])}
MOUNTING_PARAMS = ("MNT_ROLL_DEG", "MNT_PITCH_DEG", "MNT_YAW_DEG")


def param_specs(cfg) -> list[ParamSpec]:
    """The stable parameter set (names, order and ranges never change while running)."""
    out = []
    for o in OUTPUTS:
        out.append(ParamSpec(o.param_name, getattr(cfg.outputs, o.config_key), 0.0, o.max_rate_hz,
                             f"{o.config_key[:-3]} rate, Hz (0 = off)"))
    r, p, y = cfg.sensor.mounting_rpy_deg
    out += [
        ParamSpec("MNT_ROLL_DEG", r, -180.0, 180.0, "sensor mounting roll in the body frame, deg"),
        ParamSpec("MNT_PITCH_DEG", p, -90.0, 90.0, "sensor mounting pitch in the body frame, deg"),
        ParamSpec("MNT_YAW_DEG", y, -180.0, 180.0, "sensor mounting yaw in the body frame, deg"),
        ParamSpec("DECL_MANUAL", 1.0 if cfg.location.declination_deg is not None else 0.0, 0.0, 1.0,
                  "1 = use DECL_DEG, 0 = WMM at the configured or autopilot position", integer=True),
        ParamSpec("DECL_DEG", cfg.location.declination_deg or 0.0, -180.0, 180.0,
                  "magnetic declination, deg east (used when DECL_MANUAL = 1)"),
    ]
    # the iron the aided estimator learned on top of the calibration (daemon.learned_iron), read-only
    out += [ParamSpec(n, 0.0, -MAX_PARAM_UT, MAX_PARAM_UT, f"learned hard iron, body {n[-1]}, uT (read-only)",
                      read_only=True) for n in LEARNED_IRON_PARAMS[:3]]
    out.append(ParamSpec(LEARNED_IRON_PARAMS[3], NOT_LEARNING_SD, NOT_LEARNING_SD, MAX_PARAM_UT,
                         "largest 1-sigma of the learned hard iron, uT (-1: the estimator learns none; read-only)",
                         read_only=True))
    out.append(ParamSpec(LEARNED_IRON_SOURCE, 0.0, 0.0, float(max(LEARNED_IRON_SOURCES.values())),
                         "what learned the iron: 0 nothing yet, " + ", ".join(
                             f"{code} {name}" for name, code in LEARNED_IRON_SOURCES.items()) + " (read-only)",
                         integer=True, read_only=True))
    out += [ParamSpec(n, 1.0 if n[-1] == n[-2] else 0.0, -MAX_PARAM_SOFT, MAX_PARAM_SOFT,
                      f"learned soft iron I + D, row {n[-2]} column {n[-1]}, body FRD (read-only)", read_only=True)
            for n in LEARNED_SOFT_PARAMS]
    out.append(ParamSpec(LEARNED_SOFT_SD, NOT_LEARNING_SD, NOT_LEARNING_SD, MAX_PARAM_SOFT,
                         "largest 1-sigma of an element of the learned soft iron D (-1: none learned; read-only)",
                         read_only=True))
    out.append(ParamSpec(LEARNED_IRON_ACTION, 0.0, 0.0, 2.0, "write 1 to accept the learned iron into the "
                         "calibration, 2 to reset it (momentary; refused while armed)", integer=True, momentary=True))
    return out



class ParamProtocol:
    """PARAM_REQUEST_LIST/READ and PARAM_SET on the daemon's ParamStore. What a change does is the store's
    `on_change` (wired by daemon.service); `signing_required()` says whether an unsigned PARAM_SET is refused;
    `spawn(coro)` runs the list stream as a task on the event loop."""

    def __init__(self, params: ParamStore, outbound: Outbound, counters: ServiceCounters, *,
                 signing_required: Callable[[], bool], spawn: Callable[[Coroutine], object]):
        self.params = params
        self.outbound = outbound
        self.counters = counters
        self.signing_required = signing_required
        self.spawn = spawn

    def _param_value(self, index: int):
        name, value = self.params.item(index)
        return msgs.param_value(name, value, index, len(self.params))

    async def _stream_params(self, endpoint: Endpoint) -> None:
        for i in range(len(self.params)):
            endpoint.send(self._param_value(i))
            await asyncio.sleep(PARAM_STREAM_PAUSE_S)

    def on_message(self, endpoint: Endpoint, msg, mtype: str, broadcast: bool) -> None:
        if mtype == "PARAM_REQUEST_LIST":
            self.spawn(self._stream_params(endpoint))
            return
        name = decode_param_id(msg.param_id)
        shown = printable_param_id(name)
        if mtype == "PARAM_REQUEST_READ":
            if msg.param_index == PARAM_INDEX_BY_NAME:
                index = self.params.index_of(name)
            else:
                index = msg.param_index if 0 <= msg.param_index < len(self.params) else None
                shown = f"index {msg.param_index}"
            if index is None:
                if not broadcast:      # (a broadcast read is for whoever has it: not ours to refuse)
                    self.params.rejected_reads += 1
                    self.outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter {shown}")
                return
            endpoint.send(self._param_value(index))
            return
        # PARAM_SET
        index = self.params.index_of(name)
        if index is None:
            if not broadcast:
                self.params.rejected_writes += 1
                self.outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unknown parameter {shown}")
            return
        # every refusal below: counted, one STATUSTEXT (rate limited by statustext, which also logs it)
        if self.signing_required() and not msg.get_signed():
            self.counters.unsigned_refused += 1
            self.outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: unsigned write of {name} refused")
        elif msg.param_type not in PARAM_TYPES:
            self.params.rejected_writes += 1
            self.outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: {name}: param_type {msg.param_type} unknown")
        else:
            ok, reason = self.params.set(name, msg.param_value)
            if not ok:
                self.outbound.statustext(mavlink.MAV_SEVERITY_WARNING, f"ahrsd: {reason}")
            elif self.params.specs[index].momentary:
                # an action done: answered with the value written, as ground stations check a write by its answer
                # (MAVProxy re-sends a write answered otherwise, repeating the action); it reads 0 again after
                self.outbound.send(msgs.param_value(name, float(msg.param_value), index, len(self.params)))
                return
        self.outbound.send(self._param_value(index))   # always answered, with the value in force

