"""The commands every ahrsd answers: message intervals, message requests, gyro calibration."""

from __future__ import annotations

import math
import time
from importlib.metadata import version

from ahrsd.daemon import messages as msgs
from ahrsd.daemon.commands import CommandAck
from ahrsd.daemon.mavlink_io import mavlink



def register_builtin_commands(service) -> None:
    r = service.commands
    r.register(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, lambda m, c: set_message_interval(service, m))
    r.register(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, lambda m, c: get_message_interval(service, m, c),
               state_changing=False)
    r.register(mavlink.MAV_CMD_REQUEST_MESSAGE, lambda m, c: request_message(service, m, c), state_changing=False)
    r.register(mavlink.MAV_CMD_PREFLIGHT_CALIBRATION, lambda m, c: preflight_calibration(service, m, c),
               accept_broadcast=False)


def _message_id(value: float) -> int | None:
    # hostile input: NaN/inf params must give None, not raise (int(nan) is a ValueError)
    return int(value) if math.isfinite(value) and 0 <= value < 2**24 and value == int(value) else None


def set_message_interval(service, msg) -> int:
    mid = _message_id(msg.param1)
    if mid is None or mid not in service.schedule or not math.isfinite(msg.param2):
        return mavlink.MAV_RESULT_DENIED          # an infinite interval would silently switch the output off
    try:
        service.schedule.set_interval_us(mid, msg.param2)
    except ValueError:
        return mavlink.MAV_RESULT_DENIED
    return mavlink.MAV_RESULT_ACCEPTED


def get_message_interval(service, msg, ctx) -> int:
    mid = _message_id(msg.param1)
    if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        interval = 1_000_000
    elif mid is not None and mid in service.schedule:
        interval = service.schedule.interval_us(mid)
    else:
        interval = 0   # "0: not available"
    service.loop.call_soon(ctx.endpoint.send, msgs.message_interval(mid or 0, interval))
    return mavlink.MAV_RESULT_ACCEPTED


def autopilot_version(service):
    caps = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    major, minor, patch = (int(part) for part in version("ahrsd").split(".")[:3])
    sw = (major << 24) | (minor << 16) | (patch << 8) | 255   # FIRMWARE_VERSION_TYPE_OFFICIAL in the low byte
    return mavlink.MAVLink_autopilot_version_message(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0,
                                                     [0] * 18)


def request_message(service, msg, ctx) -> int:
    mid = _message_id(msg.param1)
    now = time.monotonic()
    if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        out = autopilot_version(service)
    elif mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
        out = msgs.heartbeat(service.mav_type, service.health.system_status(now))
    elif mid is not None and mid in service.schedule:
        out = service.build_output(mid, now)
        if out is None:
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    else:
        return mavlink.MAV_RESULT_DENIED
    # ACK first, then the message (the ACK is sent by the router when we return)
    service.loop.call_soon(ctx.endpoint.send if msg.param7 == 1 else service.send, out)
    return mavlink.MAV_RESULT_ACCEPTED


def preflight_calibration(service, msg, ctx):
    """param1 = 1: gyro bias (here); param2 = 1/76: magnetometer start/force-save (daemon.magcal, when
    attached). "Only one sensor per message" (common.xml MAV_CMD_PREFLIGHT_CALIBRATION):
    anything else is UNSUPPORTED."""
    from ahrsd.daemon.commands import command_params

    p = command_params(msg)
    magcal = getattr(service, "magcal", None)
    if p[0] == 0 and p[1] != 0 and not any(p[2:]) and magcal is not None:
        return magcal.handle_preflight_mag(msg, ctx)
    if p[0] != 1 or any(p[1:]):
        return mavlink.MAV_RESULT_UNSUPPORTED
    if service.autopilot.armed:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    if service.health.calibrating:
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    if not service.health.samples_flowing(time.monotonic()):
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    from ahrsd.daemon.gyro_cal import GyroBiasCalibration

    cal = GyroBiasCalibration(service, ctx, service.source.sample_rate_hz)
    ack = cal.start()
    return CommandAck(ack.result, ack.progress)
