"""A restart with a different heading, against fake autopilots that implement the documented rules
(docs/daemon.md, "Restarts"; read from ArduPilot's and PX4's source):

* FakeEkf3 (ArduPilot EKF3 in flight): aligns to the first sample; afterwards a sample whose innovation is
  beyond the 3σ gate (σ = VISO_YAW_M_NSE = 0.2 rad) is rejected and the yaw kept; reset_counter does not
  touch yaw (it is a position reset only).
* FakeEkf2 (PX4 EKF2): EV yaw fusion stops 0.4 s after the data stops; it (re)starts when samples come
  < 0.2 s apart and > 1 s after its last fusion, fusing that sample through the heading gate
  (2.6 σ, σ² = EKF2_EVA_NOISE = 0.1); while fusion runs, a changed reset_counter resets the yaw to ours.

Two runs of the real service share a state directory, on the simulated chip through the MEKF; between them
the sensor mounting changes by 60° (a re-mounted unit), so the second run's heading differs by 60°.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrsd.calibration.models import Calibration
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.daemon.config import Config, OutputsConfig
from ahrsd.daemon.output_registry import BY_MESSAGE_ID
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.service import Service
from ahrsd.estimator import make_estimator
from ahrsd.simulation import open_stream

VPE = 102
VPE_HZ = 30.0
GAP_S = 3.0


def wrap_deg(x):
    return (x + 180.0) % 360.0 - 180.0


class FakeEkf3:
    GATE_RAD = 3 * 0.2
    GAIN = 0.05                    # per sample: a ~0.7 s time constant at 30 Hz

    def __init__(self):
        self.yaw = None
        self.rejected = 0

    def feed(self, t, yaw, reset_counter):
        if self.yaw is None:
            self.yaw = yaw
            return
        innov = math.remainder(yaw - self.yaw, 2 * math.pi)
        if abs(innov) > self.GATE_RAD:
            self.rejected += 1
            return
        self.yaw += self.GAIN * innov


class FakeEkf2:
    GATE_RAD = 2.6 * math.sqrt(0.1)
    GAIN = 0.05

    def __init__(self):
        self.yaw = None
        self.active = False
        self.last_data = -math.inf
        self.last_fuse = -math.inf
        self.counter = None
        self.resets = 0

    def feed(self, t, yaw, reset_counter):
        if self.active and t - self.last_data > 0.4:
            self.active = False                          # "vision data stopped"
        ev_reset = self.counter is not None and reset_counter != self.counter
        self.counter = reset_counter
        interval_ok = t - self.last_data < 0.2
        self.last_data = t
        if self.yaw is None:
            self.yaw, self.active, self.last_fuse = yaw, True, t
            return
        innov = math.remainder(yaw - self.yaw, 2 * math.pi)
        if self.active:
            if ev_reset:
                self.yaw, self.last_fuse = yaw, t
                self.resets += 1
            elif abs(innov) <= self.GATE_RAD:
                self.yaw += self.GAIN * innov
                self.last_fuse = t
        elif interval_ok and t - self.last_fuse > 1.0 and abs(innov) <= self.GATE_RAD:
            self.yaw += self.GAIN * innov
            self.active, self.last_fuse = True, t


def run(tmp_path, mounting_yaw_deg, seconds, autopilots, t0, *, reset_mode=False, slew_deg_s=5.0, resets=0):
    """One run of the service: VPEs at 30 Hz fed to the fake autopilots at autopilot time t0 + t.
    Returns (t, published yaw deg, estimator heading deg, reset_counter) per VPE, and the service."""
    outputs = OutputsConfig.parse({"heading_slew_deg_s": slew_deg_s, "reset_counter_on_calibration": reset_mode})
    cfg = Config().with_overrides(state_dir=str(tmp_path / "state"))
    cfg = dataclasses.replace(cfg, outputs=outputs,
                              sensor=dataclasses.replace(cfg.sensor, mounting_rpy_deg=(0.0, 0.0, mounting_yaw_deg)))
    svc = Service(cfg)
    svc.state_dir.mkdir(parents=True, exist_ok=True)
    svc.start_restart_rule()
    svc.pipeline = Pipeline(make_estimator("mekf"), Calibration.identity())
    svc.pipeline.set_mounting([0.0, 0.0, mounting_yaw_deg])
    stream = open_stream("static", seed=5, errors="ideal")
    for _ in range(resets):            # heading resets during the run (e.g. re-initialisations)
        svc.signal_heading_reset()
    rows, next_vpe, k = [], 0.0, 0
    while True:
        b = stream.next_block(4096)
        for i in range(len(b.t_s)):
            t = float(b.t_s[i])
            if t >= seconds:
                svc._shutdown_io("test end")
                return np.array(rows), svc
            s = make_sample(t, b.gyro_rad_s[i], b.accel_m_s2[i], b.mag_ut[i], counter=k, flags=SampleFlags.NEW_DATA)
            k += 1
            svc._process((s,), t)
            est = svc.pipeline.last_estimate
            if t >= next_vpe:
                next_vpe = t + 1.0 / VPE_HZ
                m = BY_MESSAGE_ID[VPE].build(svc, est, svc.pipeline.last_sample, t)
                if m is not None:
                    for ap in autopilots:
                        ap.feed(t0 + t, m.yaw, m.reset_counter)
                    rows.append((t, math.degrees(m.yaw), math.degrees(est.heading_true_rad), m.reset_counter))


def test_restart_with_another_heading_is_slewed_in_and_ekf3_takes_it(tmp_path):
    ekf3, ekf2 = FakeEkf3(), FakeEkf2()
    first, svc1 = run(tmp_path, 0.0, 12.0, (ekf3, ekf2), 0.0)
    before = ekf3.yaw
    assert abs(wrap_deg(math.degrees(before) - first[-1, 2])) < 0.5       # both follow us in run 1
    counter1 = svc1.reset_counter
    second, svc2 = run(tmp_path, 60.0, 30.0, (ekf3, ekf2), 12.0 + GAP_S)
    new_heading = second[-1, 2]
    step = wrap_deg(new_heading - first[-1, 2])
    assert abs(abs(step) - 60.0) < 1.0                                    # the restart really changed it
    assert svc2.restart_heading.restart_step_deg is not None
    # the published heading starts where the autopilot was and never steps
    assert abs(wrap_deg(second[0, 1] - first[-1, 1])) < 0.5
    assert np.max(np.abs(wrap_deg(np.diff(second[:, 1])))) < 5.0 / VPE_HZ + 0.05
    assert np.all(second[:, 3] == counter1)                               # reset_counter continues, unchanged
    # EKF3 took every sample and ended on the new heading; EKF2 too
    assert ekf3.rejected == 0
    assert abs(wrap_deg(math.degrees(ekf3.yaw) - new_heading)) < 0.5
    assert abs(wrap_deg(math.degrees(ekf2.yaw) - new_heading)) < 0.5


def test_reset_mode_holds_until_ekf2_fuses_again_then_resets(tmp_path):
    ekf2 = FakeEkf2()
    first, _ = run(tmp_path, 0.0, 12.0, (ekf2,), 0.0, reset_mode=True)
    second, svc2 = run(tmp_path, 60.0, 12.0, (ekf2,), 12.0 + GAP_S, reset_mode=True)
    new_heading = second[-1, 2]
    assert ekf2.resets == 1
    assert abs(wrap_deg(math.degrees(ekf2.yaw) - new_heading)) < 0.1     # reset to ours, not slowly pulled
    jump = np.flatnonzero(np.diff(second[:, 3]))                          # the reset_counter change
    assert len(jump) == 1
    t_reset = second[jump[0] + 1, 0] - second[0, 0]
    assert 1.5 <= t_reset <= 2.5                                          # after the hold, not at once


def test_restart_with_the_same_heading_changes_nothing(tmp_path):
    ekf2 = FakeEkf2()
    first, svc1 = run(tmp_path, 10.0, 10.0, (ekf2,), 0.0, resets=7)
    second, svc2 = run(tmp_path, 10.0, 10.0, (ekf2,), 10.0 + GAP_S)
    assert svc1.reset_counter == 7 and np.all(second[:, 3] == 7)         # continues where the autopilot is
    assert ekf2.resets == 0
    assert not svc2.heading_slew.active
    assert np.max(np.abs(wrap_deg(second[:, 1] - second[:, 2]))) < 1e-6  # sent as estimated
