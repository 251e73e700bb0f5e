"""GNSS recording CSV: round trip, .csv.gz, optional columns in any subset, malformed files named by line."""

import gzip
import math

import numpy as np
import pytest

from ahrsd.core.gnss import DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, DEFAULT_V_ACC_M, GnssFixType, make_fix
from ahrsd.drivers.gnss.recording import (GNSS_RECORDING_HEADER, GnssRecordingFormatError, GnssRecordingWriter,
                                          gnss_path_for, read_gnss_recording)

BASE = "t_s,lat_deg,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s"


def _fixes():
    return [make_fix(10.0 + 0.2 * k, 47.0 + 1e-6 * k, -122.5 - 2e-6 * k, 100.0 + k, [1.5, -2.25, 0.125 * k],
                     h_acc_m=1.2, v_acc_m=2.4, s_acc_m_s=0.07, fix_type=GnssFixType.RTK_FLOAT, num_sats=11,
                     hdop=0.8, extra={"speed_gt": 3.0 + k})
            for k in range(5)]


def test_header_is_the_public_one():
    assert GNSS_RECORDING_HEADER == BASE


@pytest.mark.parametrize("name", ["rec.gnss.csv", "rec.gnss.csv.gz"])
def test_round_trip(tmp_path, name):
    path = tmp_path / name
    with GnssRecordingWriter(path, extra_columns=("speed_gt",)) as w:
        for f in _fixes():
            w.write(f)
    if name.endswith(".gz"):
        with gzip.open(path, "rt") as f:                     # really gzip, header first
            assert f.readline().startswith(BASE + ",h_acc_m,v_acc_m,s_acc_m_s,fix_type")
    back = read_gnss_recording(path)
    assert len(back) == 5
    for a, b in zip(_fixes(), back):
        assert (b.t_s, b.lat_deg, b.lon_deg, b.alt_m) == (a.t_s, a.lat_deg, a.lon_deg, a.alt_m)
        np.testing.assert_array_equal(b.vel_ned_m_s, a.vel_ned_m_s)
        assert (b.h_acc_m, b.v_acc_m, b.s_acc_m_s, b.fix_type, b.num_sats, b.hdop) == (1.2, 2.4, 0.07,
                                                                                    GnssFixType.RTK_FLOAT, 11, 0.8)
        assert b.extra["speed_gt"] == a.extra["speed_gt"]


def test_base_columns_only_take_documented_defaults(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text(BASE + "\n1.0,47.5,8.25,500.0,1.0,2.0,nan\n# a comment\n1.2,47.5,8.25,500.0,1.0,2.0,\n")
    fixes = read_gnss_recording(path)
    assert len(fixes) == 2
    f = fixes[0]
    assert (f.h_acc_m, f.v_acc_m, f.s_acc_m_s) == (2.1, 4.4, 0.074) == (DEFAULT_H_ACC_M, DEFAULT_V_ACC_M,
                                                                      DEFAULT_S_ACC_M_S)
    assert f.fix_type == GnssFixType.FIX_3D and f.num_sats == -1
    assert math.isnan(f.vel_ned_m_s[2]) and math.isnan(fixes[1].vel_ned_m_s[2])


def test_optional_columns_in_any_subset_and_order(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text(BASE + ",num_sats,s_acc_m_s,fix_type\n1.0,47.5,8.25,500.0,1.0,2.0,0.5,7,0.3,2\n"
                    "2.0,47.5,8.25,500.0,1.0,2.0,0.5,,nan,\n")
    a, b = read_gnss_recording(path)
    assert (a.num_sats, a.s_acc_m_s, a.fix_type, a.h_acc_m, a.v_acc_m) == (7, 0.3, GnssFixType.FIX_2D, 2.1, 4.4)
    assert (b.num_sats, b.s_acc_m_s, b.fix_type) == (-1, 0.074, GnssFixType.FIX_3D)


@pytest.mark.parametrize("header, what", [
    ("", "line 1: empty"),
    ("t_s,lat_deg,lon_deg,alt_m,vel_n_m_s,vel_e_m_s", "missing: vel_d_m_s"),
    ("t_s,lat,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s", "column 2 is 'lat'"),
    (BASE + ",h_acc_m,h_acc_m", "unique and non-empty: 'h_acc_m'"),
    (BASE + ",,h_acc_m", "unique and non-empty: an empty name"),
])
def test_bad_header(tmp_path, header, what):
    path = tmp_path / "g.csv"
    path.write_text(header + "\n")
    with pytest.raises(GnssRecordingFormatError, match="line 1") as exc:
        read_gnss_recording(path)
    assert what in str(exc.value)


@pytest.mark.parametrize("row, what", [
    ("1.0,47.5,8.25,500.0,1.0,2.0", "line 3: 6 fields, expected 7"),
    ("1.0,47.5,eight,500.0,1.0,2.0,0.0", "line 3, column 'lon_deg': 'eight' is not a number"),
])
def test_bad_row_names_the_line(tmp_path, row, what):
    path = tmp_path / "g.csv"
    path.write_text(BASE + "\n0.8,47.5,8.25,500.0,1.0,2.0,0.0\n" + row + "\n")
    with pytest.raises(GnssRecordingFormatError) as exc:
        read_gnss_recording(path)
    assert what in str(exc.value)


def test_bad_fix_type_and_num_sats(tmp_path):
    path = tmp_path / "g.csv"
    path.write_text(BASE + ",fix_type\n1.0,47.5,8.25,500.0,1.0,2.0,0.0,9\n")
    with pytest.raises(GnssRecordingFormatError, match="line 2, column 'fix_type': 9 is not a fix type"):
        read_gnss_recording(path)
    path.write_text(BASE + ",num_sats\n1.0,47.5,8.25,500.0,1.0,2.0,0.0,7.5\n")
    with pytest.raises(GnssRecordingFormatError, match="line 2, column 'num_sats'.*not an integer"):
        read_gnss_recording(path)


def test_not_gzip_with_gz_name(tmp_path):
    path = tmp_path / "g.csv.gz"
    path.write_text(BASE + "\n")
    with pytest.raises(GnssRecordingFormatError, match="cannot read"):
        read_gnss_recording(path)


def test_gnss_path_beside_the_imu_recording(tmp_path):
    assert gnss_path_for(tmp_path / "boat.csv") == tmp_path / "boat.gnss.csv"
    assert gnss_path_for("run/boat.csv.gz").as_posix() == "run/boat.gnss.csv.gz"
    assert gnss_path_for("boat").as_posix() == "boat.gnss.csv"
