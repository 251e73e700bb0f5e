"""The commands every ahrsd answers: message intervals, message requests, gyro calibration.

Every handler reads its parameters through daemon.command_args (the same view of COMMAND_LONG and COMMAND_INT)
and checks them before acting; a bad request is refused with the MAV_RESULT and a reason (`Refused`).
Parameters a command does not use are ignored, as the MAVLink command tables say ("reserved")."""

from __future__ import annotations

import math
import time
from importlib.metadata import version

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.command_args import CommandArgs, Refused, whole_number
from ahrsd.daemon.commands import CommandAck
from ahrsd.daemon.mavlink_io import mavlink



class BuiltinCommands:
    """The parts the built-in commands act on, given explicitly. `field_calibration`: the mag-cal protocol
    handler PREFLIGHT_CALIBRATION param2 delegates to (None: refused as unsupported); `start_gyro_calibration(ctx)`
    starts daemon.gyro_cal for one command."""

    def __init__(self, *, endpoint_outputs, publishers, outbound, health, autopilot, field_calibration,
                 start_gyro_calibration, call_soon, clock=time.monotonic):
        self.endpoint_outputs = endpoint_outputs
        self.publishers = publishers
        self.outbound = outbound
        self.health = health
        self.autopilot = autopilot
        self.field_calibration = field_calibration
        self.start_gyro_calibration = start_gyro_calibration
        self.call_soon = call_soon
        self.clock = clock

    def register(self, r) -> None:
        r.register(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, lambda m, c: set_message_interval(self, m, c))
        r.register(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, lambda m, c: get_message_interval(self, m, c),
                   state_changing=False)
        r.register(mavlink.MAV_CMD_REQUEST_MESSAGE, lambda m, c: request_message(self, m, c), state_changing=False)
        r.register(mavlink.MAV_CMD_PREFLIGHT_CALIBRATION, lambda m, c: preflight_calibration(self, m, c),
                   accept_broadcast=False)


MESSAGE_ID_MAX = 2**24 - 1          # MAVLink 2 message ids are 24 bits
MAX_INTERVAL_US = 3600e6            # SET_MESSAGE_INTERVAL: slower than once an hour is refused, not "almost off"
RESPONSE_DEFAULT, RESPONSE_REQUESTER, RESPONSE_BROADCAST = 0, 1, 2   # REQUEST_MESSAGE param7


def _message_id(value: float) -> int | None:
    # hostile input: NaN/inf params must give None, not raise (int(nan) is a ValueError)
    return whole_number(value, 0, MESSAGE_ID_MAX)


def set_message_interval(parts: BuiltinCommands, msg, ctx) -> int:
    """param1 message id, param2 interval µs (−1 off, 0 default, > 0). Changes the rate on the endpoint the
    request came in on only (daemon.endpoint_outputs)."""
    schedule = ctx.endpoint.schedule
    args = CommandArgs.of(msg)
    mid, interval_us = _message_id(args.p(1)), args.p(2)
    if mid is None:
        return Refused(mavlink.MAV_RESULT_DENIED, f"SET_MESSAGE_INTERVAL: message id {args.p(1)} invalid")
    if mid not in schedule:
        return Refused(mavlink.MAV_RESULT_DENIED, f"SET_MESSAGE_INTERVAL: message {mid} is not an output")
    # an infinite interval would silently switch the output off, a tiny one exceed its maximum rate
    if not (interval_us in (-1.0, 0.0) or 0.0 < interval_us <= MAX_INTERVAL_US):
        return Refused(mavlink.MAV_RESULT_DENIED, f"SET_MESSAGE_INTERVAL: interval {interval_us} us invalid")
    rate_hz = 1e6 / interval_us if interval_us > 0 else 0.0
    if rate_hz > schedule.max_rate_hz(mid):
        return Refused(mavlink.MAV_RESULT_DENIED, f"msg {mid}: {rate_hz:.4g} Hz > max {schedule.max_rate_hz(mid):g} Hz")
    parts.endpoint_outputs.set_message_interval(ctx.endpoint, mid, interval_us)
    return mavlink.MAV_RESULT_ACCEPTED


def get_message_interval(parts: BuiltinCommands, msg, ctx) -> int:
    """param1 message id; answered with MESSAGE_INTERVAL (interval 0: "not available" for a valid id we do
    not publish)."""
    raw_id = CommandArgs.of(msg).p(1)
    mid = _message_id(raw_id)
    if mid is None:
        return Refused(mavlink.MAV_RESULT_DENIED, f"GET_MESSAGE_INTERVAL: message id {raw_id} invalid")
    if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        interval_us = 1_000_000   # the 1 Hz heartbeat
    elif mid is not None and mid in ctx.endpoint.schedule:
        interval_us = ctx.endpoint.schedule.interval_us(mid)
    else:
        interval_us = 0   # "0: not available"
    parts.call_soon(ctx.endpoint.send, msgs.message_interval(mid, interval_us))
    return mavlink.MAV_RESULT_ACCEPTED


def autopilot_version():
    caps = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    major, minor, patch = (int(part) for part in version("ahrsd").split(".")[:3])
    sw = (major << 24) | (minor << 16) | (patch << 8) | 255   # FIRMWARE_VERSION_TYPE_OFFICIAL in the low byte
    return mavlink.MAVLink_autopilot_version_message(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0,
                                                     [0] * 18)


def request_message(parts: BuiltinCommands, msg, ctx) -> int:
    """param1 message id, param2..6 message-specific (none of ours uses them), param7 response target
    (0 default = every endpoint, 1 the requester, 2 broadcast); in COMMAND_INT param7 is z."""
    args = CommandArgs.of(msg)
    mid = _message_id(args.p(1))
    target = whole_number(args.p(7), RESPONSE_DEFAULT, RESPONSE_BROADCAST)
    if mid is None:
        return Refused(mavlink.MAV_RESULT_DENIED, f"REQUEST_MESSAGE: message id {args.p(1)} invalid")
    if target is None:
        return Refused(mavlink.MAV_RESULT_DENIED, f"REQUEST_MESSAGE: response target {args.p(7)} invalid")
    now = parts.clock()
    if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        out = autopilot_version()
    elif mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        out = msgs.heartbeat(parts.outbound.identity.mav_type, parts.health.system_status(now))
    elif mid is not None and mid in ctx.endpoint.schedule:
        out = parts.publishers.build_output(mid, now)
        if out is None:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    else:
        return Refused(mavlink.MAV_RESULT_DENIED, f"REQUEST_MESSAGE: message {mid} not available")
    # ACK first, then the message (the ACK is sent by the router when we return)
    parts.call_soon(ctx.endpoint.send if target == RESPONSE_REQUESTER else parts.outbound.send, out)
    return mavlink.MAV_RESULT_ACCEPTED


def preflight_calibration(parts: BuiltinCommands, msg, ctx):
    """param1 = 1: gyro bias (here); param2 = 1/76: magnetometer start/force-save (daemon.magcal, when
    attached). "Only one sensor per message" (MAV_CMD_PREFLIGHT_CALIBRATION): anything else is UNSUPPORTED."""
    p = CommandArgs.of(msg).params
    if not all(math.isfinite(v) for v in p):
        return Refused(mavlink.MAV_RESULT_DENIED, "PREFLIGHT_CALIBRATION: non-finite parameter")
    magcal = parts.field_calibration
    if p[0] == 0 and p[1] != 0 and not any(p[2:]) and magcal is not None:
        return magcal.handle_preflight_mag(msg, ctx)
    if p[0] != 1 or any(p[1:]):
        return mavlink.MAV_RESULT_UNSUPPORTED
    if parts.autopilot.armed:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    if parts.health.calibrating:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    if not parts.health.samples_flowing(parts.clock()):
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    ack = parts.start_gyro_calibration(ctx)
    return CommandAck(ack.result, ack.progress)
