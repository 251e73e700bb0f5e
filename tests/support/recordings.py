"""Write a simulated block to a recording file (the format `ahrsd record` writes), for tests that hand the CLI a
recording of a known motion."""

from __future__ import annotations

from pathlib import Path

from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter


def write_block(path: Path, block, *, with_truth: bool = False) -> Path:
    """One row per sample of `block` (a simulation block) at its own time stamps; `with_truth` adds the
    simulator's attitude as the truth_q* columns."""
    with RecordingWriter(path, extra_columns=TRUTH_COLUMNS if with_truth else ()) as w:
        for i in range(len(block)):
            sample = make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i])
            w.write(sample, truth_q_wxyz=block.truth_q_wxyz[i] if with_truth else None)
    return Path(path)
