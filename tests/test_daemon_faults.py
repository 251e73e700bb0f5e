"""The daemon under sensor faults (simulated chip with a fault plan, in-process service, real UDP link):
corrupt frames are counted and skipped, a vanished device puts the daemon in CRITICAL and stops the heading
feed, and it recovers on its own when the device answers again."""

from __future__ import annotations

import asyncio
import dataclasses
import socket
import time

import pytest

from ahrsd.daemon.config import Config, EndpointConfig, StateConfig
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.drivers.chip_source import ChipSource
from ahrsd.daemon.service import Service
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.faults import FaultKind, FaultPlan
from ahrsd.drivers.simulated import SimulatedAdis16405
from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)


def test_corrupt_frames_and_a_vanished_device(tmp_path):
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    port = rx.getsockname()[1]
    cfg = dataclasses.replace(Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{port}"),),
                              state=StateConfig(str(tmp_path)))
    save_mag_calibration(tmp_path, sim_chip_mag_model())      # no heading is sent on an uncalibrated one
    plan = FaultPlan(seed=3)
    bus = SimulatedAdis16405("static", seed=0, clock=time.monotonic, faults=plan)
    driver = Adis16405(bus)
    driver.start()
    plan.add(FaultKind.GARBAGE, start_sample=bus.sample_index, probability=0.02)
    bus_error = plan.add(FaultKind.BUS_ERROR, enabled=False)    # switched on once the daemon is ACTIVE
    service = Service(cfg, source=ChipSource(driver, bus, "faulty chip"))
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    events: list[tuple[float, str, object]] = []

    def collect():
        while True:
            try:
                data = rx.recv(4096)
            except BlockingIOError:
                return
            for m in parser.parse_buffer(data) or ():
                events.append((time.monotonic(), m.get_type(), m))

    async def main():
        loop = asyncio.get_running_loop()
        loop.add_reader(rx.fileno(), collect)
        task = asyncio.create_task(service.run())
        # each phase ends on what the ground station saw, not on a fixed time: a loaded machine only takes
        # longer (the overall limit is for a daemon that never recovers)
        end = time.monotonic() + 300
        phase, t_phase = "wait-active", 0.0
        while time.monotonic() < end and phase != "done":
            await asyncio.sleep(0.1)
            s = states()
            if phase == "wait-active" and s and s[-1] == mavlink.MAV_STATE_ACTIVE:
                bus_error.enabled, phase = True, "device-gone"
                fault.update(t=time.monotonic(), n_states=len(s))
            elif phase == "device-gone" and mavlink.MAV_STATE_CRITICAL in after_fault() and failure_reported():
                phase, t_phase = "gone-for-a-while", time.monotonic()
            elif phase == "gone-for-a-while" and time.monotonic() - t_phase > 2.5:     # ≥ 2 heartbeats
                bus_error.enabled, phase = False, "recovering"
            elif phase == "recovering" and recovered():
                phase, t_phase = "after", time.monotonic()
            elif phase == "after" and time.monotonic() - t_phase > 1.0 and heading_resumed():
                phase = "done"
        service.request_stop()
        code = await task
        loop.remove_reader(rx.fileno())
        return code

    def states():
        return [m.system_status for _, t, m in events if t == "HEARTBEAT"]

    # a starved daemon may report CRITICAL while it boots: everything is judged from the fault's start
    fault = {"t": float("inf"), "n_states": 0}

    def after_fault():
        return states()[fault["n_states"]:]

    def failure_reported():
        return any(kind == "STATUSTEXT" and "sensor failure" in m.text and t > fault["t"] for t, kind, m in events)

    def recovered():
        s = after_fault()
        return mavlink.MAV_STATE_CRITICAL in s and s[-1] == mavlink.MAV_STATE_ACTIVE

    def texts_in_order():
        """The indices in `events` of the failure's text (after the fault) and of the recovery's after it."""
        i_fail = next((i for i, (t, kind, m) in enumerate(events) if kind == "STATUSTEXT"
                       and "sensor failure" in m.text and t > fault["t"]), None)
        i_back = None if i_fail is None else next((i for i, (_, kind, m) in enumerate(events) if i > i_fail
                                                   and kind == "STATUSTEXT" and "recovered" in m.text), None)
        return i_fail, i_back

    def heading_resumed():
        _, i_back = texts_in_order()
        return i_back is not None and any(kind == "VISION_POSITION_ESTIMATE" for _, kind, _ in events[i_back:])

    assert asyncio.run(main()) == 0
    rx.close()
    s = states()
    assert s[fault["n_states"] - 1] == mavlink.MAV_STATE_ACTIVE         # was good before the fault
    assert mavlink.MAV_STATE_CRITICAL in after_fault()
    assert s[-1] == mavlink.MAV_STATE_ACTIVE                            # recovered without a restart
    texts = [m.text for _, t, m in events if t == "STATUSTEXT"]
    assert any("sensor failure" in x for x in texts) and any("recovered" in x for x in texts)
    assert service.counters.frame_errors > 0 and service.counters.driver_errors > 0
    # no heading for the autopilot while the device was gone, and it resumes afterwards: in the order the
    # service sent (one UDP socket on loopback keeps it), not by when this test's reader ran
    i_fail, i_back = texts_in_order()
    assert i_fail is not None and i_back is not None
    assert events[i_back][0] - events[i_fail][0] > 2.0                  # the device was gone ≥ 2.5 s of the test
    assert not [1 for _, kind, _ in events[i_fail:i_back] if kind == "VISION_POSITION_ESTIMATE"]
    assert heading_resumed()
    # the sensor errors are reported in SYS_STATUS.errors_count4
    assert max(m.errors_count4 for _, t, m in events if t == "SYS_STATUS") > 0


def test_replay_of_a_recording_runs_and_ends(tmp_path):
    """`ahrsd run --replay` on a recording from `ahrsd record`: estimates flow, time stamps are the recording's
    t_s (what a ground station plots lines up with the recording), and the daemon stops by itself at the end
    of the file (status 0). Both by ahrsd's main in this process (support/replay_inproc.py: what is checked is
    what the daemon sends, not its process)."""
    from ahrsd.cli.main import main as ahrsd_main
    from ahrsd.drivers.recording import read_recording
    from support.replay_inproc import replay_inproc

    rec = tmp_path / "rec.csv"
    # recorded in this process: the same bytes as `ahrsd record` in its own (docs/testing.md, rel33)
    assert ahrsd_main(["record", "--sim", "static", "--output", str(rec), "--seconds", "3", "--quiet"]) == 0
    save_mag_calibration(tmp_path / "state", sim_chip_mag_model())  # no heading is sent on an uncalibrated one
    got = replay_inproc(tmp_path, "--replay", str(rec))              # returns once the run ended by itself, 0
    usecs = [m.usec for _, m in got.get("VISION_POSITION_ESTIMATE", [])]
    assert len(usecs) > 20
    recorded_us = {int(t * 1e6) for t in read_recording(rec).t_s}
    assert all(u in recorded_us for u in usecs)                     # recording time, not CLOCK_MONOTONIC
