"""The reader process's blocks kept as columns (core.sample_block, Pipeline.process_block): the block is
calibrated and rotated at once, yet every sample is counted, calibrated, estimated and shown to the listeners as
the per-sample path does. Truth is worked independently: the calibration's affine maps written out per vector."""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrsd.calibration.models import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import LATE_AFTER_S, ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.process_source import _RECORD, pack, unpack_block

from support.sample_sequence import calibration, counted_one_by_one, sequence
from support.sample_sequence import cuts as block_cuts

RATE_HZ = 819.2
F = SampleFlags


class _Est:
    flags = EstimateFlags.NONE


class _StubEstimator:
    def __init__(self):
        self.seen: list[ImuSample] = []

    def update(self, sample):
        self.seen.append(sample)
        return _Est()


def _by_hand(cal: Calibration, raw: ImuSample, mounting=None):
    """The models' formulas (calibration/models.py docstrings), one vector at a time, then C · v."""
    g, a, m = cal.gyro, cal.accel, cal.mag
    out = (g.matrix @ (raw.gyro_rad_s - g.bias_rad_s),
           a.matrix @ (raw.accel_m_s2 - a.bias_m_s2 - a.quadratic * raw.accel_m_s2 ** 2),
           m.soft_iron @ (raw.mag_ut - m.hard_iron_ut))
    return out if mounting is None else tuple(mounting @ v for v in out)


def _raw(counters, flags=None, seed=2):
    rng = np.random.default_rng(seed)
    flags = flags or [SampleFlags.NEW_DATA] * len(counters)
    return [ImuSample(100.0 + k / RATE_HZ, rng.normal(0, 0.5, 3), rng.normal([0, 0, -9.8], 1.0),
                      rng.normal([20, 0, 40], 3.0), 25.0 + 0.01 * k, 5.0, f, 0, k) for k, f in zip(counters, flags)]


def _reader(pipeline, raw_sink=None):
    return SampleReader(None, pipeline, Health(stale_timeout_s=0.1), ServiceCounters(), SampleListeners(),
                        ReaderOutputs(publish=lambda now: None, statustext=lambda sev, text: None,
                                      heading_reset=lambda: None, ready=lambda: None, raw_sink=raw_sink),
                        poll_hz=200.0)


def test_a_block_is_the_packed_samples_column_by_column():
    raw = _raw(range(6), [SampleFlags.NEW_DATA, SampleFlags.NONE, SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE,
                          SampleFlags.NEW_DATA | SampleFlags.ALARM, SampleFlags.NEW_DATA, SampleFlags.STALE])
    block = unpack_block(pack(raw[:4]) + pack(raw[4:]))
    assert type(block) is SampleBlock and len(block) == 6
    for got, want in zip(block, raw):
        assert (got.t_s, got.temp_c, got.flags, got.counter) == (want.t_s, want.temp_c, want.flags, want.counter)
        assert type(got.flags) is SampleFlags
        assert np.array_equal(got.gyro_rad_s, want.gyro_rad_s) and np.array_equal(got.mag_ut, want.mag_ut)
    assert [s.counter for s in block[-2:]] == [4, 5] and block[-1].counter == 5


def test_a_gap_in_the_middle_of_a_block_counts_exactly_that_gap():
    counters = [10, 11, 12, 16, 17, 18, 19]                   # 13, 14, 15 lost before 16
    flags = [SampleFlags.NEW_DATA] * 7
    flags[3] = SampleFlags.NEW_DATA | SampleFlags.GAP_BEFORE
    flags[5] = SampleFlags.NEW_DATA | SampleFlags.GYRO_INVALID
    pipeline = Pipeline(_StubEstimator(), Calibration.identity())
    _reader(pipeline).process(unpack_block(pack(_raw(counters, flags))), 100.0)
    c = pipeline.counters
    assert (c.samples, c.gaps, c.lost_samples, c.invalid_samples) == (7, 1, 3, 1)
    # the status line's rate is counted on the sensor's clock (daemon/housekeeping.HealthReport): the last
    # sample's own time stamp, sample 19's
    assert pipeline.last_sample_t_s == 100.0 + 19 / RATE_HZ


def test_every_sample_of_a_block_reaches_the_estimator_and_the_listeners_calibrated_and_mounted():
    cal = calibration()
    est = _StubEstimator()
    pipeline = Pipeline(est, cal)
    pipeline.set_mounting([0.0, 0.0, 90.0])
    c_mount = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])    # Rz(90°): body ← sensor
    reader = _reader(pipeline)
    seen, sensor_frame = [], []
    reader.listeners.add(lambda s, e: (seen.append(s), sensor_frame.append(pipeline.last_sensor_sample)),
                         in_place=True)
    raw = _raw(range(40, 52))
    for k in range(0, 12, 4):
        reader.process(unpack_block(pack(raw[k:k + 4])), 100.0)
    assert [s.counter for s in seen] == list(range(40, 52)) and est.seen == seen
    for s, sensor, r in zip(seen, sensor_frame, raw):
        for got, want in zip((s.gyro_rad_s, s.accel_m_s2, s.mag_ut), _by_hand(cal, r, c_mount)):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        for got, want in zip((sensor.gyro_rad_s, sensor.accel_m_s2, sensor.mag_ut), _by_hand(cal, r)):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert (s.t_s, s.temp_c, s.flags, s.counter) == (r.t_s, r.temp_c, r.flags, r.counter)


def test_a_calibration_swapped_by_a_listener_mid_block_applies_from_the_next_sample():
    old, new = calibration(1), calibration(7)
    pipeline = Pipeline(_StubEstimator(), old)
    reader = _reader(pipeline)
    seen = []

    def listener(s, e):
        seen.append(s)
        if s.counter == 2:
            pipeline.calibration = new                        # what Service.apply_calibration does, between samples

    reader.listeners.add(listener, in_place=True)
    raw = _raw(range(6))
    reader.process(unpack_block(pack(raw)), 100.0)
    for s, r in zip(seen, raw):
        want = _by_hand(old if r.counter <= 2 else new, r)
        np.testing.assert_allclose(s.mag_ut, want[2], rtol=0, atol=1e-12)


def test_the_field_calibration_gets_each_sample_in_the_sensor_frame_with_the_mag_model_that_calibrated_it():
    """The field calibration's listener (daemon.magcal.FieldCalibrationPart) reads the pipeline's attributes
    directly: it must still hand its protocol every sample calibrated but unrotated (a mounting rotates only the
    body-frame sample), the mounting, and the magnetometer model of the calibration in force at that sample (one
    swapped by a listener mid-block from the next sample), against the models' formulas by hand."""
    from types import SimpleNamespace

    from ahrsd.daemon.magcal import FieldCalibrationPart

    for rpy in ([0.0, 0.0, 0.0], [0.0, 0.0, 90.0]):
        old, new = calibration(1), calibration(7)
        pipeline = Pipeline(_StubEstimator(), old)
        pipeline.set_mounting(rpy)
        given = []
        part = FieldCalibrationPart.__new__(FieldCalibrationPart)
        part._tick_handle = object()                       # its ticker runs already (tests/test_loop_tickers.py)
        part.host = SimpleNamespace(pipeline=pipeline)
        part.protocol = SimpleNamespace(session=None, on_sample=lambda *args: given.append(args))
        reader = _reader(pipeline)
        reader.listeners.add(part.on_sample, in_place=True)
        reader.listeners.add(lambda s, e: setattr(pipeline, "calibration", new) if s.counter == 2 else None,
                             in_place=True)
        raw = _raw(range(6))
        reader.process(unpack_block(pack(raw)), 100.0)
        assert len(given) == 6
        for (sample, _est, mounting, model), r in zip(given, raw):
            cal = old if r.counter <= 2 else new
            for got, want in zip((sample.gyro_rad_s, sample.accel_m_s2, sample.mag_ut), _by_hand(cal, r)):
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
            assert model is cal.mag and mounting is pipeline.mounting and sample.counter == r.counter


def test_a_sample_the_stepping_estimator_rejects_is_counted_and_resets_it_and_the_next_one_goes_on():
    """An estimator with `step` (the daemon's path) raising ValueError at one sample: that sample gives no estimate,
    it is counted in estimator_errors and the estimator is reset once; the samples after it are stepped as before."""
    class Stepping:
        name = "stepping"

        def __init__(self):
            self.stepped, self.resets = [], 0

        def step(self, sample):
            if sample.counter == 3:
                raise ValueError("not finite")
            self.stepped.append(sample.counter)
            return _Est()

        def update(self, sample):
            raise AssertionError("a stepping estimator is stepped")

        def reset(self):
            self.resets += 1

        def set_declination(self, declination_rad):
            pass

        def relearn_field_reference(self, heading_change_rad=float("nan")):
            pass

    from ahrsd.estimator.base import SteppingEstimator

    est = Stepping()
    assert isinstance(est, SteppingEstimator)
    pipeline = Pipeline(est, calibration())
    given = list(pipeline.process_block(unpack_block(pack(_raw(range(6))))))
    assert [g is None for g in given] == [False, False, False, True, False, False]
    assert est.stepped == [0, 1, 2, 4, 5] and est.resets == 1 and pipeline.counters.estimator_errors == 1
    assert pipeline.counters.samples == 6 and pipeline.last_sample.counter == 5


def test_the_vehicle_log_gets_every_raw_sample_of_a_block():
    logged = []
    pipeline = Pipeline(_StubEstimator(), calibration())
    raw = _raw(range(5))
    _reader(pipeline, raw_sink=logged.append).process(unpack_block(pack(raw)), 100.0)
    assert [s.counter for s in logged] == list(range(5))
    assert all(np.array_equal(a.mag_ut, b.mag_ut) for a, b in zip(logged, raw))    # raw, not calibrated


def test_late_samples_of_a_block_are_counted_from_their_time_stamps():
    pipeline = Pipeline(_StubEstimator(), Calibration.identity())
    reader = _reader(pipeline)
    raw = _raw(range(8))                                      # t_s 100.0 .. 100.0 + 7 periods
    now = raw[3].t_s + 0.05 + 1e-6                            # samples 0..3 used more than LATE_AFTER_S late
    reader.process(unpack_block(pack(raw)), now)
    assert reader.counters.late_samples == 4


def test_samples_already_built_take_the_same_one_path():
    """A per-sample read or a replay's list (SampleBlock.of): calibrated and mounted as the formulas by hand say,
    the sensor-frame sample too, and the raw samples the vehicle log and a new calibration see are the source's
    own objects (not copies)."""
    cal = calibration(5)
    est = _StubEstimator()
    pipeline = Pipeline(est, cal)
    pipeline.set_mounting([0.0, 0.0, 90.0])
    c_mount = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])    # Rz(90°): body ← sensor
    logged, sensor_frame, raw_seen = [], [], []
    reader = _reader(pipeline, raw_sink=logged.append)
    reader.listeners.add(lambda s, e: (sensor_frame.append(pipeline.last_sensor_sample),
                                       raw_seen.append(pipeline.last_raw_sample)), in_place=True)
    raw = _raw(range(20, 27), seed=9)
    reader.process((raw[0],), 100.0)                          # the per-sample reader's call
    reader.process(raw[1:5], 100.0)                           # a replay's or a reader thread's list
    pipeline.process(raw[5])                                  # one sample straight into the pipeline
    pipeline.process(raw[6])
    assert [s.counter for s in est.seen] == list(range(20, 27))
    assert all(a is b for a, b in zip(logged, raw[:5])) and len(logged) == 5
    assert all(a is b for a, b in zip(raw_seen, raw[:5])) and pipeline.last_raw_sample is raw[6]
    for s, r in zip(est.seen, raw):
        for got, want in zip((s.gyro_rad_s, s.accel_m_s2, s.mag_ut), _by_hand(cal, r, c_mount)):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert (s.t_s, s.temp_c, s.supply_v, s.flags, s.counter) == (r.t_s, r.temp_c, r.supply_v, r.flags, r.counter)
    for sensor, r in zip(sensor_frame + [pipeline.last_sensor_sample], raw[:5] + [raw[6]]):
        for got, want in zip((sensor.gyro_rad_s, sensor.accel_m_s2, sensor.mag_ut), _by_hand(cal, r)):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert reader.health.last_sample_flags == raw[4].flags


# --- the counts, samples, late samples and listeners must not depend on how a sequence is cut into blocks
# (worked out one sample at a time: tests/support/sample_sequence.py): what any block-wise rewrite of the path must keep (docs/daemon.md
# "Performance", session 25)


def test_the_counts_are_those_of_one_sample_at_a_time_however_the_blocks_are_cut():
    samples = sequence()
    want = counted_one_by_one(samples)
    assert want == (60, 4, 13, 4)                            # the sequence's own figures (3 + 1 + 7 + 2 lost)
    for cuts in [[(k, k + 1) for k in range(60)], [(k, k + 4) for k in range(0, 60, 4)]] + \
            [block_cuts(60, seed) for seed in range(8)]:
        est = _StubEstimator()
        pipeline = Pipeline(est, Calibration.identity())
        reader = _reader(pipeline)
        done = 0
        for lo, hi in cuts:
            reader.process(unpack_block(pack(samples[lo:hi])), samples[hi - 1].t_s)
            done = hi
            c = pipeline.counters
            # after every block, the counts of its samples so far
            assert (c.samples, c.gaps, c.lost_samples, c.invalid_samples) == counted_one_by_one(samples[:done])
        # the estimator saw every sample as the source gave it (identity calibration), each flag as it was
        assert len(est.seen) == 60
        for got, want_s in zip(est.seen, samples):
            assert type(got) is ImuSample and type(got.flags) is SampleFlags
            assert (got.t_s, got.temp_c, got.supply_v, got.flags, got.diag_stat, got.counter) == \
                (want_s.t_s, want_s.temp_c, want_s.supply_v, want_s.flags, want_s.diag_stat, want_s.counter)
            for a, b in ((got.gyro_rad_s, want_s.gyro_rad_s), (got.accel_m_s2, want_s.accel_m_s2),
                         (got.mag_ut, want_s.mag_ut)):
                assert a.dtype == np.float64 and a.shape == (3,) and a.tobytes() == b.tobytes()


def test_late_samples_and_the_last_flags_follow_the_block_sample_by_sample():
    samples = sequence()
    pipeline = Pipeline(_StubEstimator(), Calibration.identity())
    reader = _reader(pipeline)
    late = 0
    for lo, hi in block_cuts(60, 3):
        now = samples[lo].t_s + LATE_AFTER_S + 1.5 / RATE_HZ      # the block's first two samples are late
        late += sum(1 for s in samples[lo:hi] if s.t_s < now - LATE_AFTER_S)
        reader.process(unpack_block(pack(samples[lo:hi])), now)
        assert reader.health.last_sample_flags == int(samples[hi - 1].flags)
    assert reader.counters.late_samples == late and late > 30


def test_unpacked_columns_are_the_records_fields():
    """Every field of every record, read independently through the record dtype, whatever the values (negative
    and large integers, NaN temperatures)."""
    samples = [dataclasses.replace(s, diag_stat=d, counter=c, temp_c=t)
               for s, d, c, t in zip(sequence()[:5], (0, -1, 2 ** 40, 7, 0x8000),
                                     (3, 2 ** 62, -5, 0, 11), (float("nan"), -40.0, 85.0, 0.0, 1e-300))]
    data = pack(samples)
    rec = np.frombuffer(data, dtype=_RECORD)
    block = unpack_block(data)
    assert len(block) == 5
    for name, col in (("t_s", block.t_s), ("temp_c", block.temp_c), ("supply_v", block.supply_v),
                      ("flags", block.flags), ("diag", block.diag_stat), ("counter", block.counter)):
        assert np.array_equal(np.asarray(col), rec[name], equal_nan=name == "temp_c"), name
        assert all(type(v) is type(rec[name][0].item()) for v in col), name
    want = np.concatenate([rec["gyro"], rec["accel"], rec["mag"]], axis=1)
    assert block.vectors.shape == (5, 9) and block.vectors.tobytes() == want.tobytes()
    assert block.vectors.flags.writeable and block.vectors.flags.c_contiguous
    empty = unpack_block(b"")
    assert len(empty) == 0 and empty.vectors.shape == (0, 9)


def test_a_listener_added_or_dropped_by_a_listener_takes_effect_from_the_next_sample():
    pipeline = Pipeline(_StubEstimator(), Calibration.identity())
    reader = _reader(pipeline)
    seen = {"a": [], "b": [], "c": []}

    def b(s, e):
        seen["b"].append(s.counter)

    def c(s, e):
        seen["c"].append(s.counter)

    def a(s, e):
        seen["a"].append(s.counter)
        if s.counter == 1003:
            reader.listeners.drop(b)                        # b is still called for this sample
            reader.listeners.add(c, in_place=True)          # c only from the next one

    reader.listeners.add(a, in_place=True)
    reader.listeners.add(b)
    samples = [dataclasses.replace(s, flags=F.NEW_DATA) for s in sequence()[:8]]    # counters 1001..1008
    reader.process(unpack_block(pack(samples)), samples[-1].t_s)
    assert seen == {"a": list(range(1001, 1009)), "b": [1001, 1002, 1003], "c": list(range(1004, 1009))}
