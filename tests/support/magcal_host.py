"""A fake daemon host for the mag-cal MAVLink handler, and helpers to drive it with synthetic trajectories.

Messages are packed and parsed by pymavlink so a wrong field order or type fails where they are used.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np

from ahrsd.calibration.store import CalibrationStore
from ahrsd.core.sample import make_sample
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Identity, Outbound

from support.field_data import SITE

MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)


def wire(msg):
    """Pack and parse like a receiver would."""
    buf = msg.pack(MAV)
    return mavlink.MAVLink(None).parse_char(bytearray(buf))


class FakeHost:
    def __init__(self, state_dir, armed=False):
        self.store = CalibrationStore(state_dir)
        self.cal = self.store.load()
        self.sent = []
        self.is_armed = armed
        self.applied = []
        # texts go out as the daemon sends them (daemon.outbound: chunked, logged), to `send` below; its clock
        # steps a second per text, so the rate limit never drops one here (tests/test_outbound_statustext.py
        # tests the limit)
        self.outbound = Outbound(Identity(1, 200, mavlink.MAV_TYPE_ONBOARD_CONTROLLER), ServiceCounters(),
                                 clock=itertools.count().__next__)
        self.outbound.endpoints.append(self)

    def current_calibration(self):
        return self.cal

    def apply_calibration(self, cal):
        self.store.save(cal)      # as Service.apply_calibration: persist first, swap only if that worked
        self.cal = cal
        self.applied.append(cal)

    def send(self, msg):
        self.sent.append(wire(msg))

    def send_together(self, msgs):
        for msg in msgs:
            self.send(msg)
        return True

    def statustext(self, severity, text):
        self.outbound.statustext(severity, text)

    def armed(self):
        return self.is_armed

    def reference_field(self, lat_deg=None, lon_deg=None):
        return SITE

    def of_type(self, name):
        return [m for m in self.sent if m.get_type() == name]

    def texts(self):
        """STATUSTEXT lines, MAVLink 2 chunks (same id, chunk_seq 0, 1, ...) joined back into one line."""
        out, chunks = [], {}
        for m in self.of_type("STATUSTEXT"):
            if m.id == 0:
                out.append(m.text)
            elif m.chunk_seq == 0:
                chunks[m.id] = len(out)
                out.append(m.text)
            elif m.id in chunks:
                out[chunks[m.id]] += m.text
        return out


class Clock:
    t = 1000.0

    def __call__(self):
        return self.t


def cmd(command, *params):
    p = list(params) + [0.0] * (7 - len(params))
    return wire(mavlink.MAVLink_command_long_message(1, 200, command, 0, *p))


def body_rate(traj, i):
    """Body rates of the heading turn alone (roll/pitch rates left out): R_bn · [0, 0, ψ̇]."""
    psi_dot = (traj.yaw[min(i + 1, len(traj.t) - 1)] - traj.yaw[max(i - 1, 0)]) / (
        traj.t[min(i + 1, len(traj.t) - 1)] - traj.t[max(i - 1, 0)])
    r, p = traj.roll[i], traj.pitch[i]
    return psi_dot * np.array([-np.sin(p), np.sin(r) * np.cos(p), np.cos(r) * np.cos(p)])


def tick_settled(proto) -> None:
    """One protocol tick; a fit it started is waited for and collected (deterministic tests)."""
    proto.tick()
    if proto._fit_future is not None:
        proto._fit_future.result()
        proto.tick()


def drive(proto, clock, traj, host, until=None, max_t=None):
    """Feed the trajectory as calibrated samples; tick at 10 Hz of sample time (clock follows sample time)."""
    next_tick = 0.0
    for i in range(len(traj.t)):
        t = traj.t[i]
        if max_t is not None and t > max_t:
            break
        clock.t = 1000.0 + t
        mag = host.cal.mag.apply(traj.raw[i])
        s = make_sample(t, np.zeros(3), traj.accel[i], mag)
        est = SimpleNamespace(roll_rad=traj.roll[i], pitch_rad=traj.pitch[i], yaw_rad=traj.yaw[i],
                              rate_body_rad_s=body_rate(traj, i), gyro_bias_rad_s=np.zeros(3))
        proto.on_sample(s, est)
        if t >= next_tick:
            next_tick = t + 0.1
            tick_settled(proto)
            if until is not None and until():
                return t
    return traj.t[-1]


def drive_vehicle(proto, clock, block, host, courses=None, until=None):
    """Feed a fieldcal_sim recording (truth attitude as the estimate) and GPS_RAW_INT at arrival times."""
    from support.field_vehicle import truth_euler

    eul = truth_euler(block)
    next_tick, k = 0.0, 0
    for i in range(len(block.t_s)):
        t = float(block.t_s[i])
        clock.t = 1000.0 + t
        mag = host.cal.mag.apply(block.mag_ut[i])
        proto.on_sample(make_sample(t, block.gyro_rad_s[i], block.accel_m_s2[i], mag),
                        SimpleNamespace(roll_rad=eul[i, 2], pitch_rad=eul[i, 1], yaw_rad=eul[i, 0],
                                        rate_body_rad_s=block.truth_gyro_rad_s[i], gyro_bias_rad_s=np.zeros(3)))
        while courses is not None and k < courses[0].size and courses[0][k] <= t:
            proto.on_gnss_message(gps_raw_int(courses[1][k], courses[2][k], courses[3][k]))
            k += 1
        if t >= next_tick:
            next_tick = t + 0.1
            tick_settled(proto)
            if until is not None and until():
                return i
    return len(block.t_s) - 1


def gps_raw_int(t_valid_s, course_rad, speed_m_s, fix_type=3, vel_acc_mm_s=0):
    """GPS_RAW_INT as an autopilot sends it (cog cdeg, vel cm/s), packed and parsed by pymavlink."""
    return wire(mavlink.MAVLink_gps_raw_int_message(
        int(t_valid_s * 1e6), fix_type, 364200000, 549800000, 1345000, 80, 120, int(round(speed_m_s * 100)),
        int(round(np.degrees(course_rad) * 100)) % 36000, 12, 0, 0, 0, vel_acc_mm_s, 0, 0))
