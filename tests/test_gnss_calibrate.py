"""`ahrsd calibrate mag --method backstepping --gnss`: the course reference (straight and fast enough only),
GNSS fixes offered to the levelling estimator in time order, usage errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.calibration.mag.backstepping_paper import BacksteppingError
from ahrsd.calibration.mag.levelling import attitude_from_estimator, roll_pitch_from_estimator
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.cli.calibrate_gnss import COURSE_MIN_SPEED_M_S, course_reference_deg
from ahrsd.cli.main import main
from ahrsd.core.gnss import make_fix
from support.fake_aided import WithoutLeverArmCheck


def fixes_of(t, course_deg, speed):
    c = np.radians(course_deg)
    return [make_fix(ti, 50.0, 5.0, 10.0, [v * math.cos(ci), v * math.sin(ci), 0.0])
            for ti, ci, v in zip(t, c, speed)]


def test_course_reference_only_on_fast_straight_tracks():
    t = np.arange(0.0, 120.0, 0.2)
    course = np.where(t < 40, 30.0, np.where(t < 60, 30.0 + 9.0 * (t - 40), 210.0))   # straight, turn, straight
    speed = np.where(t < 90, 3.0, 1.0)                                                  # then too slow
    at = np.arange(0.0, 120.0, 0.05)
    ref = course_reference_deg(fixes_of(t, course, speed), at)
    straight1 = (at > 6) & (at < 34)
    straight2 = (at > 66) & (at < 84)
    assert np.allclose(ref[straight1], 30.0) and np.allclose(ref[straight2], 210.0)
    assert np.all(np.isnan(ref[(at > 41) & (at < 59)]))                   # turning: course is not heading
    assert np.all(np.isnan(ref[at > 91]))                                 # below COURSE_MIN_SPEED_M_S
    assert COURSE_MIN_SPEED_M_S > 1.0


class Recorder(WithoutLeverArmCheck):
    """An aided estimator (estimator.base.GnssAidedEstimator) that records what it is offered, in order."""

    name = "recorder"

    def __init__(self):
        self.events = []
        self.gnss_counters = None

    def update_gnss(self, fix):
        self.events.append(("fix", fix.t_s))

    def update(self, sample):
        self.events.append(("sample", sample.t_s))
        return type("E", (), {"roll_rad": 0.1, "pitch_rad": -0.2, "sigma_rpy_rad": np.zeros(3)})()


def test_levelling_offers_the_fixes_in_time_order():
    rec = Recorder()
    t = np.arange(10) * 0.1
    data = MagFitInput(t, np.ones((10, 3)), np.ones((10, 3)), np.zeros((10, 3)))
    # on a sample's time (0.0, t[3]) the fix goes first; one after the last sample (0.95) is never offered
    fixes = fixes_of([0.0, 0.05, 0.25, t[3], 0.85, 0.95], [0] * 6, [1] * 6)
    roll, pitch, _ = attitude_from_estimator(data, "x", fixes=fixes, estimator=rec)
    want = sorted([("sample", x) for x in t] + [("fix", f.t_s) for f in fixes if f.t_s <= t[-1]],
                  key=lambda e: (e[1], e[0] != "fix"))
    assert rec.events == want and np.all(roll == 0.1) and np.all(pitch == -0.2)


def test_levelling_refuses_fixes_for_an_unaided_estimator():
    t = np.arange(10) * 0.1
    data = MagFitInput(t, np.ones((10, 3)), np.ones((10, 3)), np.zeros((10, 3)))
    with pytest.raises(BacksteppingError, match="takes no GNSS"):
        roll_pitch_from_estimator(data, "mekf", fixes=[])


def _a_recording(tmp_path):
    """A recording path that exists: `calibrate mag` says "no such file" before any usage error (the usage
    checks below run before the file is read, so its content does not matter)."""
    path = tmp_path / "x.csv"
    path.write_text("")
    return path


def test_gnss_needs_backstepping(tmp_path, ahrsd_inproc):
    res = ahrsd_inproc("mag", _a_recording(tmp_path), "--lat", "50", "--lon", "5", "--gnss", "x.gnss.csv", "--dry-run")
    assert res.returncode == 2 and "--gnss goes with --method backstepping" in res.stderr


def test_gnss_course_needs_gnss(tmp_path, ahrsd_inproc):
    res = ahrsd_inproc("mag", _a_recording(tmp_path), "--lat", "50", "--lon", "5", "--method", "backstepping",
                       "--gnss-course", "--dry-run")
    assert res.returncode == 2 and "--gnss-course needs --gnss" in res.stderr


def _first_seconds(csv_path, seconds: float):
    """A copy of a recording (IMU or GNSS CSV) holding its header and the rows with t_s < `seconds`."""
    lines = csv_path.read_text().splitlines(keepends=True)
    kept = [lines[0]] + [ln for ln in lines[1:] if float(ln.split(",", 1)[0]) < seconds]
    out = csv_path.with_name(f"first{seconds:g}s_{csv_path.name}")
    out.write_text("".join(kept))
    return out


def test_aided_levelling_on_a_boat(tmp_path, ahrsd_inproc):
    """The aided roll/pitch against the simulator's truth, and the CLI using it."""
    from scipy.spatial.transform import Rotation

    from ahrsd.calibration.mag.backstepping_aided import aided_roll_pitch
    from ahrsd.core.wmm import earth_field
    from ahrsd.drivers.gnss.recording import read_gnss_recording
    from ahrsd.drivers.recording import read_recording

    rec = tmp_path / "boat.csv"
    # at an eighth of the chip's default rate (SMPL_PRD 7): the recording's and the levelling's cost is per sample
    # in this process: no interpreter start and ahrsd import (the console script is test_recording's)
    assert main(["record", "--sim", "boat", "--seconds", "90", "--rate-hz", "102.4", "-o", str(rec), "--quiet"]) == 0
    r = read_recording(rec)
    data = MagFitInput(r.t_s, r.mag_ut, r.accel_m_s2, r.gyro_rad_s)
    roll, pitch, _, _ = aided_roll_pitch(data, read_gnss_recording(tmp_path / "boat.gnss.csv"),
                                         earth_field(36.42, 54.98).declination_rad)
    truth = Rotation.from_quat(np.column_stack([r.extra[c] for c in ("truth_qx", "truth_qy", "truth_qz",
                                                                      "truth_qw")])).as_euler("ZYX")
    late = r.t_s > 30.0

    def tilt_rms_deg(roll_rad, pitch_rad):
        roll_err = np.angle(np.exp(1j * (roll_rad - truth[:, 2])))[late]
        return np.degrees(np.sqrt(np.mean(roll_err ** 2 + (pitch_rad - truth[:, 1])[late] ** 2)))

    # what back-stepping levels with otherwise: the accelerometer low-passed at τ = 0.2 s (its default), whose
    # apparent vertical leans in the boat's turns and waves; the specific force → roll/pitch formula of ZYX Euler
    from scipy.ndimage import uniform_filter1d

    rate_hz = (len(r.t_s) - 1) / (r.t_s[-1] - r.t_s[0])
    acc = uniform_filter1d(r.accel_m_s2, size=int(0.4 * rate_hz), axis=0)
    accel_tilt = tilt_rms_deg(np.arctan2(-acc[:, 1], -acc[:, 2]),
                              np.arctan2(acc[:, 0], np.hypot(acc[:, 1], acc[:, 2])))
    aided_tilt = tilt_rms_deg(roll, pitch)
    print(f"tilt RMS after 30 s: aided {aided_tilt:.3f}°, accelerometer {accel_tilt:.3f}°")
    assert aided_tilt < 0.5 * accel_tilt, (aided_tilt, accel_tilt)
    # the CLI's own checks below are about its wiring (the levelling line, the rejections, the priors it passes),
    # not the levelling's accuracy checked above: the first 30 s of the same recording and receiver serve them
    rec, gnss = _first_seconds(rec, 30.0), _first_seconds(tmp_path / "boat.gnss.csv", 30.0)
    res = ahrsd_inproc("mag", rec, "--lat", "36.42", "--lon", "54.98", "--method", "backstepping", "--gnss",
                       gnss, "--dry-run", "--state-dir", tmp_path)
    # 30 s of this boat cover far less than a circle of heading: the fit refuses (a full circle needs longer),
    # after levelling, and says why
    assert res.returncode == 1 and "levelling: ins aided by" in res.stdout, res.stdout + res.stderr
    assert "REFUSED: the data cover " in res.stdout and "turn the vehicle through a full circle" in res.stdout
    assert "0 rejected" in res.stdout
    assert "WARNING: no accelerometer calibration" in res.stdout    # the state directory holds none
    # with an accelerometer calibration stored, the fit is told the bias prior (its JSON says what it got)
    import json

    from ahrsd.calibration.accel_trust import ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
    from ahrsd.calibration.models import AccelModel, Calibration
    from ahrsd.calibration.store import CalibrationStore

    CalibrationStore(tmp_path / "state").save(Calibration(accel=AccelModel(bias_m_s2=np.array([0.02, -0.01, 0.0]),
                                                                             matrix=np.eye(3))))
    res = ahrsd_inproc("mag", rec, "--lat", "36.42", "--lon", "54.98", "--method", "backstepping", "--gnss",
                       gnss, "--dry-run", "--state-dir", tmp_path / "state", "--json",
                       "--lever-arm-m", "0.1", "0", "-0.2")
    levelling = json.loads(res.stdout)["quality"]["aided_levelling"]
    assert levelling["accel_bias_sigma_m_s2"] == pytest.approx(ACCEL_BIAS_SIGMA_CALIBRATED_M_S2), levelling
    assert levelling["filter_overrides"] == {"lever_arm_m": [0.1, 0.0, -0.2]}, levelling   # the antenna's place


def test_the_levelling_bias_prior_follows_the_accelerometer_calibration(tmp_path):
    """--gnss: the aided levelling is told how well the accelerometer bias is known — the filter's own prior
    (and a warning) without a calibration, ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 with one, the operator's figure when
    given."""
    import argparse

    from ahrsd.calibration.accel_trust import ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
    from ahrsd.calibration.models import AccelModel, Calibration
    from ahrsd.cli.calibrate import _levelling_accel_bias_prior

    none = Calibration.identity()
    cal = Calibration(accel=AccelModel(bias_m_s2=np.array([0.05, -0.02, 0.01]), matrix=np.eye(3)))
    sigma, note = _levelling_accel_bias_prior(argparse.Namespace(accel_bias_sigma_mg=None), none)
    assert sigma is None and note.startswith("WARNING: no accelerometer calibration")
    sigma, note = _levelling_accel_bias_prior(argparse.Namespace(accel_bias_sigma_mg=None), cal)
    assert sigma == ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 and "accelerometer calibrated" in note
    assert "not aligned to the housing" in note and "--align-to-faces" in note
    aligned = Calibration(accel=cal.accel, metadata={"accel": {"face_alignment": {"rotation_deg": 0.1}}})
    sigma, note = _levelling_accel_bias_prior(argparse.Namespace(accel_bias_sigma_mg=None), aligned)
    assert sigma == ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 and "not aligned" not in note
    sigma, note = _levelling_accel_bias_prior(argparse.Namespace(accel_bias_sigma_mg=5.0), cal)
    assert sigma == pytest.approx(5e-3 * 9.80665) and "5 mg (given)" in note


@pytest.mark.parametrize("extra, message", [
    (["--accel-bias-sigma-mg", "2"], "--accel-bias-sigma-mg needs --gnss"),
    (["--gnss", "g.csv", "--accel-bias-sigma-mg", "0"], "expected 0 < MG"),
    (["--gnss", "g.csv", "--accel-bias-sigma-mg", "nan"], "expected 0 < MG"),
])
def test_accel_bias_sigma_usage(tmp_path, extra, message, ahrsd_inproc):
    res = ahrsd_inproc("mag", _a_recording(tmp_path), "--lat", "50", "--lon", "5", "--method", "backstepping",
                       "--dry-run", *extra)
    assert res.returncode == 2 and message in res.stderr, res.stderr


@pytest.mark.parametrize("extra, message", [
    (["--lever-arm-m", "0", "0", "-1"], "--lever-arm-m needs --gnss"),
    (["--gnss", "g.csv", "--lever-arm-m", "0", "0", "-101"], "expected three numbers in [-100, 100] m"),
    (["--gnss", "g.csv", "--lever-arm-m", "nan", "0", "0"], "expected three numbers"),
])
def test_lever_arm_usage(tmp_path, extra, message, ahrsd_inproc):
    res = ahrsd_inproc("mag", _a_recording(tmp_path), "--lat", "50", "--lon", "5", "--method", "backstepping",
                       "--dry-run", *extra)
    assert res.returncode == 2 and message in res.stderr, res.stderr


def test_the_reference_field_is_taken_at_the_recordings_position_without_lat_lon(tmp_path, ahrsd_inproc):
    """Without --lat/--lon, `--gnss` gives the site: the median of the recording's valid fixes (rows without a
    fix, placed a degree away, must not count), and the reference field is WMM2025's there (pygeomag called
    here, on the position computed here from the CSV's rows); --lat/--lon still override it."""
    import csv
    import json

    from pygeomag import GeoMag

    rec = tmp_path / "boat.csv"
    assert main(["record", "--sim", "boat", "--seconds", "20", "--rate-hz", "102.4", "-o", str(rec), "--quiet"]) == 0
    gnss = tmp_path / "boat.gnss.csv"
    with gnss.open() as f:
        rows = list(csv.DictReader(f))
    for row in rows[::5]:        # a receiver's no-fix rows: the last position it had, a degree off (and no height)
        lost = dict(row, t_s=f"{float(row['t_s']) + 0.1:.3f}", lat_deg=str(float(row["lat_deg"]) + 1.0),
                    lon_deg=str(float(row["lon_deg"]) - 1.0), alt_m="nan", fix_type="1")
        rows.append(lost)
    rows.sort(key=lambda r: float(r["t_s"]))
    with gnss.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    valid = [r for r in rows if int(r["fix_type"]) >= 2]
    lat, lon, alt = (float(np.median([float(r[k]) for r in valid])) for k in ("lat_deg", "lon_deg", "alt_m"))
    assert np.ptp([float(r["lat_deg"]) for r in valid]) > 2e-4      # the boat moves: first fix ≠ median
    truth = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=lat, glon=lon, alt=alt / 1000.0,
                                                                   time=2026.0 + 151 / 365)   # 2026-06-01

    res = ahrsd_inproc("mag", rec, "--method", "backstepping", "--gnss", gnss, "--date", "2026-06-01", "--dry-run",
                       "--state-dir", tmp_path / "state", "--json")
    out = json.loads(res.stdout)
    site = out["reference_site"]
    assert site["lat_deg"] == pytest.approx(lat, abs=1e-9) and site["lon_deg"] == pytest.approx(lon, abs=1e-9)
    assert site["alt_m"] == pytest.approx(alt, abs=1e-6) and "median" in site["source"]
    assert out["field_ut"] == pytest.approx(truth.f / 1000.0, abs=2e-3)      # WMM at the rounded 1e-4°, 1 m
    assert out["inclination_deg"] == pytest.approx(truth.i, abs=1e-3)
    text = ahrsd_inproc("mag", rec, "--method", "backstepping", "--gnss", gnss, "--date", "2026-06-01",
                        "--dry-run", "--state-dir", tmp_path / "state").stdout
    assert f"the median of the {len(valid)} GNSS fixes of {gnss}" in text, text

    res = ahrsd_inproc("mag", rec, "--method", "backstepping", "--gnss", gnss, "--date", "2026-06-01", "--dry-run",
                       "--state-dir", tmp_path / "state", "--json", "--lat", "-40", "--lon", "170")
    given = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=-40.0, glon=170.0, alt=0.0,
                                                                   time=2026.0 + 151 / 365)
    assert json.loads(res.stdout)["field_ut"] == pytest.approx(given.f / 1000.0, abs=2e-3)


@pytest.mark.parametrize("extra, message", [
    ((), "give --lat and --lon, or --gnss"),
    (("--lat", "50"), "give --lat and --lon together"),
    (("--lon", "5", "--method", "backstepping", "--gnss", "x.gnss.csv"), "give --lat and --lon together"),
])
def test_a_reference_field_needs_a_site(tmp_path, extra, message, ahrsd_inproc):
    res = ahrsd_inproc("mag", _a_recording(tmp_path), *extra, "--dry-run")
    assert res.returncode == 2 and message in res.stderr, res.stderr
