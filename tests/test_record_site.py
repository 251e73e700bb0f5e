"""`ahrsd record --sim --site/--iron`: the place reaches the simulated chip's field and the GNSS receiver's track,
the iron the vehicle's. The truth is independent of the simulator: the WMM2025 field at Tromsø straight from
pygeomag (its own coefficient file) and the unseen iron's numbers written here."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.cli.main import main

TROMSO_LAT_DEG, TROMSO_LON_DEG = 69.65, 18.96
UNSEEN_HARD_IRON_UT = np.array([-27.7, 31.9, 34.7])
UNSEEN_SOFT_IRON = np.array([[0.980, -0.085, -0.097], [-0.046, 1.066, 0.019], [0.028, -0.091, 0.996]])


def _wmm2025_dip_deg(lat_deg: float, lon_deg: float, alt_m: float, date: dt.date) -> float:
    """The field's inclination from pygeomag's WMM2025 (km, decimal year)."""
    from pygeomag import GeoMag

    start = dt.date(date.year, 1, 1)
    year = date.year + (date - start).days / (dt.date(date.year + 1, 1, 1) - start).days
    r = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0,
                                                               time=year)
    return float(np.degrees(np.arctan2(r.z, np.hypot(r.x, r.y))))


@pytest.mark.parametrize("place", ["69.65", "69.65,north", "69.65,18.96,0,2026-13-01", "95,18.96"])
def test_a_mistyped_place_is_a_usage_error_naming_the_option(tmp_path, capsys, place):
    out = tmp_path / "x.csv"
    with pytest.raises(SystemExit) as exc:
        main(["record", "--sim", "boat", "--seconds", "1", "-o", str(out), f"--site={place}"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --site" in err and ("LAT,LON" in err or "lat_deg" in err), err
    assert not out.exists()


def test_an_unknown_iron_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["record", "--sim", "boat", "--seconds", "1", "-o", str(tmp_path / "x.csv"), "--iron", "rusty"])
    assert exc.value.code == 2 and "argument --iron" in capsys.readouterr().err


def test_the_place_reaches_the_field_and_the_receiver_and_the_iron_the_vehicle(tmp_path):
    from ahrsd.drivers.gnss.recording import read_gnss_recording
    from ahrsd.drivers.recording import read_recording

    rec = tmp_path / "boat.csv"
    assert main(["record", "--sim", "boat", "--seconds", "3", "--seed", "11", "--errors", "ideal", "-q", "-o",
                 str(rec), f"--site={TROMSO_LAT_DEG},{TROMSO_LON_DEG}", "--iron", "unseen"]) == 0
    r = read_recording(rec)
    q_wxyz = np.column_stack([r.extra[c] for c in ("truth_qw", "truth_qx", "truth_qy", "truth_qz")])
    # raw = S · B_body + h: the field in the body from the unseen iron's numbers written here, then into NED
    b_body = (np.linalg.inv(UNSEEN_SOFT_IRON) @ (r.mag_ut - UNSEEN_HARD_IRON_UT).T).T
    b_ned = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]).apply(b_body).mean(axis=0)
    dip_deg = np.degrees(np.arctan2(b_ned[2], np.hypot(b_ned[0], b_ned[1])))
    # the place given without height or date: 0 m, the simulator's date (docs/simulation.md: 2026-01-01)
    expected = _wmm2025_dip_deg(TROMSO_LAT_DEG, TROMSO_LON_DEG, 0.0, dt.date(2026, 1, 1))
    assert dip_deg == pytest.approx(expected, abs=0.2)                 # ≈ 78°; the default site's ≈ 56°
    fixes = read_gnss_recording(rec.with_name("boat.gnss.csv"))
    assert fixes and all(abs(f.lat_deg - TROMSO_LAT_DEG) < 0.05 and abs(f.lon_deg - TROMSO_LON_DEG) < 0.05
                         for f in fixes)
