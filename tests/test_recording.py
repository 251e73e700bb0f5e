"""The CSV recording format (a public interface): exact header, round trip, clear errors for bad files."""

import subprocess
import sys

import numpy as np
import pytest

from ahrsd.drivers.recording import (RECORDING_HEADER, TRUTH_COLUMNS, RecordingFormatError, RecordingWriter,
                                     iter_samples, read_recording)
from ahrsd.core.sample import SampleFlags, make_sample

HEADER = ("t_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
          "mag_x_ut,mag_y_ut,mag_z_ut")


def random_samples(n, seed=0):
    rng = np.random.default_rng(seed)
    flags = [SampleFlags.NEW_DATA, SampleFlags.NEW_DATA | SampleFlags.ALARM | SampleFlags.GYRO_SATURATED]
    return [make_sample(k / 819.2, rng.normal(size=3), rng.normal(size=3) * 9.8, rng.normal(size=3) * 50,
                        temp_c=25 + rng.normal(), supply_v=5.0, flags=flags[k % 2], counter=k) for k in range(n)]


def test_header_is_exactly_the_public_one():
    assert RECORDING_HEADER == HEADER


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "r.csv"
    samples = random_samples(500)
    quats = np.random.default_rng(1).normal(size=(500, 4))
    with RecordingWriter(path, extra_columns=("temp_c", "supply_v", "flags", "counter") + TRUTH_COLUMNS) as w:
        for s, q in zip(samples, quats):
            w.write(s, truth_q_wxyz=q)
    assert path.read_text().splitlines()[0] == HEADER + ",temp_c,supply_v,flags,counter," + ",".join(TRUTH_COLUMNS)
    r = read_recording(path)
    assert len(r) == 500
    assert np.array_equal(r.t_s, [s.t_s for s in samples])
    assert np.array_equal(r.gyro_rad_s, [s.gyro_rad_s for s in samples])
    assert np.array_equal(r.accel_m_s2, [s.accel_m_s2 for s in samples])
    assert np.array_equal(r.mag_ut, [s.mag_ut for s in samples])
    assert np.array_equal(r["temp_c"], [s.temp_c for s in samples])
    assert np.array_equal(r["gyro_y_rad_s"], r.gyro_rad_s[:, 1])
    assert np.array_equal(r.truth_q_wxyz, quats)
    assert r.sample_rate_hz == pytest.approx(819.2)
    back = list(iter_samples(path))
    assert len(back) == 500
    for a, b in zip(samples, back):
        assert a.t_s == b.t_s and a.flags == b.flags and a.counter == b.counter and a.temp_c == b.temp_c
        assert np.array_equal(a.gyro_rad_s, b.gyro_rad_s) and np.array_equal(a.mag_ut, b.mag_ut)
    assert [s.flags for s in r.samples()] == [s.flags for s in samples]


def test_foreign_file_with_only_the_base_columns_and_unknown_extras(tmp_path):
    path = tmp_path / "other.csv"
    path.write_text("\ufeff" + HEADER + ",baro_pa\r\n0.0,0,0,0,0,0,-9.81,20,0,45,101325\r\n"
                    "# a comment line\r\n0.01,1e-3,0,0,0,0,-9.81,20,0,45,nan\r\n")
    r = read_recording(path)
    assert len(r) == 2 and np.isnan(r["baro_pa"][1]) and r.accel_m_s2[0, 2] == -9.81
    s = list(iter_samples(path))
    assert s[1].gyro_rad_s[0] == 1e-3 and s[1].flags == SampleFlags.NONE and s[1].counter == 1
    assert r.truth_q_wxyz is None


@pytest.mark.parametrize("header, message", [
    ("", "empty"),
    ("t,gyro_x_rad_s", "column 1 is 't' but must be 't_s'"),
    (HEADER.replace("gyro_z_rad_s", "gyro_z"), "column 4 is 'gyro_z' but must be 'gyro_z_rad_s'"),
    (HEADER.rsplit(",", 2)[0], "missing: mag_y_ut, mag_z_ut"),
    (HEADER + ",temp_c,temp_c", "repeats column"),
    (HEADER + ",,x", "empty column name"),
])
def test_bad_headers_are_named(tmp_path, header, message):
    path = tmp_path / "bad.csv"
    path.write_text(header + ("\n" if header else ""))
    with pytest.raises(RecordingFormatError, match=message):
        read_recording(path)


def test_truncated_row_and_non_numeric_value(tmp_path):
    path = tmp_path / "t.csv"
    good = "0.0,0,0,0,0,0,-9.81,20,0,45\n"
    path.write_text(HEADER + "\n" + good * 3 + "0.1,0,0,0,0\n" + good)
    with pytest.raises(RecordingFormatError, match=r"line 5: 5 fields, expected 10"):
        read_recording(path)
    path.write_text(HEADER + "\n" + good * 2 + "0.1,0,abc,0,0,0,-9.81,20,0,45\n")
    with pytest.raises(RecordingFormatError, match=r"line 4, column 'gyro_y_rad_s': 'abc' is not a number"):
        read_recording(path)
    with pytest.raises(RecordingFormatError):
        list(iter_samples(path))


def test_killed_recorder_last_line(tmp_path):
    path = tmp_path / "k.csv"
    path.write_text(HEADER + "\n" + "0.0,0,0,0,0,0,-9.81,20,0,45\n" * 2 + "0.2,0,0,0,0,0,-9.")
    with pytest.raises(RecordingFormatError, match="line 4"):
        read_recording(path)
    assert len(read_recording(path, strict=False)) == 2


def test_chunked_reading_keeps_line_numbers(tmp_path):
    path = tmp_path / "c.csv"
    rows = [f"{k / 100},0,0,0,0,0,-9.81,20,0,45\n" for k in range(30)]
    rows[20] = "0.2,0,0,x,0,0,-9.81,20,0,45\n"
    path.write_text(HEADER + "\n" + "".join(rows))
    with pytest.raises(RecordingFormatError, match="line 22"):      # in the 3rd chunk of 7 rows
        read_recording(path, chunk_rows=7)
    with pytest.raises(RecordingFormatError, match="line 22"):
        list(iter_samples(path, chunk_rows=7))
    rows[20] = "0.2,0,0,0,0,0,-9.81,20,0,45\n"
    path.write_text(HEADER + "\n" + "".join(rows))
    assert len(read_recording(path, chunk_rows=7)) == 30 == len(list(iter_samples(path, chunk_rows=7)))


def test_samples_without_a_counter_column_count_rows_across_chunks(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text(HEADER + ",flags\n" + "".join(f"{k / 100},0,0,0,0,0,-9.81,20,0,45,{k % 3}\n" for k in range(30)))
    samples = list(iter_samples(path, chunk_rows=7))
    assert [s.counter for s in samples] == list(range(30))
    assert [int(s.flags) for s in samples] == [k % 3 for k in range(30)]
    assert all(s.gyro_rad_s.shape == (3,) and s.mag_ut[2] == 45.0 for s in samples)


def test_writer_rejects_bad_extra_columns(tmp_path):
    with pytest.raises(ValueError):
        RecordingWriter(tmp_path / "x.csv", extra_columns=("t_s",))
    with pytest.raises(ValueError):
        RecordingWriter(tmp_path / "x.csv", extra_columns=("a,b",))


def test_record_command_simulated(tmp_path):
    out = tmp_path / "x.csv"
    proc = subprocess.run([sys.executable, "-m", "ahrsd.cli", "record", "--sim", "static", "--seconds", "2",
                           "--output", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "wrote 1638 samples" in proc.stderr
    r = read_recording(out)
    assert len(r) == 1638 and r.columns[:10] == tuple(HEADER.split(","))
    assert r.truth_q_wxyz is not None and np.allclose(np.linalg.norm(r.truth_q_wxyz, axis=1), 1.0)
    assert np.all(np.diff(r.t_s) > 0) and r.sample_rate_hz == pytest.approx(819.2, rel=1e-3)
    assert np.all(r["flags"].astype(int) & SampleFlags.NEW_DATA)
    assert r.accel_m_s2[:, 2].mean() == pytest.approx(-9.81, abs=0.2)


def test_record_command_errors_are_clear(tmp_path, capsys, monkeypatch):
    from ahrsd.cli.main import main

    assert main(["record", "--sim", "no-such-scenario", "--output", str(tmp_path / "a.csv"), "--seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert "unknown scenario" in err and "rate-table" in err
    monkeypatch.setitem(sys.modules, "spidev", None)          # as on a machine without the spi extra
    assert main(["record", "--spi", "/dev/spidev-none", "--output", str(tmp_path / "b.csv"), "--seconds", "1"]) == 1
    assert f"{sys.executable} -m pip install 'spidev>=3.6'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["record", "--output", str(tmp_path / "c.csv")])
    assert info.value.code == 2 and "--sim" in capsys.readouterr().err
    assert main(["record", "--sim", "--seconds", "-1", "--output", str(tmp_path / "d.csv")]) == 2


from hypothesis import given, settings, strategies as st  # noqa: E402

finite = st.floats(allow_nan=False, width=64)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(st.lists(st.lists(finite, min_size=10, max_size=10), min_size=1, max_size=20))
def test_round_trip_property(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("rt") / "p.csv"
    with RecordingWriter(path) as w:
        for r in rows:
            w.write(make_sample(r[0], r[1:4], r[4:7], r[7:10]))
    rec = read_recording(path)
    assert np.array_equal(np.column_stack([rec.t_s, rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut]), np.array(rows))


def test_rows_all_one_field_short_are_refused_not_recut(tmp_path):
    """Ten 9-field rows hold 90 numbers = nine 10-field rows: the reader must refuse, not reshape."""
    from ahrsd.drivers.recording import RECORDING_HEADER, RecordingFormatError, read_recording

    path = tmp_path / "short.csv"
    rows = [",".join(str(float(k + j)) for j in range(9)) for k in range(10)]
    path.write_text(RECORDING_HEADER + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(RecordingFormatError, match="9 fields, expected 10"):
        read_recording(path)


@pytest.mark.parametrize("sim_option", [["--seed", "0"], ["--errors", "ideal"], ["--realtime"],
                                        ["--site", "69.65,18.96"], ["--iron", "unseen"]])
def test_record_spi_refuses_simulation_options(tmp_path, capsys, sim_option):
    from ahrsd.cli import record
    from ahrsd.cli.main import build_parser

    opened = []
    out = tmp_path / "spi.csv"
    args = build_parser().parse_args(["record", "--spi", "/dev/spidev0.0", *sim_option, "--output", str(out),
                                      "--seconds", "1"])
    assert record.run(args, open_bus=lambda kind, **options: opened.append(kind) or 1 / 0) == 2
    err = capsys.readouterr().err
    assert sim_option[0] in err and "--sim" in err
    assert not opened and not out.exists()           # refused before the bus is opened or the file created


def test_record_sim_options_still_apply(tmp_path):
    from ahrsd.cli.main import main

    def record(*options):
        out = tmp_path / f"r{len(list(tmp_path.iterdir()))}.csv"
        assert main(["record", "--sim", "static", "--seconds", "0.05", "-q", "--output", str(out), *options]) == 0
        return read_recording(out)

    default, seed0, seed7, ideal = record(), record("--seed", "0"), record("--seed", "7"), record("--errors", "ideal")
    assert np.array_equal(default.gyro_rad_s, seed0.gyro_rad_s)        # the default seed is 0
    assert not np.array_equal(default.gyro_rad_s, seed7.gyro_rad_s)
    assert np.std(ideal.gyro_rad_s, axis=0).max() < np.std(default.gyro_rad_s, axis=0).max()   # no sensor noise
