"""Chunked and gzip-compressed reading of recordings (drivers/recording.py): the same data as the whole-file
reader, a chunk at a time, and `.csv.gz` read transparently by every reader."""

from __future__ import annotations

import gzip
import shutil

import numpy as np
import pytest

from ahrsd.drivers.recording import (RecordingFormatError, RecordingWriter, iter_recording_chunks, iter_samples,
                                     read_recording)
from ahrsd.core.sample import make_sample


@pytest.fixture()
def recording(tmp_path):
    rng = np.random.default_rng(7)
    path = tmp_path / "r.csv"
    with RecordingWriter(path, extra_columns=("temp_c", "note")) as w:
        for k in range(1000):
            s = make_sample(k / 100.0, rng.normal(size=3), rng.normal(size=3), rng.normal(size=3) * 40)
            w.write(s, temp_c=20.0 + k * 1e-3, note=float(k % 7))
    return path


def _gzip(path):
    out = path.with_suffix(".csv.gz")
    with open(path, "rb") as src, gzip.open(out, "wb") as dst:
        shutil.copyfileobj(src, dst)
    return out


def test_chunks_concatenate_to_the_whole_recording(recording):
    whole = read_recording(recording)
    chunks = list(iter_recording_chunks(recording, chunk_rows=137))
    assert [len(c) for c in chunks] == [137] * 7 + [1000 - 7 * 137]
    assert all(c.columns == whole.columns for c in chunks)
    np.testing.assert_array_equal(np.concatenate([c.t_s for c in chunks]), whole.t_s)
    np.testing.assert_array_equal(np.concatenate([c.gyro_rad_s for c in chunks]), whole.gyro_rad_s)
    np.testing.assert_array_equal(np.concatenate([c.mag_ut for c in chunks]), whole.mag_ut)
    np.testing.assert_array_equal(np.concatenate([c["note"] for c in chunks]), whole["note"])


def test_gzip_recording_reads_like_the_plain_one(recording):
    packed = _gzip(recording)
    plain, unpacked = read_recording(recording), read_recording(packed)
    np.testing.assert_array_equal(unpacked.accel_m_s2, plain.accel_m_s2)
    np.testing.assert_array_equal(unpacked["temp_c"], plain["temp_c"])
    assert [s.t_s for s in iter_samples(packed)] == [s.t_s for s in iter_samples(recording)]
    np.testing.assert_array_equal(np.concatenate([c.gyro_rad_s for c in iter_recording_chunks(packed)]),
                                  plain.gyro_rad_s)


def test_chunked_reader_names_the_bad_line(recording, tmp_path):
    lines = recording.read_text().splitlines()
    lines[500] = lines[500].rsplit(",", 1)[0]            # one field short
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingFormatError, match="line 501"):
        for _ in iter_recording_chunks(bad, chunk_rows=64):
            pass
    with pytest.raises(RecordingFormatError, match="line 501"):
        read_recording(_gzip(bad))
