"""`ahrsd replay REC --gnss GNSS.csv`: fixes merged with the samples in time order, the navigation columns
after the existing ones, the recording's fixes through the validator, clear errors for bad input."""

from __future__ import annotations

import contextlib
import io
import subprocess

import numpy as np
import pytest

from ahrsd.cli.replay import AIDED_OUTPUT_HEADER, OUTPUT_HEADER
from ahrsd.core.gnss import make_fix
from ahrsd.core.sample import make_sample
from ahrsd.estimator import make_estimator
from support.ahrsd_process import LOW_RATE
from ahrsd.estimator.replay import ATTITUDE_COLUMNS, HEADING_COLUMNS, NAV_COLUMNS, replay_attitude
from support.fake_aided import FakeAided


class RecordingOrder(FakeAided):
    def __init__(self):
        super().__init__()
        self.events = []

    def update_gnss(self, fix):
        self.events.append(("fix", fix.t_s))
        return super().update_gnss(fix)

    def update(self, sample):
        self.events.append(("sample", sample.t_s))
        return super().update(sample)


def test_fixes_are_offered_in_time_order_and_nav_columns_follow():
    samples = [make_sample(0.01 * i, [0, 0, 0], [0, 0, -9.8], [20, 0, 40], counter=i) for i in range(100)]
    fixes = [make_fix(t, 47.0 + t * 1e-5, 8.0, 400.0 + t, [1.0, 0.0, 0.0]) for t in (0.105, 0.3, 0.555, 0.985, 0.9901)]
    est = RecordingOrder()
    table = np.vstack(list(replay_attitude(est, samples, fixes=fixes, chunk_rows=37)))
    assert table.shape == (100, len(ATTITUDE_COLUMNS) + len(NAV_COLUMNS) + len(HEADING_COLUMNS))
    # expected: a fix goes in before the first sample not earlier than it (sorted, fixes first on a tie)
    # and one later than the last sample is never offered (no sample after it)
    want = sorted([("sample", s.t_s) for s in samples] + [("fix", f.t_s) for f in fixes if f.t_s <= 0.99],
                  key=lambda e: (e[1], e[0] != "fix"))
    assert est.events == want
    nav = table[:, len(ATTITUDE_COLUMNS) : len(ATTITUDE_COLUMNS) + len(NAV_COLUMNS)]
    first_nav = int(np.searchsorted([s.t_s for s in samples], 0.105))   # the first sample after the first fix
    assert np.all(np.isnan(nav[:first_nav])) and np.all(np.isfinite(nav[first_nav:]))
    row = nav[-1]
    assert list(row[:3]) == [1.5, -2.0, 0.25]                            # FakeAided's NavState velocity
    assert tuple(row[3:]) == (fixes[-2].lat_deg, fixes[-2].lon_deg, fixes[-2].alt_m)


def test_an_unaided_estimator_takes_no_fixes():
    with pytest.raises(ValueError, match="not aided"):
        list(replay_attitude(make_estimator("mekf"), [], fixes=[]))


class MagnetometerRejected(FakeAided):
    """An aided estimator with heading checks (estimator.base.HeadingCheckedEstimator) whose checks rejected
    the magnetometer: 3 rejections at up to 36.4°, 2 resets of its yaw to the GNSS yaw."""

    yaw_resets = 2
    gnss_yaw_alignments = 0

    def __init__(self):
        from ahrsd.estimator.ins import GnssCounters

        super().__init__()
        self.gnss_counters = GnssCounters(offered=20, fused_velocity=19, fused_position=18, rejected_velocity=1,
                                          rejected_position=2)

    def set_mag_calibration_sigma(self, sigma_rad):
        pass

    def heading_report(self):
        from ahrsd.estimator.ins import HeadingReport

        return HeadingReport(mag_rejections=3, max_disagreement_deg=36.4, yaw_resets=self.yaw_resets)


def test_the_summary_reads_the_gate_and_the_heading_checks_an_estimator_declares():
    """replay's summary of the GNSS fixes: 'not offered' for an estimator that takes none, the gate's counts for
    an aided one, and the magnetometer warning when it also declares heading checks that rejected it."""
    from ahrsd.cli.replay import _gate_summary

    assert _gate_summary(make_estimator("mekf")) == "not offered"
    gate = "the filter fused 19 velocities and 18 positions, its gate rejected 1 and 2"
    plain = FakeAided()
    plain.gnss_counters = MagnetometerRejected().gnss_counters
    assert _gate_summary(plain) == gate
    assert _gate_summary(MagnetometerRejected()) == (
        gate + "; WARNING: magnetometer disagreed with GNSS by up to 36.4° (the largest at its 3 rejections): "
        "calibration wrong or iron changed (heading reset to the GNSS yaw 2×)")


def test_the_summary_says_an_uncalibrated_magnetometer_disagreed_for_want_of_a_calibration():
    """walk28: `replay --gnss` of the README's uncalibrated boat said the magnetometer disagreed "calibration wrong
    or iron changed" with no calibration given; the daemon says "magnetometer not calibrated" then. The cause follows
    what the replay was given: none, one that states no heading error, one that does."""
    import math

    from ahrsd.calibration.models import Calibration, MagModel
    from ahrsd.cli.replay import _disagreement_cause, _gate_summary

    stated = Calibration.identity().with_sensor("mag", MagModel.identity(), method="test", heading_std_deg=0.5)
    unstated = Calibration.identity().with_sensor("mag", MagModel.identity(), method="test")
    for calibration, sigma_rad, cause in ((None, math.nan, "magnetometer not calibrated (no --calibration)"),
                                          (unstated, math.nan, "the magnetometer calibration states no heading error"),
                                          (stated, math.radians(0.5), "calibration wrong or iron changed")):
        assert _gate_summary(MagnetometerRejected(), mag_cause=_disagreement_cause(calibration, sigma_rad)).endswith(
            f"(the largest at its 3 rejections): {cause} (heading reset to the GNSS yaw 2×)")


def test_many_rejected_velocities_name_the_lever_arm_the_estimator_declares():
    """More than a tenth of the velocities rejected: the summary names where the filter was told the antenna is
    (GnssAidedEstimator.lever_arm_m, which ins takes from its parameters)."""
    from ahrsd.cli.replay import _gate_summary
    from ahrsd.estimator.base import GnssAidedEstimator
    from ahrsd.estimator.ins import GnssCounters

    arm = (0.5, -0.25, -1.5)
    ins = make_estimator("ins", lever_arm_m=arm)
    assert isinstance(ins, GnssAidedEstimator) and ins.lever_arm_m == arm
    told = FakeAided()
    told.lever_arm_m = arm
    told.gnss_counters = GnssCounters(offered=20, fused_velocity=15, fused_position=20, rejected_velocity=5)
    assert _gate_summary(told) == (
        "the filter fused 15 velocities and 20 positions, its gate rejected 5 and 0; WARNING: that many rejected "
        "velocities usually mean the antenna is not where the filter was told (0.5 -0.25 -1.5 m, body FRD: "
        "--set \"lever_arm_m=(x, y, z)\") or the fixes' time stamps are off")


def test_rejections_the_heading_explains_do_not_name_the_lever_arm():
    """The daemon's rule (estimator/velocity_rejection_cause.py), counted as the replay went
    (velocity_rejection_watch.py): rejections that came while the heading was not yet found or just reset to the
    GNSS yaw are said as such; only those the heading does not explain, beyond a tenth of the fixes, name the arm."""
    from ahrsd.cli.replay import _gate_summary
    from ahrsd.estimator.ins import GnssCounters

    told = FakeAided()
    told.gnss_counters = GnssCounters(offered=20, fused_velocity=12, fused_position=20, rejected_velocity=8)
    by_heading = {"heading unknown": 5, "heading reset": 2, "unexplained": 1}
    assert _gate_summary(told, by_heading) == (
        "the filter fused 12 velocities and 20 positions, its gate rejected 8 and 0; WARNING: the velocities were "
        "rejected while the filter's heading was not one to trust (5 before its heading was found, 2 within 30 s of "
        "a reset of its yaw to the GNSS yaw), not for the antenna's place or the fixes' time stamps")
    text = _gate_summary(told, {"heading unknown": 3, "unexplained": 5})
    assert "(5 of them with its heading known) usually mean the antenna is not where" in text


def ahrsd(*args):
    """`ahrsd ARGS` run in this process (its output and exit status as the console script gives them, without
    an interpreter start-up and a numba cache load per run; the console script itself is test_recording's and
    test_replay's)."""
    from ahrsd.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([*map(str, args)])
        except SystemExit as exc:   # argparse usage errors
            rc = exc.code
    return subprocess.CompletedProcess(["ahrsd", *map(str, args)], rc, out.getvalue(), err.getvalue())


def replay(*args):
    """`ahrsd replay ARGS` run in this process."""
    return ahrsd("replay", *args)


@pytest.fixture(scope="module")
def boat(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay")
    rec = tmp / "boat.csv"
    res = ahrsd("record", "--sim", "boat", "--seconds", "40", *LOW_RATE, "-o", str(rec))
    assert res.returncode == 0, res.stderr
    return rec, tmp / "boat.gnss.csv"


def test_bad_gnss_input_is_a_clear_error(boat, tmp_path):
    rec, gnss = boat
    res = replay(str(rec), "--gnss", str(gnss), "--estimator", "mekf", "-o", str(tmp_path / "o.csv"))
    assert res.returncode == 1 and "--gnss needs the aided estimator" in res.stderr
    res = replay(str(rec), "--gnss", str(tmp_path / "none.csv"), "-o", str(tmp_path / "o.csv"))
    assert res.returncode == 1 and "No such file" in res.stderr
    bad = tmp_path / "bad.gnss.csv"
    bad.write_text("t_s,lat,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s\n1,2,3,4,5,6,7\n")
    res = replay(str(rec), "--gnss", str(bad), "-o", str(tmp_path / "o.csv"))
    assert res.returncode == 1 and "lat_deg" in res.stderr
    nofix = tmp_path / "nofix.gnss.csv"
    nofix.write_text("t_s,lat_deg,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s,fix_type\n1,2,3,4,5,6,7,1\n")
    res = replay(str(rec), "--gnss", str(nofix), "-o", str(tmp_path / "o.csv"))
    assert res.returncode == 1 and "no usable fix" in res.stderr and "1 rejected" in res.stderr
    assert not (tmp_path / "o.csv").exists()


@pytest.fixture(scope="module")
def aided_replay(boat):
    """`ahrsd replay boat.csv --gnss boat.gnss.csv -o aided.csv` (the default aided estimator, no options):
    the run and its output, for the tests that read its columns and its summary."""
    rec, gnss = boat
    out = rec.with_name("aided.csv")
    return replay(str(rec), "--gnss", str(gnss), "-o", str(out)), out


def test_replay_with_gnss_adds_the_navigation_columns(boat, aided_replay):
    from ahrsd.drivers.gnss.recording import read_gnss_recording
    from ahrsd.simulation import open_stream

    rec, gnss = boat
    res, out = aided_replay
    assert res.returncode == 0, res.stderr
    assert "GNSS fixes (0 rejected;" in res.stderr and "through ins" in res.stderr
    lines = out.read_text().splitlines()
    assert lines[0] == AIDED_OUTPUT_HEADER and lines[0].startswith(OUTPUT_HEADER + ",")
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    cols = AIDED_OUTPUT_HEADER.split(",")
    t = data[:, 0]
    late = t > 20.0
    truth = open_stream("boat", errors="ideal").truth_at(t[late])
    vel = data[late][:, [cols.index(c) for c in ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s")]]
    assert np.sqrt(np.mean((vel - truth.vel_ned_m_s) ** 2)) < 0.2      # 0.05 m/s receiver noise
    lat = data[late][:, cols.index("lat_deg")]
    assert np.max(np.abs(lat - truth.lat_deg)) * 111_000 < 5.0
    assert len(read_gnss_recording(gnss)) > 150


def test_replay_reports_the_gate_and_hints_at_a_wrong_lever_arm(boat, aided_replay, tmp_path):
    """The summary says what the filter's innovation gate did; told an antenna 4 m above the IMU that the
    recording's receiver does not have (the simulator's antenna is at the IMU), the rocking boat's fixes are
    rejected and the summary points at the lever arm."""
    rec, gnss = boat
    res, _ = aided_replay
    assert res.returncode == 0 and "its gate rejected 0 and 0" in res.stderr, res.stderr
    assert "WARNING" not in res.stderr
    res = replay(str(rec), "--gnss", str(gnss), "--set", "lever_arm_m=(0, 0, -4)",
                "-o", str(tmp_path / "b.csv"))
    # the lever-arm check finds the antenna where the simulated receiver has it (at the IMU), not at the told arm
    assert res.returncode == 0 and "(0 0 -4 m, body FRD" in res.stderr, res.stderr
    assert np.linalg.norm(fitted_antenna_m(res.stderr)[0] - 0.0) < 1.0, res.stderr


def fitted_antenna_m(summary: str) -> tuple[np.ndarray, float]:
    """The antenna position replay's summary says the rejected velocities fit (the lever-arm check), and the 1σ it
    states with it (the largest axis's), m."""
    import re

    found = re.search(r"fit an antenna at \((-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\) m ±([\d.]+) m", summary)
    assert found, summary
    return np.array([float(v) for v in found.groups()[:3]]), float(found.group(4))


def test_a_recorded_antenna_lever_arm_replays_clean_only_when_given(tmp_path, caplog):
    """`record --sim boat --gnss-lever-arm-m` puts the simulated receiver's antenna on a mast; replayed without
    the arm the filter's gate rejects the rocking antenna's velocities and the summary warns, given the same arm
    (`--set lever_arm_m=...`) it does not. 20 s are enough: without the arm the gate rejects about half the
    velocities (the warning is for more than GATE_HINT_FRACTION, a tenth), with it none.

    Where the check puts the antenna: its fit takes the arm's term through the filter's attitude, so a heading ψ off
    turns that term and shrinks the fitted arm along it (by about cos ψ; docs/gnss.md). With the magnetometer
    uncalibrated the heading of this recording is 7–80° off through the 20 s, and the check puts the antenna only
    on the mast's side: up and aft. Given the simulated chip's calibration (the heading known), it puts it within its
    stated 3σ of the mast's top on every axis and states that σ at 0.5 m or less; let adopt the fitted arm, it says
    the filter fused at it. Broken: the fitted offset's sign flipped, no antenna is named; the arm's prior at 0.3 m,
    the calibrated fit stops short of the mast's top; the summary reading the momentary fit (which the adopted arm
    leaves explaining nothing), the adoption goes unsaid."""
    from bench.sim_calibration import save_mag_calibration, sim_chip_mag_model

    rec = tmp_path / "mast.csv"
    res = ahrsd("record", "--sim", "boat", "--seconds", "20", *LOW_RATE, "--gnss-lever-arm-m", "-1", "0", "-2", "-o",
                str(rec))
    assert res.returncode == 0, res.stderr
    gnss = tmp_path / "mast.gnss.csv"
    res = replay(str(rec), "--gnss", str(gnss), "-o", str(tmp_path / "a.csv"))
    # told no arm, the lever-arm check puts the antenna up the mast and aft, whatever the magnetometer said
    assert res.returncode == 0, res.stderr
    antenna, _ = fitted_antenna_m(res.stderr)
    assert antenna[2] <= -0.5 and antenna[0] < 0.0, res.stderr
    # the filter's own log of the rejected magnetometer says what the daemon says: no calibration, not a wrong one
    logged = caplog.text
    assert "GNSS-held heading by" in logged and "no magnetometer calibration stating its heading error" in logged
    assert "calibration wrong or iron changed; magnetometer rejected" not in logged
    save_mag_calibration(tmp_path / "state", sim_chip_mag_model())
    calibration = str(tmp_path / "state" / "calibration.json")
    res = replay(str(rec), "--gnss", str(gnss), "--calibration", calibration, "-o", str(tmp_path / "c.csv"))
    assert res.returncode == 0, res.stderr
    antenna, sigma_m = fitted_antenna_m(res.stderr)
    assert sigma_m <= 0.5 and np.all(np.abs(antenna - (-1, 0, -2)) <= 3 * sigma_m), res.stderr
    # let adopt the fitted arm: the arm in use leaves next to no rejections and the momentary fit explains nothing,
    # and the summary reads the latch (the told arm found wrong), not that fit
    res = replay(str(rec), "--gnss", str(gnss), "--calibration", calibration, "--set", "lever_arm_adopt=true",
                 "-o", str(tmp_path / "d.csv"))
    assert res.returncode == 0 and "the filter fused at the fitted arm once it was sure of it" in res.stderr, res.stderr
    res = replay(str(rec), "--gnss", str(gnss), "--set", "lever_arm_m=(-1, 0, -2)",
                "-o", str(tmp_path / "b.csv"))
    assert res.returncode == 0 and "WARNING" not in res.stderr, res.stderr
    bad = ahrsd("record", "--sim", "static", "--seconds", "1", "--gnss-lever-arm-m", "0", "0", "-200",
                "-o", str(tmp_path / "c.csv"))
    assert bad.returncode == 1 and "expected three numbers" in bad.stderr, bad.stderr
