"""`ahrsd record --sim` writes beside each sample the truth attitude of that chip sample: the one the burst
returned. The simulated chip runs on a stepped clock that moves one sample period at every transfer, so while
the driver reads DIAG_STAT after a burst with EA set (an injected alarm) the chip produces the next sample —
the chip's truth after the read is then a later sample's. The expected truth comes from the scenario itself
(an independent simulation stream, indexed by the chip sample each burst returned, noted by this test's bus)."""

from __future__ import annotations

import numpy as np

from ahrsd.cli import record as record_cli
from ahrsd.cli.main import build_parser
from ahrsd.drivers.faults import FaultKind, FaultPlan
from ahrsd.drivers.recording import read_recording
from ahrsd.drivers.registers import GLOB_CMD
from ahrsd.drivers.source import open_chip_bus
from ahrsd.simulation import open_stream

from support.chip_bus import SimulatedChipBus

RATE_HZ = 819.2
SEED = 12
SECONDS = 5.5                 # 4506 rows: the last ~300 in the alarm, every third chip sample
ALARM_FROM_SAMPLE = 4200      # the rate table is turning from chip sample 4097 (5 s) on


class _SteppedClockChip(SimulatedChipBus):
    """The simulated chip on a clock that moves one sample period at each transfer, noting the chip's sample
    index right after each burst (the sample the burst returned)."""

    def __init__(self, **kw):
        self.now_s = 0.0
        plan = FaultPlan(seed=1)
        plan.add(FaultKind.ALARM, start_sample=ALARM_FROM_SAMPLE)    # every burst from there is followed by DIAG_STAT
        kw.update(clock=lambda: self.now_s, faults=plan)
        super().__init__(open_chip_bus("sim", **kw))
        self.burst_indices: list[int] = []

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        self.now_s += 1.0 / RATE_HZ
        rx = self.chip.transfer(tx, speed_hz, delay_us)
        if tx[0] == GLOB_CMD and tx[1] == 0:
            self.burst_indices.append(self.chip.sample_index)
        return rx


def test_each_row_has_the_truth_of_the_sample_its_burst_returned(tmp_path):
    out = tmp_path / "rec.csv"
    args = build_parser().parse_args(["record", "--sim", "rate-table", "--seed", str(SEED), "--seconds", str(SECONDS),
                                      "-o", str(out), "-q", "--no-self-test"])
    buses = []
    assert record_cli.run(args, open_bus=lambda kind, **kw: buses.append(_SteppedClockChip(**kw)) or buses[0]) == 0
    rec = read_recording(out)
    truth_written = np.column_stack([rec[c] for c in ("truth_qw", "truth_qx", "truth_qy", "truth_qz")])
    # the written rows are the bursts that returned a new sample: those whose chip index moved on
    indices = np.array(buses[0].burst_indices)
    fresh = indices[np.concatenate([[indices[0] >= 0], np.diff(indices) > 0])]
    assert len(fresh) == len(truth_written)
    stream_truth = open_stream("rate-table", rate_hz=buses[0].chip.sample_rate_hz, seed=SEED, errors="adis16405").next_block(
        int(fresh[-1]) + 1).truth_q_wxyz
    expected = stream_truth[fresh]
    late = fresh >= ALARM_FROM_SAMPLE
    assert late.sum() > 100                     # rows read with DIAG_STAT after their burst
    # ... while the table turns: the chip's truth after that read (two samples on) is another attitude
    assert np.abs(stream_truth[fresh[late][:-1] + 2] - expected[late][:-1]).max(axis=1).min() > 1e-5
    assert np.abs(truth_written - expected).max() < 1e-12
