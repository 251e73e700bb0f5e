"""The reader takes a run of stepped-ahead samples at once when every listener takes runs (daemon.sample_reader
SampleListeners `runs=`, daemon.pipeline `process_block(whole_runs=True)`): the counts, the last sample, the flags
the health keeps, a re-initialisation anywhere in a run and what the field calibration keeps of each sample must be
what the per-sample path gives. Truth is worked out here one sample at a time (the counting rules of
PipelineCounters, the field calibration's window by its definition); the per-sample path is compared besides."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import ImuSample
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.magcal import FieldCalibrationPart, MagCalProtocol, _kept_vectors
from ahrsd.daemon.magcal_settings import MagCalSettings
from ahrsd.daemon.pipeline import Pipeline, _calibrated_rows
from ahrsd.daemon.sample_reader import ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.process_source import pack, unpack_block
from ahrsd.estimator.base import BlockSteppingEstimator
from ahrsd.estimator.filter_output import estimate_flags

from support.magcal_host import Clock, FakeHost
from support.sample_sequence import calibration, counted_one_by_one, sequence
from support.sample_sequence import cuts as block_cuts

REINIT = int(EstimateFlags.REINITIALISED)
WINDOW_S = 0.02                    # the field calibration's fixed-yaw window: ~16 samples of the 60


class _View:
    """An in-place estimate view (estimator/estimate_view.py) as ins's: time and flag bits of the sample set last."""

    def __init__(self):
        self.t_s, self.bits, self.valid = float("nan"), 0, False

    def set(self, t_s, bits, valid):
        self.t_s, self.bits, self.valid = t_s, bits, valid

    @property
    def flags(self):
        return estimate_flags(self.bits)

    def snapshot(self):
        return (self.t_s, self.bits)


class _RunEstimator:
    """Steps runs of drawn length (0 to the block's rest; a seeded draw a call, so two paths that call alike get
    alike runs), one sample alone otherwise; a sample whose counter is in `reinit_at` gets REINITIALISED."""

    name = "runs"

    def __init__(self, reinit_at, seed=3):
        self.rng = np.random.default_rng(seed)
        self.reinit_at = reinit_at
        self.view = _View()
        self.seen: list[tuple] = []       # (t_s, row bytes) of every sample stepped, in order
        self.t_to_counter: dict = {}

    def _bits(self, t_s):
        return REINIT if self.t_to_counter.get(float(t_s)) in self.reinit_at else 0

    def update(self, sample):
        raise AssertionError("stepped only")

    def reset(self):
        pass

    def set_declination(self, declination_rad):
        pass

    def relearn_field_reference(self, heading_change_rad=float("nan")):
        pass

    def step(self, sample):
        self.seen.append((float(sample.t_s), np.concatenate((sample.gyro_rad_s, sample.accel_m_s2,
                                                             sample.mag_ut)).tobytes()))
        self.view.set(sample.t_s, self._bits(sample.t_s), True)
        return self.view

    def step_block(self, t_s, rows, sample_flags):
        k = int(self.rng.integers(0, len(t_s) + 1))
        for j in range(k):
            self.seen.append((float(t_s[j]), rows[j].tobytes()))
        bits = [self._bits(t) for t in t_s[:k]]
        if k:
            self.view.set(float(t_s[k - 1]), bits[-1], True)
        return bits, self.view


def _sensor_frame_by_hand(cal: Calibration, s: ImuSample) -> tuple:
    """The models' formulas (calibration/models.py docstrings), one vector at a time: no mounting."""
    g, a, m = cal.gyro, cal.accel, cal.mag
    return (g.matrix @ (s.gyro_rad_s - g.bias_rad_s),
            a.matrix @ (s.accel_m_s2 - a.bias_m_s2 - a.quadratic * s.accel_m_s2 ** 2),
            m.soft_iron @ (s.mag_ut - m.hard_iron_ut))


def _run(samples, cuts, reinit_at, tmp_path, takes_runs: bool, cal=None, rpy=(0.0, 0.0, 0.0)):
    est = _RunEstimator(reinit_at)
    est.t_to_counter = {float(s.t_s): s.counter for s in samples}
    assert isinstance(est, BlockSteppingEstimator)
    pipeline = Pipeline(est, Calibration.identity() if cal is None else cal)
    pipeline.set_mounting(rpy)
    resets = []
    reader = SampleReader(None, pipeline, Health(stale_timeout_s=0.1), ServiceCounters(), SampleListeners(),
                          ReaderOutputs(publish=lambda now: None, statustext=lambda sev, text: None,
                                        heading_reset=lambda: resets.append(len(est.seen)), ready=lambda: None),
                          poll_hz=200.0)
    part = FieldCalibrationPart.__new__(FieldCalibrationPart)
    part._tick_handle = object()                       # its ticker runs already (tests/test_loop_tickers.py)
    part.host = SimpleNamespace(pipeline=pipeline)
    part.protocol = MagCalProtocol(FakeHost(tmp_path), MagCalSettings(fixed_yaw_average_s=WINDOW_S), clock=Clock(),
                                   fit_in_process=False)
    # as Service._start_field_calibration adds it; without `runs` the reader steps ahead but hands on each sample
    reader.listeners.add(part.on_sample, in_place=True, steps_ahead=part.steps_ahead,
                         runs=(part.on_run, part.takes_runs) if takes_runs else None)
    after_blocks = []
    for lo, hi in cuts:
        whole = reader.listeners.take_runs()
        reader.process(unpack_block(pack(samples[lo:hi])), samples[hi - 1].t_s)
        c, last = pipeline.counters, pipeline.last_sample
        after_blocks.append((whole, (c.samples, c.gaps, c.lost_samples, c.invalid_samples),
                             (last.t_s, last.gyro_rad_s.tobytes(), last.accel_m_s2.tobytes(), last.mag_ut.tobytes(),
                              last.temp_c, last.supply_v, last.flags, last.diag_stat, last.counter),
                             pipeline.last_sample_t_s, pipeline.last_raw_sample.counter,
                             int(reader.health.last_estimate_flags), reader.health.last_sample_flags, len(resets)))
    proto = part.protocol
    kept = [(t, *(v.tobytes() for v in _kept_vectors(k)), model) for t, k, model in proto._recent_raw]
    return after_blocks, kept, proto, est, pipeline


@pytest.mark.parametrize("seed, calibrated, rpy", [(0, False, (0.0, 0.0, 0.0)), (1, False, (0.0, 0.0, 90.0)),
                                                   (2, True, (0.0, 0.0, 0.0)), (3, True, (10.0, -5.0, 90.0)),
                                                   (4, True, (0.0, 0.0, 0.01)), (5, False, (0.0, 0.0, 0.0))])
def test_whole_runs_count_keep_and_hand_on_what_the_sample_by_sample_path_does(seed, calibrated, rpy, tmp_path):
    samples = sequence()
    reinit_at = {samples[k].counter for k in (5, 29, 44)}      # inside runs as often as not
    cuts = block_cuts(len(samples), seed, max_size=15)
    cal = calibration(seed) if calibrated else None
    runs, kept, proto, est, pipeline = _run(samples, cuts, reinit_at, tmp_path / "a", True, cal, rpy)
    alone, kept_alone, proto_alone, est_alone, _ = _run(samples, cuts, reinit_at, tmp_path / "b", False, cal, rpy)
    assert all(whole for whole, *_ in runs) and not any(whole for whole, *_ in alone)
    assert runs == [(True, *rest) for _, *rest in alone]
    # what the field calibration keeps, bit for bit the per-sample path's (a mounted one's sensor-frame rows too)
    assert kept == kept_alone
    assert proto._last_sample_t == proto_alone._last_sample_t
    assert (proto._mounting is None) == (rpy == (0.0, 0.0, 0.0)) and proto._mounting is pipeline.mounting
    assert proto._last_estimate is est.view
    assert est.seen == est_alone.seen and len(est.seen) == 60
    # truth one sample at a time: the counts after every block
    for (lo, hi), (_, counts, last, *_) in zip(cuts, runs):
        assert counts == counted_one_by_one(samples[:hi])
        want = samples[hi - 1]
        assert (last[0], last[-1], last[6]) == (want.t_s, want.counter, want.flags)
    assert counted_one_by_one(samples) == (60, 4, 13, 4)
    # a re-initialisation signalled once for each block that holds one, wherever in the block it is
    blocks_with_reinit = sum(1 for lo, hi in cuts if any(s.counter in reinit_at for s in samples[lo:hi]))
    assert runs[-1][-1] == blocks_with_reinit == 3
    # the field calibration keeps the samples within its window of the last one, in order, each with the model
    # in force, calibrated in the SENSOR frame whatever the mounting (identity calibration: the samples as given)
    t_last = samples[-1].t_s
    want = [s for s in samples if not t_last - s.t_s > WINDOW_S]
    assert [k[0] for k in kept] == [s.t_s for s in want] and 10 < len(want) < 30
    for k, s in zip(kept, want):
        if cal is None:
            assert k[1:4] == (s.gyro_rad_s.tobytes(), s.accel_m_s2.tobytes(), s.mag_ut.tobytes())
        else:
            for got, by_hand in zip(k[1:4], _sensor_frame_by_hand(cal, s)):
                np.testing.assert_allclose(np.frombuffer(got), by_hand, rtol=0, atol=1e-9)
    assert all(k[4] is pipeline.calibration.mag for k in kept)


def test_the_reader_takes_runs_only_while_every_listener_takes_them_and_steps_ahead():
    listeners = SampleListeners()
    assert listeners.take_runs()                          # no listener: the runs' bookkeeping at once
    takes, ahead = [True], [True]
    drop = listeners.add(lambda s, e: None, in_place=True, steps_ahead=lambda: ahead[0],
                         runs=(lambda t, r, e: None, lambda: takes[0]))
    assert listeners.take_runs()
    takes[0] = False                                      # e.g. its session started
    assert not listeners.take_runs() and listeners.allow_steps_ahead()
    takes[0], ahead[0] = True, False                      # a session started
    assert not listeners.take_runs()
    ahead[0] = True
    drop_plain = listeners.add(lambda s, e: None, in_place=True, steps_ahead=lambda: True)   # no run form
    assert not listeners.take_runs() and listeners.allow_steps_ahead()
    drop_plain()
    assert listeners.take_runs()
    drop()
    assert listeners.runs == {}


def test_the_field_calibration_takes_runs_only_while_no_session_runs(tmp_path):
    pipeline = Pipeline(_RunEstimator(set()), Calibration.identity())
    part = FieldCalibrationPart.__new__(FieldCalibrationPart)
    part.host = SimpleNamespace(pipeline=pipeline)
    part.protocol = SimpleNamespace(calibrating=False)
    assert part.takes_runs()
    pipeline.set_mounting([0.0, 0.0, 90.0])               # its sensor-frame rows: the pipeline's run_sensor_rows
    assert part.takes_runs()
    part.protocol.calibrating = True                     # a session gets every sample's own estimate
    assert not part.takes_runs()


def test_a_runs_sensor_frame_rows_are_the_one_row_products_bit_for_bit():
    """Pipeline.run_sensor_rows against last_sensor_sample at each sample of the run (its one-row product):
    equal bytes (the (n, 9) product in one call takes another BLAS kernel, whose last bits differ here)."""
    samples = sequence()[:24]
    cal = calibration(9)
    pipeline = Pipeline(_RunEstimator(set()), cal)
    pipeline.set_mounting([0.0, 0.0, 90.0])
    block = unpack_block(pack(samples))
    pipeline._run_block = (block, 3, 20, cal)
    rows = pipeline.run_sensor_rows()
    one_by_one = []
    for j in range(3, 20):
        pipeline._sensor, pipeline._sensor_sample = (block, j, cal), None
        s = pipeline.last_sensor_sample
        one_by_one.append(np.concatenate((s.gyro_rad_s, s.accel_m_s2, s.mag_ut)).tobytes())
    assert [r.tobytes() for r in rows] == one_by_one
    np.testing.assert_allclose(_calibrated_rows(block.vectors[3:20], cal, None), rows, rtol=0, atol=1e-9)


@pytest.mark.parametrize("times", [
    [0.000, 0.004, 0.008, 0.012, 0.016, 0.020, 0.024, 0.028],       # in order: one trim at the run's end
    [0.000, 0.004, 0.008, 0.012, 0.016, 0.040, 0.020, 0.024],       # a later time inside the run than its last
    [float("nan"), 0.004, 0.008, 0.012, 0.016, 0.040, 0.020, 0.024],
    [0.000, 0.004, 0.008, 0.012, 0.016, 0.040, float("nan"), 0.024],
    [0.000, 0.004, 0.008, 0.012, 0.016, 0.020, 0.024, float("nan")],
])
def test_a_run_keeps_what_its_samples_one_by_one_keep_whatever_their_times(times, tmp_path):
    """The protocol's `on_run` against `on_sample` at each of the run's samples (the per-sample path), after a
    first run of samples in order, the window 10 ms."""
    rng = np.random.default_rng(8)
    model = Calibration.identity().mag
    first_t = [-0.03 + 0.004 * k for k in range(7)]
    rows = rng.normal(0.0, 1.0, (len(first_t) + len(times), 9))
    t_all = first_t + times
    one, run = (MagCalProtocol(FakeHost(tmp_path / name), MagCalSettings(fixed_yaw_average_s=0.01), clock=Clock(),
                               fit_in_process=False) for name in ("one", "run"))
    for t, r in zip(t_all, rows):
        one.on_sample(ImuSample(t, r[0:3], r[3:6], r[6:9]), None, None, model)
    run.on_run(first_t, rows[:len(first_t)], None, model)
    run.on_run(times, rows[len(first_t):], None, model)

    def kept(proto):
        return [(repr(t), *(v.tobytes() for v in _kept_vectors(k)), m) for t, k, m in proto._recent_raw]
    assert kept(run) == kept(one) and len(kept(one)) >= 3
    assert repr(run._last_sample_t) == repr(one._last_sample_t)
