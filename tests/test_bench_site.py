"""The honest-heading benches' `--site` / `--iron`: a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" and the unseen iron reach
the simulator. The truth is independent of the code under test: the field's dip at Tromsø (≈ 78°, published
WMM/IGRF maps; the default site dips ≈ 56°, the held-out one ≈ −64°) and the unseen iron's numbers written here."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.heading_timeline import main as heading_timeline_main
from bench.vehicle_accuracy import honesty_site, simulate_vehicle

TROMSO = "69.65,18.96"
UNSEEN_HARD_IRON_UT = np.array([-27.7, 31.9, 34.7])
UNSEEN_SOFT_IRON = np.array([[0.980, -0.085, -0.097], [-0.046, 1.066, 0.019], [0.028, -0.091, 0.996]])


def _field_ned_ut(run, mag_ut) -> np.ndarray:
    """Each sample's magnetometer reading turned into NED by the simulator's true attitude (body → NED)."""
    return Rotation.from_quat(run.truth_q_wxyz[:, [1, 2, 3, 0]]).apply(mag_ut)


def test_the_named_sites_resolve_as_before_and_a_place_takes_the_held_out_iron():
    assert honesty_site("held-out") == ("-33.87,151.21,40,2026-09-01", "held-out")
    assert honesty_site("default") == (None, "default")
    assert honesty_site(TROMSO) == (TROMSO, "held-out")
    assert honesty_site("held-out", "unseen") == ("-33.87,151.21,40,2026-09-01", "unseen")
    with pytest.raises(ValueError):
        honesty_site("69.65")            # no longitude
    with pytest.raises(ValueError):
        honesty_site(TROMSO, "rusty")


QUICK_ACCURACY = ["--vehicles", "--quick", "--vehicle-scenarios", "boat", "--vehicle-seeds", "1"]


@pytest.mark.parametrize("bench, argv", [("heading_timeline", ["--site", "69.65,north", "--seeds", "11"]),
                                         ("daemon_heading", ["--site", "69.65,north"]),
                                         ("honesty_spread", ["--site", "69.65,north", "--seeds", "11"]),
                                         ("accuracy", [*QUICK_ACCURACY, "--honesty-site", "69.65,north"])])
def test_a_mistyped_place_is_a_usage_error_before_any_run(bench, argv):
    main = heading_timeline_main if bench == "heading_timeline" else importlib.import_module(f"bench.{bench}").main
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_a_place_and_the_unseen_iron_reach_the_simulator():
    site, iron = honesty_site(TROMSO, "unseen")
    calibrated = simulate_vehicle("boat", 3.0, 11, site, mag="calibrated", iron=iron)
    b = _field_ned_ut(calibrated, calibrated.mag_ut).mean(axis=0)
    dip_deg = np.degrees(np.arctan2(b[2], np.hypot(b[0], b[1])))
    assert dip_deg == pytest.approx(78.4, abs=1.0)
    assert np.hypot(b[0], b[1]) == pytest.approx(10.8, abs=1.0)        # the weak horizontal field up there
    # the raw field is the unseen iron's: raw = S · B_body + h (+ the sensor's own < 1 µT / 1 % errors)
    raw = simulate_vehicle("boat", 3.0, 11, site, mag="uncalibrated", iron=iron)
    b_body = Rotation.from_quat(raw.truth_q_wxyz[:, [1, 2, 3, 0]]).inv().apply(b)
    hard_ut = (raw.mag_ut - b_body @ UNSEEN_SOFT_IRON.T).mean(axis=0)
    np.testing.assert_allclose(hard_ut, UNSEEN_HARD_IRON_UT, atol=2.0)


def test_the_daemon_benchs_place_and_iron_reach_the_recording_it_replays(tmp_path):
    """bench/daemon_heading.py --site/--iron: the recording `ahrsd run --replay` reads (through the simulated chip)
    and its GNSS file are at the place, with the unseen iron."""
    from ahrsd.drivers.gnss.recording import read_gnss_recording
    from ahrsd.drivers.recording import read_recording
    from bench.daemon_heading import record_boat

    rec = tmp_path / "boat.csv"
    record_boat(rec, 2.0, 11, TROMSO, "unseen")
    r = read_recording(rec)
    q_wxyz = np.column_stack([r.extra[c] for c in ("truth_qw", "truth_qx", "truth_qy", "truth_qz")])
    # raw = S · B_body + h: the field in the body from the unseen iron's numbers written here, then into NED
    b_body = (np.linalg.inv(UNSEEN_SOFT_IRON) @ (r.mag_ut - UNSEEN_HARD_IRON_UT).T).T
    b = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]).apply(b_body).mean(axis=0)
    assert np.degrees(np.arctan2(b[2], np.hypot(b[0], b[1]))) == pytest.approx(78.4, abs=1.5)
    assert np.hypot(b[0], b[1]) == pytest.approx(10.8, abs=1.5)
    fixes = read_gnss_recording(rec.with_name("boat.gnss.csv"))
    assert fixes and all(abs(f.lat_deg - 69.65) < 0.1 and abs(f.lon_deg - 18.96) < 0.1 for f in fixes)


def test_the_daemon_benchs_own_recording_at_the_default_site_and_iron_is_ahrsd_records(tmp_path):
    """At the default site with the default iron (the boat scenario's own) the bench's recording is byte for byte
    what `ahrsd record --sim boat` writes: the place and the iron are all that --site / --iron change."""
    from ahrsd.cli.main import main as ahrsd_main
    from bench.daemon_heading import record_boat

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    assert ahrsd_main(["record", "--sim", "boat", "--seconds", "2", "--seed", "12", "-o", str(tmp_path / "a/boat.csv"),
                       "--quiet"]) == 0
    record_boat(tmp_path / "b/boat.csv", 2.0, 12, None, "default")
    for name in ("boat.csv", "boat.gnss.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
