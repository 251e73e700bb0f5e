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
        # who takes each message type (a handler (endpoint, msg, now) per type)
        self._routes: dict[str, Callable[[Endpoint, object, float], None]] = {
            "HEARTBEAT": self._on_heartbeat, "PARAM_VALUE": self._on_param_value,
            "GLOBAL_POSITION_INT": self._on_position, "GPS_RAW_INT": self._on_position,
            "TIMESYNC": self._on_timesync, "COMMAND_ACK": self._on_command_ack,
            "COMMAND_LONG": self._on_command, "COMMAND_INT": self._on_command,
            "FILE_TRANSFER_PROTOCOL": self._on_ftp,
            "PARAM_REQUEST_LIST": self._on_param_request, "PARAM_REQUEST_READ": self._on_param_request,
            "PARAM_SET": self._on_param_request,
        }

    def on_message(self, endpoint: Endpoint, msg) -> None:
        """Route one message by its type (`_routes`); our own traffic echoed back by a router or a broadcast
        link is dropped, a type no part takes is ignored."""
        identity = self.outbound.identity
        if msg.get_srcSystem() == identity.system_id and msg.get_srcComponent() == identity.component_id:
            return
        now = self.clock()
        route = self._routes.get(msg.get_type())
        if route is not None:
            route(endpoint, msg, now)

    def _on_heartbeat(self, endpoint: Endpoint, msg, now: float) -> None:
        """The autopilot found (and its system id adopted, when following it); ArduPilot's heartbeat starts the
        source-set check's EK3_SRC reads."""
        identity, autopilot = self.outbound.identity, self.autopilot
        src_sys = msg.get_srcSystem()
        if AutopilotState.is_autopilot_heartbeat(msg) and autopilot.on_heartbeat(msg, now):
            log.info("autopilot found: system %d component %d", src_sys, msg.get_srcComponent())
            if self.follow_autopilot_id and src_sys != identity.system_id:
                self.outbound.set_system_id(src_sys)
        if (self.source_set_check is not None and autopilot.from_this_autopilot(msg)
                and msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
            self.source_set_check.on_autopilot_heartbeat()     # reads its EK3_SRC parameters

    def _on_param_value(self, endpoint: Endpoint, msg, now: float) -> None:
        if self.source_set_check is not None and self.autopilot.from_this_autopilot(msg):
            self.source_set_check.on_param_value(msg)

    def _on_position(self, endpoint: Endpoint, msg, now: float) -> None:
        """GLOBAL_POSITION_INT / GPS_RAW_INT of our autopilot (any before one is found): to its state, to a
        MAVLink GNSS source, and to the declination while it waits for a position."""
        autopilot = self.autopilot
        if autopilot.system_id is not None and msg.get_srcSystem() != autopilot.system_id:
            return
        if msg.get_type() == "GLOBAL_POSITION_INT":
            autopilot.on_global_position_int(msg, now)
        else:
            autopilot.on_gps_raw_int(msg, now)
        if self.gnss is not None:
            self.gnss.on_mavlink(msg, now)
        if self.declination.waiting_for_position:
            self.declination.resolve()

    def _on_timesync(self, endpoint: Endpoint, msg, now: float) -> None:
        if msg.tc1 == 0:   # a request; answers have tc1 != 0 (MAVLink TIMESYNC v2)
            self.timesync.on_request(endpoint, msg, now)

    def _on_command_ack(self, endpoint: Endpoint, msg, now: float) -> None:
        if self.restart_heading is not None and self.autopilot.from_this_autopilot(msg):
            self.restart_heading.on_command_ack(msg)

    def _on_command(self, endpoint: Endpoint, msg, now: float) -> None:
        identity = self.outbound.identity
        ours, broadcast = is_for_us(msg, identity.system_id, identity.component_id)
        if ours:
            self.commands.handle(msg, endpoint, broadcast)

    def _on_ftp(self, endpoint: Endpoint, msg, now: float) -> None:
        identity = self.outbound.identity
        reply = ftp_nak(msg, identity.system_id, identity.component_id)
        if reply is not None:
            endpoint.send(reply)

    def _on_param_request(self, endpoint: Endpoint, msg, now: float) -> None:
        identity = self.outbound.identity
        ours, broadcast = is_for_us(msg, identity.system_id, identity.component_id)
        if ours:
            self.params.on_message(endpoint, msg, msg.get_type(), broadcast)
