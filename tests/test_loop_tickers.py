"""The daemon's periodic callbacks on the event loop — housekeeping (daemon.housekeeping) and the field
calibration's ticker (daemon.magcal) — tick at their rates, one loop iteration (one wake) a tick, on a virtual
clock (tests/support/virtual_time_loop.py): counts, no wall-clock figure."""

from __future__ import annotations

import asyncio
import logging
from types import SimpleNamespace

import pytest

from ahrsd.daemon.housekeeping import HOUSEKEEPING_HZ, Housekeeping
from ahrsd.daemon.magcal import FieldCalibrationPart
from support.virtual_time_loop import VirtualTimeLoop


def _run_for(loop: VirtualTimeLoop, seconds: float, start) -> None:
    """Run the loop `seconds` of its time with `start()` (a task or None) running; the task's failure is raised."""
    async def main():
        task = start()
        try:
            await asyncio.wait_for(asyncio.shield(task), seconds) if task is not None else await asyncio.sleep(seconds)
        except asyncio.TimeoutError:
            task.cancel()

    loop.run_until_complete(main())


def test_housekeeping_runs_every_job_on_absolute_deadlines_one_loop_wake_a_tick():
    loop = VirtualTimeLoop()
    t0 = loop.time()
    calls: list[float] = []
    hk = Housekeeping([calls.append, lambda now: None])
    iterations_before = loop.iterations
    _run_for(loop, 100.0 - 1e-6, lambda: loop.create_task(hk.run(loop)))
    loop.close()
    period = 1.0 / HOUSEKEEPING_HZ
    assert len(calls) == 1000
    assert all(abs(t - (t0 + k * period)) < 1e-6 for k, t in enumerate(calls))
    # one iteration a tick (a task resumed by asyncio.sleep costs two); a few more for starting and ending
    assert loop.iterations - iterations_before <= len(calls) + 10


def test_a_late_housekeeping_tick_is_caught_up_at_once_none_skipped():
    loop = VirtualTimeLoop()
    calls: list[float] = []

    def slow_once(now):
        calls.append(now)
        if len(calls) == 10:
            loop.now_s += 0.35                 # this tick kept the loop busy for 3.5 periods

    _run_for(loop, 10.0 - 1e-6, lambda: loop.create_task(Housekeeping([slow_once]).run(loop)))
    loop.close()
    assert len(calls) == 100                   # the rate stays exact over the run
    gaps = [b - a for a, b in zip(calls, calls[1:])]
    # ticks 11 to 13 (due at 1.0, 1.1, 1.2 s) all run at 1.25 s, then on the grid again (1.3 s)
    assert gaps[9] == pytest.approx(0.35) and gaps[10] == gaps[11] == 0.0 and gaps[12] == pytest.approx(0.05)


def test_a_housekeeping_job_that_raises_ends_run_with_its_exception():
    loop = VirtualTimeLoop()
    n = [0]

    def failing(now):
        n[0] += 1
        if n[0] == 5:
            raise ZeroDivisionError("job bug")

    with pytest.raises(ZeroDivisionError):
        _run_for(loop, 10.0, lambda: loop.create_task(Housekeeping([failing]).run(loop)))
    loop.close()
    assert n[0] == 5


def test_the_field_calibration_ticker_ticks_at_its_rate_one_loop_wake_a_tick_and_stops_at_close(caplog):
    """Started by the first sample (`on_sample`); at max(10, 2.5 × progress rate) Hz; a tick that raises is
    logged and the ticking goes on; `close` stops it."""
    loop = VirtualTimeLoop()
    part = FieldCalibrationPart.__new__(FieldCalibrationPart)
    part._tick_handle = None
    pipeline = SimpleNamespace(last_sensor_sample=None, last_estimate=None, mounting=None,
                               calibration=SimpleNamespace(mag=None))
    part.host = SimpleNamespace(pipeline=pipeline)
    ticks: list[float] = []

    def tick():
        ticks.append(loop.time())
        if len(ticks) == 3:
            raise RuntimeError("tick bug")

    part.protocol = SimpleNamespace(settings=SimpleNamespace(progress_rate_hz=8.0), calibrating=False, session=None,
                                    on_sample=lambda *a: None, close=lambda: None)
    part.tick = tick

    async def main():
        for _ in range(3):
            part.on_sample(None, None)         # only the first sample starts the ticker
        before = loop.iterations
        await asyncio.sleep(10.0 - 1e-6)
        part.close()
        n = len(ticks)
        await asyncio.sleep(1.0)
        return before, n

    with caplog.at_level(logging.ERROR, logger="ahrsd.daemon.magcal"):
        before, n_at_close = loop.run_until_complete(main())
    loop.close()
    assert "magcal tick failed" in caplog.text
    assert n_at_close == 200                   # 20 Hz (2.5 × 8 Hz) for 10 s, the failed tick included
    assert len(ticks) == n_at_close            # none after close
    assert loop.iterations - before <= n_at_close + 10
