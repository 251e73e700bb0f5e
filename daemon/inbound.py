"""Inbound MAVLink: every message from every endpoint goes through `InboundDispatch.on_message`, which routes it
(autopilot heartbeat and position, TIMESYNC, commands, parameters) after dropping our own echoed traffic.

Who receives what is declared in the constructor: the parts it routes to are arguments, the optional ones
(the GNSS task, the ArduPilot source-set check, the restart rule) `None` when not configured."""

from __future__ import annotations

import logging
import time
from typing import Callable, Protocol

from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.commands import CommandRouter
from ahrsd.daemon.declination import Declination
from ahrsd.daemon.ftp_nak import ftp_nak
from ahrsd.daemon.mavlink_io import Endpoint, is_for_us, mavlink
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.param_protocol import ParamProtocol
from ahrsd.daemon.restart_heading import RestartHeading
from ahrsd.daemon.source_set_check import SourceSetCheck
from ahrsd.daemon.timesync_answers import TimesyncAnswers

log = logging.getLogger(__name__)


class AutopilotGnssInput(Protocol):
    """The GNSS task's MAVLink input (daemon.gnss_task with `[gnss] source = "mavlink"`)."""

    def on_mavlink(self, msg, now: float) -> None: ...


class InboundDispatch:
    """`on_message(endpoint, msg)`, the callback of every Endpoint. `follow_autopilot_id`: adopt the autopilot's
    system id (no `[mavlink] system_id` configured)."""

    def __init__(self, outbound: Outbound, autopilot: AutopilotState, commands: CommandRouter,
                 params: ParamProtocol, declination: Declination, *, follow_autopilot_id: bool,
                 gnss: AutopilotGnssInput | None = None, source_set_check: SourceSetCheck | None = None,
                 restart_heading: RestartHeading | None = None, clock: Callable[[], float] = time.monotonic):
        self.outbound = outbound
        self.autopilot = autopilot
        self.commands = commands
        self.params = params
        self.declination = declination
        self.follow_autopilot_id = follow_autopilot_id
        self.gnss = gnss
        self.source_set_check = source_set_check
        self.restart_heading = restart_heading
        self.clock = clock
        self.timesync = TimesyncAnswers(outbound.counters)   # answers TIMESYNC requests, rate limited per sender

    def on_message(self, endpoint: Endpoint, msg) -> None:
        identity = self.outbound.identity
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if src_sys == identity.system_id and src_comp == identity.component_id:
            return   # our own traffic echoed back by a router or a broadcast link
        mtype = msg.get_type()
        now = self.clock()
        autopilot = self.autopilot
        if mtype == "HEARTBEAT":
            if AutopilotState.is_autopilot_heartbeat(msg) and autopilot.on_heartbeat(msg, now):
                log.info("autopilot found: system %d component %d", src_sys, src_comp)
                if self.follow_autopilot_id and src_sys != identity.system_id:
                    self.outbound.set_system_id(src_sys)
            if (self.source_set_check is not None and autopilot.from_this_autopilot(msg)
                    and msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
                self.source_set_check.on_autopilot_heartbeat()     # reads its EK3_SRC parameters
            return
        if mtype == "PARAM_VALUE":
            if self.source_set_check is not None and autopilot.from_this_autopilot(msg):
                self.source_set_check.on_param_value(msg)
            return
        if mtype in ("GLOBAL_POSITION_INT", "GPS_RAW_INT"):
            if autopilot.system_id is None or src_sys == autopilot.system_id:
                if mtype == "GLOBAL_POSITION_INT":
                    autopilot.on_global_position_int(msg, now)
                else:
                    autopilot.on_gps_raw_int(msg, now)
                if self.gnss is not None:
                    self.gnss.on_mavlink(msg, now)
                if self.declination.waiting_for_position:
                    self.declination.resolve()
            return
        if mtype == "TIMESYNC":
            if msg.tc1 == 0:   # a request; answers have tc1 != 0 (MAVLink TIMESYNC v2)
                self.timesync.on_request(endpoint, msg, now)
            return
        if mtype == "COMMAND_ACK":
            if self.restart_heading is not None and autopilot.from_this_autopilot(msg):
                self.restart_heading.on_command_ack(msg)
            return
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            ours, broadcast = is_for_us(msg, identity.system_id, identity.component_id)
            if ours:
                self.commands.handle(msg, endpoint, broadcast)
            return
        if mtype == "FILE_TRANSFER_PROTOCOL":
            reply = ftp_nak(msg, identity.system_id, identity.component_id)
            if reply is not None:
                endpoint.send(reply)
            return
        if mtype in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            ours, broadcast = is_for_us(msg, identity.system_id, identity.component_id)
            if ours:
                self.params.on_message(endpoint, msg, mtype, broadcast)
