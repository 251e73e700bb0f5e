"""A field magnetometer calibration session leaves the estimator alone until its result is accepted (#28, #30:
the README tour saw mekf's heading 1σ peak 0.1–0.4° higher in daemons running a session). The same simulated
boat samples go through the daemon's own parts — the sample reader, the pipeline, mekf on a right calibration with
its stated figure, and the field calibration (daemon.magcal.FieldCalibrationPart as Service wires it, ticked on
the samples' clock) — once without a session and once with one started 5 s in and run to its result, left
unanswered as `ahrsd magcal start </dev/null` leaves it. Every published attitude and 1σ must be the same bit for
bit: what differed in the tour was the daemon's start (docs/magcal-field.md "A session and the heading 1σ")."""

from __future__ import annotations

import functools
import math
import time
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("ahrsd.daemon.service")

from ahrsd.calibration.field import CalStatus  # noqa: E402
from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad  # noqa: E402
from ahrsd.calibration.models import Calibration, MagModel  # noqa: E402
from ahrsd.daemon.config import Config  # noqa: E402
from ahrsd.daemon.magcal import CMD_START, DaemonMagCalHost, FieldCalibrationPart  # noqa: E402
from ahrsd.daemon.magcal_settings import MagCalSettings  # noqa: E402
from ahrsd.daemon.pipeline import Pipeline  # noqa: E402
from ahrsd.daemon.service import Service  # noqa: E402
from ahrsd.estimator.mekf import Mekf  # noqa: E402
from support.stream_samples import stream_samples  # noqa: E402

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

RUN_S = 100.0
START_AT_S = 5.0
TICK_S = 0.1      # the part's ticker period at the default progress rate (daemon.magcal: ≥ 10 Hz)


@functools.lru_cache(maxsize=1)
def _level_turns():
    """The level turns of seed 1, simulated once for both runs (freed after the module: _level_turns_freed)."""
    return stream_samples("level-turns", 1, RUN_S)


@pytest.fixture(scope="module", autouse=True)
def _level_turns_freed():
    yield
    _level_turns.cache_clear()


def _run(tmp_path, with_session: bool):
    """(t, roll, pitch, yaw, σ roll, σ pitch, σ yaw) every TICK_S, and the session's last status (None without)."""
    svc = Service(Config().with_overrides(state_dir=str(tmp_path)))
    stream = _level_turns()
    e = stream.errors
    right = Calibration.identity().with_sensor("mag", MagModel(e.hard_iron_ut, np.linalg.inv(e.soft_iron)),
                                               method="test", heading_std_deg=0.09, offset_std_deg=0.09)
    estimator = Mekf()
    svc.use_pipeline(Pipeline(estimator, right))
    estimator.set_mag_calibration_sigma(calibration_heading_sigma_rad(right))      # as Service.start does
    now = [0.0]
    host = DaemonMagCalHost(svc.pipeline, svc.swap, svc.outbound, svc.autopilot, svc.positions, svc.heading.slew)
    part = FieldCalibrationPart(host, MagCalSettings(), commands=svc.commands, autopilot=svc.autopilot,
                                set_calibrating=svc.set_calibrating, clock=lambda: now[0], warm_fit_worker=False)
    part.protocol.fit_in_process = False      # fits in a thread: no worker process to start
    part._tick_handle = object()              # no loop ticker: ticked below on the samples' clock
    svc.listeners.add(part.on_sample, in_place=True)        # as Service._start_field_calibration adds it
    start = SimpleNamespace(command=CMD_START, param1=0.0, param2=0.0, param3=0.0, param4=0.0, param5=0.0,
                            param6=0.0, param7=0.0, get_type=lambda: "COMMAND_LONG")
    rows, next_tick, started = [], 0.0, False
    pending = []      # the samples up to the next tick (or the start), to the reader as one block as the daemon's
    for _k, t, s in stream.until(RUN_S):
        if t >= RUN_S:
            if pending:
                svc.reader.process(pending, now[0])
            s = part.protocol.session
            if s is not None:
                _wait_for_the_fit(part, s)
            return np.array(rows), (s.status if s is not None else None), part
        if with_session and not started and t >= START_AT_S:
            if pending:
                svc.reader.process(pending, now[0])
                pending = []
            now[0] = t
            assert part.protocol.handle_start(start) == 0      # MAV_RESULT_ACCEPTED
            started = True
        pending.append(s)
        now[0] = t
        if t >= next_tick:
            svc.reader.process(pending, t)
            pending = []
            next_tick = t + TICK_S
            part.tick()
            est = svc.pipeline.last_estimate
            rows.append((t, est.roll_rad, est.pitch_rad, est.yaw_rad, *est.sigma_rpy_rad))


FIT_WAIT_S = 120.0


def _wait_for_the_fit(part, session) -> None:
    """The session fits in a thread while the samples run at the processor's speed: on a busy machine the last
    sample comes before the fit ends. Tick (the samples' clock held at the end) until the fit's result is taken
    in, so the status read is the session's outcome, not the race's."""
    end = time.monotonic() + FIT_WAIT_S
    while session.status in (CalStatus.RUNNING_STEP_ONE, CalStatus.RUNNING_STEP_TWO) and time.monotonic() < end:
        if not part.protocol.fit_running:
            break
        time.sleep(0.05)
        part.tick()


def test_a_running_session_changes_no_published_attitude_or_sigma(tmp_path):
    without, status_without, _ = _run(tmp_path / "a", with_session=False)
    with_, status, part = _run(tmp_path / "b", with_session=True)
    assert status_without is None
    # the session ran its whole course: it took samples, fitted and waits for an answer
    assert status == CalStatus.SUCCESS and not part.protocol.saved, status
    assert part.protocol.session.result is not None
    assert len(with_) == len(without) and np.all(np.isfinite(without[20:]))
    # the heading 1σ moves over the run (the boat's turns): the comparison is not of a constant
    assert np.ptp(without[20:, 6]) > math.radians(1.0)
    assert np.array_equal(with_, without), np.max(np.abs(with_ - without), axis=0)
