"""Inbound MAVLink: every message from every endpoint goes through `_on_message`, which routes it (autopilot
heartbeat and position, TIMESYNC, commands, parameters) after dropping our own echoed traffic."""

from __future__ import annotations

import logging
import time

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.ftp_nak import ftp_nak
from ahrsd.daemon.mavlink_io import Endpoint, is_for_us, mavlink

log = logging.getLogger(__name__)


class InboundDispatch:
    """Service part: `_on_message`, the callback of every Endpoint."""

    def _send_on(self, endpoint: Endpoint, msg) -> None:
        endpoint.send(msg)

    def _on_message(self, endpoint: Endpoint, msg) -> None:
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if src_sys == self.system_id and src_comp == self.component_id:
            return   # our own traffic echoed back by a router or a broadcast link
        mtype = msg.get_type()
        now = time.monotonic()
        if mtype == "HEARTBEAT":
            if AutopilotState.is_autopilot_heartbeat(msg) and self.autopilot.on_heartbeat(msg, now):
                log.info("autopilot found: system %d component %d", src_sys, src_comp)
                if self.config.mavlink.system_id == 0 and src_sys != self.system_id:
                    self.system_id = src_sys
                    for ep in self.endpoints:
                        ep.set_system_id(src_sys)
            if (self.source_set_check is not None and self.autopilot.from_this_autopilot(msg)
                    and msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
                self.source_set_check.on_autopilot_heartbeat()     # reads its EK3_SRC parameters
            return
        if mtype == "PARAM_VALUE":
            if self.source_set_check is not None and self.autopilot.from_this_autopilot(msg):
                self.source_set_check.on_param_value(msg)
            return
        if mtype in ("GLOBAL_POSITION_INT", "GPS_RAW_INT"):
            if self.autopilot.system_id is None or src_sys == self.autopilot.system_id:
                if mtype == "GLOBAL_POSITION_INT":
                    self.autopilot.on_global_position_int(msg, now)
                else:
                    self.autopilot.on_gps_raw_int(msg, now)
                if self.gnss is not None:
                    self.gnss.on_mavlink(msg, now)
                if self.declination_source.startswith("none"):
                    self._resolve_declination()
            return
        if mtype == "TIMESYNC":
            if msg.tc1 == 0:   # a request; answers have tc1 != 0 (MAVLink TIMESYNC v2)
                endpoint.send(msgs.timesync_reply(endpoint.timesync_stamp_ns(), msg.ts1))
            return
        if mtype == "COMMAND_ACK":
            if self.restart_heading is not None and self.autopilot.from_this_autopilot(msg):
                self.restart_heading.on_command_ack(msg)
            return
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            ours, broadcast = is_for_us(msg, self.system_id, self.component_id)
            if ours:
                self.commands.handle(msg, endpoint, broadcast)
            return
        if mtype == "FILE_TRANSFER_PROTOCOL":
            reply = ftp_nak(msg, self.system_id, self.component_id)
            if reply is not None:
                endpoint.send(reply)
            return
        if mtype in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            ours, broadcast = is_for_us(msg, self.system_id, self.component_id)
            if ours:
                self._on_param_message(endpoint, msg, mtype, broadcast)

