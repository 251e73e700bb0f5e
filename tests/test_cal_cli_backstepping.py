"""`ahrsd calibrate mag --method backstepping` end to end: the recording's heading_ref_deg column, --swing-table,
--plot (and a clear exit 2 without matplotlib), on a simulated boat whose IMU is mounted 4° off the hull axis.

No magnetometer-only fit can see that 4°: the recording's field is consistent with any yaw of the sensor. A
heading reference (a true-heading column, or a compass-swing table) must remove it."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag import backstepping as bs
from ahrsd.cli.plots import backstepping as bsplot
from ahrsd.calibration.mag import backstepping_paper as paper
from ahrsd.calibration.mag import swing
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.models import MagModel
from ahrsd.calibration.store import load_calibration_file
from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter
from ahrsd.core.sample import make_sample
from ahrsd.core.wmm import earth_field
from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate
from ahrsd.core.angles import wrap_180_deg

SITE = DEFAULT_SITE
SITE_ARGS = ["--lat", str(SITE.lat_deg), "--lon", str(SITE.lon_deg), "--alt-m", str(SITE.alt_m),
             "--date", SITE.date.isoformat()]
HULL_OFFSET_DEG = 4.0   # hull heading = IMU body heading + 4° (the IMU is mounted yawed 4° off the keel)
# The fit's own constant heading error without any reference is ~0.1–0.2° on this run (measured while writing
# the test); with a reference the remaining offset is set by the reference and the levelling: 0.3° is the
# issue's target for "offset removed" (issue #6).
OFFSET_TOL_DEG = 0.3


@pytest.fixture
def ahrsd_inproc(capsys):
    """The same command line in this process (saves the interpreter start-up). Returns (rc, stdout, stderr)."""
    from ahrsd.cli.main import main

    def run(*args):
        capsys.readouterr()
        try:
            rc = main(["calibrate", *map(str, args)])
        except SystemExit as exc:
            rc = exc.code
        out, err = capsys.readouterr()
        return rc, out, err

    return run


def _write(path: Path, blk, heading_ref_deg=None) -> Path:
    cols = TRUTH_COLUMNS + (("heading_ref_deg",) if heading_ref_deg is not None else ())
    with RecordingWriter(path, extra_columns=cols) as w:
        for i in range(len(blk.t_s)):
            extra = {} if heading_ref_deg is None else {"heading_ref_deg": heading_ref_deg[i]}
            w.write(make_sample(blk.t_s[i], blk.gyro_rad_s[i], blk.accel_m_s2[i], blk.mag_ut[i]),
                    truth_q_wxyz=blk.truth_q_wxyz[i], **extra)
    return path


@pytest.fixture(scope="module")
def boat(tmp_path_factory):
    """120 s of the simulated boat (level-turns: 3 full turns, waves ±7.5°, 2 m/s) at 20 Hz, ADIS16405 errors and
    the default vehicle iron. Recorded twice: without a reference, and with heading_ref_deg = the hull's true
    heading, missing (NaN) for 20 s and at every 7th sample."""
    d = tmp_path_factory.mktemp("boat")
    blk = simulate("level-turns", 120, rate_hz=20, seed=3, errors=SensorErrors.adis16405(seed=3))
    q = blk.truth_q_wxyz
    yaw, pitch, roll = Rotation.from_quat(np.column_stack((q[:, 1:], q[:, :1]))).as_euler("ZYX").T
    hull = (np.degrees(yaw) + HULL_OFFSET_DEG) % 360.0
    ref = hull.copy()
    ref[600:1000] = np.nan
    ref[::7] = np.nan
    field = earth_field(SITE.lat_deg, SITE.lon_deg, SITE.alt_m, SITE.date)
    return {"blk": blk, "roll": roll, "pitch": pitch, "hull_deg": hull, "field": field,
            "noref": _write(d / "boat.csv", blk), "ref": _write(d / "boat-ref.csv", blk, ref), "dir": d}


def hull_heading_error_deg(boat, soft_iron, hard_iron_ut):
    """Calibrated magnetic heading (true roll/pitch) minus the hull's magnetic heading over the recording, in
    degrees: (constant offset, RMS). The offset is the heading-independent part (A of a deviation fit of the
    errors), so it does not depend on how long the boat spent on each heading (its turn rate varies 5…13 °/s)."""
    model = MagModel(np.asarray(hard_iron_ut), np.asarray(soft_iron))
    psi = paper.magnetic_heading_deg(model.apply(boat["blk"].mag_ut), boat["roll"], boat["pitch"])
    hull_mag = (boat["hull_deg"] - math.degrees(boat["field"].declination_rad)) % 360.0
    err = wrap_180_deg(psi - hull_mag)
    return -swing.fit_deviation(psi, hull_mag).a_deg, float(np.sqrt(np.mean(err**2)))


def test_heading_ref_column_removes_the_offset_json_and_plot(boat, tmp_path, ahrsd_inproc, monkeypatch):
    from support.figures import line, saved_figures

    state, png = tmp_path / "state", tmp_path / "bs.png"
    with saved_figures(monkeypatch) as figs:
        rc, stdout, stderr = ahrsd_inproc("mag", "--method", "backstepping", boat["ref"], *SITE_ARGS, "--state-dir",
                                          state, "--json", "--plot", png)
    assert rc == 0, stdout + stderr
    out = json.loads(stdout)
    assert out["method"] == "backstepping" and out["refused"] is None
    assert f"figure written to {png}" in stderr                 # the figure's place, beside the JSON on stdout
    assert len(out["hard_iron_ut"]) == 3 and np.asarray(out["soft_iron"]).shape == (3, 3)
    assert 0 < out["residual_rms_ut"] < 0.2 and out["saved_to"] == str(state / "calibration.json")
    card = out["quality"]["heading_reference"]
    assert {"A_deg", "B_deg", "C_deg", "D_deg", "E_deg", "folded_offset_deg"} <= set(card)
    # rows without a reference (NaN) are not used: of the 1200 blocks of 0.1 s the 200 in the 20 s gap have none;
    # a block that lost one of its two rows (every 7th row) keeps the other
    assert card["n"] == 1000
    assert card["folded_offset_deg"] == pytest.approx(HULL_OFFSET_DEG, abs=0.5)
    for k in "BCDE":   # the field fit leaves no heading-dependent deviation
        assert abs(card[f"{k}_deg"]) < 0.3, card
    mean, rms = hull_heading_error_deg(boat, out["soft_iron"], out["hard_iron_ut"])
    assert abs(mean) < OFFSET_TOL_DEG and rms < 0.8
    stored = load_calibration_file(state / "calibration.json")
    np.testing.assert_allclose(stored.mag.soft_iron, out["soft_iron"])
    assert stored.metadata["mag"]["heading_reference"]["folded_offset_deg"] == pytest.approx(card["folded_offset_deg"])
    assert png.read_bytes()[:4] == b"\x89PNG" and len(figs) == 1
    # the figure's heading errors are the recording's reference against the calibrated compass, offset folded
    # in: around zero at every heading (the simulated hull offset is gone), all round the circle
    err = line(figs[0].axes[2], "recording (heading_ref_deg)")
    err = err[np.isfinite(err[:, 1])]                     # rows without a reference are drawn as gaps
    assert np.ptp(err[:, 0]) > 300
    print(f"plotted heading error: median {np.median(err[:, 1]):.3f}°, RMS {np.sqrt(np.mean(err[:, 1] ** 2)):.3f}°")
    assert abs(np.median(err[:, 1])) < OFFSET_TOL_DEG and np.sqrt(np.mean(err[:, 1] ** 2)) < 1.0


def test_without_reference_the_mounting_offset_stays(boat, ahrsd_inproc):
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--dry-run", "--json")
    assert rc == 0, out + err
    res = json.loads(out)
    assert "heading_reference" not in res["quality"]
    mean, _ = hull_heading_error_deg(boat, res["soft_iron"], res["hard_iron_ut"])
    assert mean == pytest.approx(-HULL_OFFSET_DEG, abs=0.5)


def _swing_table(boat, soft_iron, hard_iron_ut, path: Path) -> Path:
    """A classical 8-point swing: on each of N, NE, …, NW (hull heading, magnetic) the compass is read several
    times (every sample within ±2° of it, over the three turns) against a reference with 0.2° error; the
    compass column is the heading the calibration without a reference gives there."""
    model = MagModel(np.asarray(hard_iron_ut), np.asarray(soft_iron))
    psi = paper.magnetic_heading_deg(model.apply(boat["blk"].mag_ut), boat["roll"], boat["pitch"])
    hull_mag = (boat["hull_deg"] - math.degrees(boat["field"].declination_rad)) % 360.0
    rng = np.random.default_rng(8)
    rows = ["# compass swing, magnetic headings", "reference_deg,compass_deg"]
    for target in np.arange(0.0, 360.0, 45.0):
        near = np.abs(wrap_180_deg(hull_mag - target)) < 2.0
        ref = target + float(np.mean(wrap_180_deg(hull_mag[near] - target)))
        compass = target + float(np.mean(wrap_180_deg(psi[near] - target)))
        rows.append(f"{ref + rng.normal(0, 0.2):.2f},{compass % 360.0:.2f}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_swing_table_removes_the_offset_and_reports_the_card(boat, tmp_path, ahrsd_inproc):
    state = tmp_path / "state"    # empty: the same (no) bench calibration for both fits
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--state-dir", state,
                                "--dry-run", "--json")
    first = json.loads(out)
    table = _swing_table(boat, first["soft_iron"], first["hard_iron_ut"], tmp_path / "swing.csv")
    # in this process: the console entry point is test_cal_cli's (test_mag_json_has_the_public_keys_and_is_saved)
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--state-dir", state,
                                "--swing-table", table, "--json")
    assert rc == 0, out + err
    res = json.loads(out)
    assert {"hard_iron_ut", "soft_iron", "residual_rms_ut"} <= set(res)
    card = res["quality"]["heading_reference"]
    assert card["source"] == "swing-table" and card["n"] == 8 and "note" not in card
    assert card["A_deg"] == pytest.approx(HULL_OFFSET_DEG, abs=0.5)
    assert card["folded_offset_deg"] == card["A_deg"]
    # B..E from 8 such readings have σ ≈ 0.36·√(2/8) ≈ 0.18°, plus the fit's own semicircular residual on this
    # recording (B ≈ 0.55° measured): a loose bound
    assert max(abs(card[f"{k}_deg"]) for k in "BCDE") < 0.8
    # 8 readings, each with the fit's wave-correlated heading error (0.58° RMS per sample, ~3 independent passes
    # per heading → ~0.3°) and 0.2° of reference: A has σ ≈ 0.13°; 3σ (measured on this run: −0.21°)
    mean, _ = hull_heading_error_deg(boat, res["soft_iron"], res["hard_iron_ut"])
    assert abs(mean) < 0.4
    # only the yaw changed: the same hard iron and residual, W rotated about body z by −A
    np.testing.assert_allclose(res["hard_iron_ut"], first["hard_iron_ut"])
    assert res["residual_rms_ut"] == pytest.approx(first["residual_rms_ut"], rel=1e-9)
    folded = bs.fold_heading_offset(MagModel(np.asarray(first["hard_iron_ut"]), np.asarray(first["soft_iron"])),
                                    card["A_deg"])
    np.testing.assert_allclose(res["soft_iron"], folded.soft_iron, atol=1e-12)
    # the report for a person shows the card
    rc, text, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--dry-run",
                                 "--swing-table", table)
    assert rc == 0 and "deviation card from the swing table" in text and "B " in text and "E " in text


def test_heading_reference_fixes_in_the_fit(boat):
    """Two fixes in fit_backstepping found by this integration: a sparse reference (NaN between fixes) survives
    the 0.1 s block averaging, and the reference is compared with the lean-compensated heading (the uncompensated
    accelerometer tilt leans into the turns and showed as a spurious C ≈ 2.7° on this boat)."""
    blk = boat["blk"]
    sparse = np.where(np.arange(len(blk.t_s)) % 10 == 0, boat["hull_deg"], np.nan)
    for href, n_min in ((boat["hull_deg"], 1100), (sparse, 200)):
        data = MagFitInput(blk.t_s, blk.mag_ut, blk.accel_m_s2, blk.gyro_rad_s, href)
        res = bs.fit_backstepping(data, boat["field"])
        assert res.ok, res.refused
        card = res.quality["heading_reference"]
        assert card["n"] >= n_min
        assert abs(card["C_deg"]) < 0.3 and abs(card["B_deg"]) < 0.3, card
        mean, _ = hull_heading_error_deg(boat, res.model.soft_iron, res.model.hard_iron_ut)
        assert abs(mean) < OFFSET_TOL_DEG


def test_plot_without_matplotlib_is_a_clear_usage_error(boat, tmp_path, ahrsd_inproc, monkeypatch):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, name, None)   # `import matplotlib…` now raises ImportError
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    png, state = tmp_path / "bs.png", tmp_path / "state"
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["ref"], *SITE_ARGS, "--state-dir", state,
                                "--plot", png)
    assert rc == 2
    assert f"--plot needs matplotlib: {sys.executable} -m pip install matplotlib" in err and "Traceback" not in out + err
    assert not png.exists() and not (state / "calibration.json").exists()   # refused before fitting or saving
    # the library function raises a typed error (an ImportError) with the same hint
    data = MagFitInput(boat["blk"].t_s, boat["blk"].mag_ut, boat["blk"].accel_m_s2)
    res = bs.fit_backstepping(data, boat["field"], speed_m_s=None)
    from ahrsd.core.plotting import PlotUnavailableError

    with pytest.raises(PlotUnavailableError, match="-m pip install matplotlib"):
        bsplot.plot_backstepping(res, data, png)
    assert issubclass(PlotUnavailableError, ImportError)


def test_bad_reference_inputs_are_clear(boat, tmp_path, ahrsd_inproc):
    state = tmp_path / "state"
    bad = tmp_path / "bad-swing.csv"
    bad.write_text("reference_deg,compass_deg\n0,1\n45,forty\n")
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--state-dir", state,
                                "--swing-table", bad)
    assert rc == 1 and "bad-swing.csv:3" in err and "Traceback" not in err
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", boat["noref"], *SITE_ARGS, "--state-dir", state,
                                "--swing-table", tmp_path / "missing.csv", "--json")
    assert rc == 1 and "swing table" in json.loads(out)["error"]
    blk = boat["blk"]
    wrong = np.full(len(blk.t_s), np.nan)
    wrong[5] = 1000.0
    rc, out, err = ahrsd_inproc("mag", "--method", "backstepping", _write(tmp_path / "w.csv", blk, wrong),
                                *SITE_ARGS, "--state-dir", state)
    assert rc == 1 and "heading_ref_deg 1000.0" in err
    rc, out, err = ahrsd_inproc("mag", "--method", "ellipsoid", boat["ref"], *SITE_ARGS, "--state-dir", state,
                                "--heading-ref-delay-s", "2")
    assert rc == 2 and "--heading-ref-delay-s goes with --method backstepping" in err
    assert not (state / "calibration.json").exists()


def test_a_gnss_recording_beside_it_is_named_when_levelled_by_the_accelerometer(boat, tmp_path, ahrsd_inproc):
    """Session 23's walk fitted the tour's GNSS boat with --lat/--lon: 'predicted 0.16°', then 0.83° heading RMS in
    ins. With REC.gnss.csv beside the recording and no --gnss, the report says --gnss levels with the aided
    attitude; without the file, or with --json, nothing is added."""
    import shutil

    rec = shutil.copy(boat["noref"], tmp_path / "run.csv")
    rc, stdout, _ = ahrsd_inproc("mag", "--method", "backstepping", rec, *SITE_ARGS, "--dry-run")
    assert rc == 0 and "--gnss" not in stdout
    (tmp_path / "run.gnss.csv").write_text("t_s\n")   # only its presence is read
    rc, stdout, _ = ahrsd_inproc("mag", "--method", "backstepping", rec, *SITE_ARGS, "--dry-run")
    hint = [line for line in stdout.splitlines() if "lies beside the recording" in line]
    assert rc == 0 and len(hint) == 1 and f"--gnss {tmp_path / 'run.gnss.csv'}" in hint[0], stdout
    rc, stdout, _ = ahrsd_inproc("mag", "--method", "backstepping", rec, *SITE_ARGS, "--dry-run", "--json")
    assert rc == 0 and json.loads(stdout)["method"] == "backstepping"
