"""The reader process's blocks through the daemon's per-sample path (drivers.process_source `unpack_block`,
daemon.pipeline `process_block`, daemon.sample_reader `process`) against the per-sample rules worked out here
one sample at a time: the counts (gaps, lost, invalid), the samples the estimator sees, the late samples and
what the listeners see must not depend on how the sequence is cut into blocks. What a block-wise rewrite of
that path must keep (docs/daemon.md "Performance", session 25)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ahrsd.calibration.models import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.health import Health
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.daemon.sample_reader import LATE_AFTER_S, ReaderOutputs, SampleListeners, SampleReader
from ahrsd.drivers.process_source import _RECORD, pack, unpack_block

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


def _sequence() -> list[ImuSample]:
    """A recorded-like sequence: 60 samples with lost ones (counter jumps flagged GAP_BEFORE, one at a block's
    first row and one in a block of its own), each invalid flag alone in a block, the chip's other flags
    (ALARM with a DIAG_STAT, STALE, saturation, the burst bug recovered), and clean stretches between."""
    rng = np.random.default_rng(4)
    flags = [F.NEW_DATA] * 60
    jumps = {8: 3, 21: 1, 40: 7}                 # index: samples lost before it
    for k in jumps:
        flags[k] |= F.GAP_BEFORE
    flags[13] |= F.MAG_INVALID
    flags[26] |= F.ACCEL_INVALID
    flags[33] |= F.GYRO_INVALID
    flags[47] |= F.GYRO_INVALID | F.ACCEL_INVALID | F.MAG_INVALID | F.GAP_BEFORE
    jumps[47] = 2
    flags[15] = F.STALE
    flags[17] |= F.ALARM
    flags[30] |= F.GYRO_SATURATED | F.BURST_BUG_RECOVERED
    out, counter = [], 1000
    for k, f in enumerate(flags):
        counter += 1 + jumps.get(k, 0)
        out.append(ImuSample(50.0 + counter / RATE_HZ, rng.normal(0, 0.5, 3), rng.normal([0, 0, -9.8], 1.0),
                             rng.normal([20, 0, 40], 3.0), 25.0 + 0.01 * k, 5.0 - 1e-3 * k, f,
                             0x40 if f & F.ALARM else 0, counter))
    return out


def _counted_one_by_one(samples: list[ImuSample]) -> tuple[int, int, int, int]:
    """(samples, gaps, lost, invalid) by the rules of PipelineCounters, one sample at a time."""
    gaps = lost = invalid = 0
    last = None
    for s in samples:
        if s.flags & F.GAP_BEFORE:
            gaps += 1
            if last is not None and s.counter > last + 1:
                lost += s.counter - last - 1
        if s.flags & (F.GYRO_INVALID | F.ACCEL_INVALID | F.MAG_INVALID):
            invalid += 1
        last = s.counter
    return len(samples), gaps, lost, invalid


def _reader(pipeline):
    return SampleReader(None, pipeline, Health(stale_timeout_s=0.1), ServiceCounters(), SampleListeners(),
                        ReaderOutputs(publish=lambda now: None, statustext=lambda sev, text: None,
                                      heading_reset=lambda: None, ready=lambda: None), poll_hz=200.0)


def _cuts(n: int, seed: int) -> list[tuple[int, int]]:
    rng = np.random.default_rng(seed)
    out, k = [], 0
    while k < n:
        size = int(rng.integers(1, 8))
        out.append((k, min(n, k + size)))
        k += size
    return out


def test_the_counts_are_those_of_one_sample_at_a_time_however_the_blocks_are_cut():
    samples = _sequence()
    want = _counted_one_by_one(samples)
    assert want == (60, 4, 13, 4)                            # the sequence's own figures (3 + 1 + 7 + 2 lost)
    for cuts in [[(k, k + 1) for k in range(60)], [(k, k + 4) for k in range(0, 60, 4)]] + \
            [_cuts(60, seed) for seed in range(8)]:
        est = _StubEstimator()
        pipeline = Pipeline(est, Calibration.identity())
        reader = _reader(pipeline)
        done = 0
        for lo, hi in cuts:
            reader.process(unpack_block(pack(samples[lo:hi])), samples[hi - 1].t_s)
            done = hi
            c = pipeline.counters
            # after every block, the counts of its samples so far
            assert (c.samples, c.gaps, c.lost_samples, c.invalid_samples) == _counted_one_by_one(samples[:done])
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
    samples = _sequence()
    pipeline = Pipeline(_StubEstimator(), Calibration.identity())
    reader = _reader(pipeline)
    late = 0
    for lo, hi in _cuts(60, 3):
        now = samples[lo].t_s + LATE_AFTER_S + 1.5 / RATE_HZ      # the block's first two samples are late
        late += sum(1 for s in samples[lo:hi] if s.t_s < now - LATE_AFTER_S)
        reader.process(unpack_block(pack(samples[lo:hi])), now)
        assert reader.health.last_sample_flags == int(samples[hi - 1].flags)
    assert reader.counters.late_samples == late and late > 30


def test_unpacked_columns_are_the_records_fields():
    """Every field of every record, read independently through the record dtype, whatever the values (negative
    and large integers, NaN temperatures)."""
    samples = [dataclasses.replace(s, diag_stat=d, counter=c, temp_c=t)
               for s, d, c, t in zip(_sequence()[:5], (0, -1, 2 ** 40, 7, 0x8000),
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
    samples = [dataclasses.replace(s, flags=F.NEW_DATA) for s in _sequence()[:8]]    # counters 1001..1008
    reader.process(unpack_block(pack(samples)), samples[-1].t_s)
    assert seen == {"a": list(range(1001, 1009)), "b": [1001, 1002, 1003], "c": list(range(1004, 1009))}
