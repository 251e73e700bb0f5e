"""An iron that steps is seen against the gyro (issue 28, estimator/mag_step.py): the magnetometer heading jumps
while the gyro says the vehicle did not turn. The two-window test on worked numbers; on the simulator a step of
the hard iron on a straight road is caught within seconds and the published heading stays within 3σ of the truth;
calibrated runs with turns and waves never trip it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator.mag_step import MagStepDetector
from bench.vehicle_accuracy import IRON_STEP_UT, simulate_vehicle, tilt_heading_errors_deg
from support.thinned_ins import run_ins_thinned

RATE_HZ = 4.9          # the heading checks run at the GNSS fixes (not 5 Hz: no check on a window's edge)
NOISE_RAD = 0.002      # ± this, alternating: the mean square successive difference is (2a)²/2 = 2a²
STEP_RAD = 10 * NOISE_RAD


def _feed(det: MagStepDetector, innovations, yaw_rate_rad_s: float = 0.0, bias_sigma_rad: float = 0.0):
    """(check index, step) of each detection."""
    found = []
    for k, inn in enumerate(innovations):
        t = k / RATE_HZ
        step = det.add(t, inn, yaw_rate_rad_s * t, 0.0, bias_sigma_rad ** 2, 0.0, 0.0, 0.0)
        if step is not None:
            found.append((k, step))
    return found


def _innovations(n_before: int, n_after: int, step_rad: float) -> np.ndarray:
    alternating = NOISE_RAD * (-1.0) ** np.arange(n_before + n_after)
    return alternating + np.r_[np.zeros(n_before), np.full(n_after, step_rad)]


def test_a_step_is_declared_at_the_check_the_worked_numbers_give():
    """Windows 5 s / 2 s at 4.9 Hz: 25 checks before, 10 after. Only noise: σ of the difference of the means is
    √(2a²·(1/25 + 1/10)) = a·√0.28 = 0.529 a, the gate 5σ = 2.646 a. k checks after a step of 10 a the after-mean
    is up by k·a, the ten after-checks' alternating noise cancels and the 25 before-checks' leaves ±a/25: k = 2
    gives 2a + a/25 = 2.04 a, k = 3 gives 3a − a/25 = 2.96 a — declared at the third check after the step, as
    2.96 a."""
    det = MagStepDetector()
    found = _feed(det, _innovations(60, 10, STEP_RAD))
    assert [k for k, _ in found] == [60 + 2], found
    assert found[0][1] == pytest.approx(2.96 * NOISE_RAD, rel=1e-9), found
    assert det.detections == 1
    # the same with the step downwards: −3a − a/25 = −3.04 a
    found = _feed(MagStepDetector(), _innovations(60, 10, -STEP_RAD))
    assert [k for k, _ in found] == [62] and found[0][1] == pytest.approx(-3.04 * NOISE_RAD, rel=1e-9), found


def test_a_turn_widens_the_test_by_the_magnetometers_heading_dependent_error():
    """The same step while the vehicle turns at 20°/s with a calibration good to 0.5°: over the 7 s span the
    heading turns by 140° (capped at 2 rad): the calibration's error may change by √2·0.5°·2 = 1.41° = 0.0247 rad
    (1σ), so the gate is 0.123 rad — a 0.02 rad step is not declared, a 0.2 rad one is."""
    rate = math.radians(20.0)
    assert _feed(MagStepDetector(), _innovations(60, 20, STEP_RAD), rate, math.radians(0.5)) == []
    assert len(_feed(MagStepDetector(), _innovations(60, 20, 0.2), rate, math.radians(0.5))) == 1
    # a straight leg with the same calibration: declared
    assert len(_feed(MagStepDetector(), _innovations(60, 20, STEP_RAD), 0.0, math.radians(0.5))) == 1



# Without a step, the difference of the window means varies by what the module docstring lists; each part is drawn
# here from its own model (numpy, not the detector) and the detector fed the innovations it makes, with that part's
# variance told as the filter tells it. At the 5σ gate no stream of 40 s may trip it; leave the part out of the
# test's variance and most streams do (mutations iron-step-yaw-variance, iron-step-gyro-variance).
STREAMS = 25
STREAM_CHECKS = 196          # 40 s at 4.9 Hz
WHITE_RAD = 0.002            # the magnetometer heading's white noise, 1σ
YAW_SIGMA_RAD = 0.01         # the filter's yaw 1σ; a GNSS fix moves its error every CORRECTION_CHECKS checks
CORRECTION_CHECKS = 15       # ~3 s between the corrections that move it
GYRO_BIAS_SIGMA_RAD_S = 0.003
GYRO_ARW_RAD_S_SQRT_HZ = 0.005


def _no_step_streams(part: str, rng) -> list[tuple[np.ndarray, dict]]:
    """(innovations, the detector's variance arguments) of STREAMS streams without a step, with `part`'s error."""
    k = np.arange(STREAM_CHECKS)
    t = k / RATE_HZ
    streams = []
    for _ in range(STREAMS):
        inn = rng.normal(0.0, WHITE_RAD, STREAM_CHECKS)
        told = {"yaw_var_rad2": 0.0, "gyro_bias_var_rad2_s2": 0.0, "gyro_arw_rad_s_sqrt_hz": 0.0}
        if part == "yaw":
            # the filter's yaw error, redrawn at each correction (variance P at every check): a difference of two
            # window means varies by at most 2P
            draws = rng.normal(0.0, YAW_SIGMA_RAD, STREAM_CHECKS // CORRECTION_CHECKS + 1)
            inn -= draws[k // CORRECTION_CHECKS]
            told["yaw_var_rad2"] = YAW_SIGMA_RAD ** 2
        elif part == "gyro bias":
            # the filter's heading drifts at the vertical gyro bias's error, drawn once for the stream
            inn -= rng.normal(0.0, GYRO_BIAS_SIGMA_RAD_S) * t
            told["gyro_bias_var_rad2_s2"] = GYRO_BIAS_SIGMA_RAD_S ** 2
        else:
            # the angle random walk: white rate noise integrated between checks
            inn -= np.cumsum(rng.normal(0.0, GYRO_ARW_RAD_S_SQRT_HZ * math.sqrt(1.0 / RATE_HZ), STREAM_CHECKS))
            told["gyro_arw_rad_s_sqrt_hz"] = GYRO_ARW_RAD_S_SQRT_HZ
        streams.append((inn, told))
    return streams


@pytest.mark.parametrize("part", ["yaw", "gyro bias", "gyro random walk"])
def test_no_step_is_declared_on_streams_whose_mean_moves_only_as_the_test_allows(part):
    rng = np.random.default_rng(20261207)
    tripped = 0
    for inn, told in _no_step_streams(part, rng):
        det = MagStepDetector()
        for k, x in enumerate(inn):
            det.add(k / RATE_HZ, float(x), 0.0, told["yaw_var_rad2"], 0.0, 0.0, told["gyro_bias_var_rad2_s2"],
                    told["gyro_arw_rad_s_sqrt_hz"])
        tripped += det.detections > 0
    assert tripped == 0, (part, tripped, STREAMS)

# the car at Dunedin (dip −70.7°, H 19.4 µT), seed 3, drives straight from 120 s to 197 s (truth yaw rate below
# 0.5°/s): at 130 s the hard iron moves by the bench's 9 µT step reversed (−IRON_STEP_UT), which turns its heading
# by 4.0° and the field's magnitude by only 3 % (inside the norm check's 10 %), while the GNSS yaw says nothing on a
# straight road. Without the step test the filter follows the trusted magnetometer: 2.3° off with σ 0.30° at
# 150 s (site22's miss at Dunedin: 2.9° off with σ 0.22°). (IRON_STEP_UT itself turns this car's heading by only
# 1.7° here, and the magnetometer's norm by 1 %: below what the test sees, docs/gnss.md "An iron that steps".)
SITE = "-45.87,170.50"
STEP_UT = tuple(-x for x in IRON_STEP_UT)
STEP_AT_S = 130.0
SECONDS = 180.0     # the magnetometer re-enters about 30 s after the step; the check records kept (the latest 128,
#                     25 s) reach back to its re-entry
REPLAYED_S = 150.0  # the part of the run the replay test records


@pytest.fixture(scope="module")
def straight_step():
    from ahrsd.simulation import SensorErrors

    errors = SensorErrors.adis16405(3).replace(hard_iron_step_ut=STEP_UT, hard_iron_step_t_s=STEP_AT_S)
    run = simulate_vehicle("car", SECONDS, 3, SITE, errors=errors)   # calibrated for the iron before the step
    return run, _run_keeping_integrity(run)


def _run_keeping_integrity(run) -> dict:
    """run_ins_detailed's q, published yaw σ and estimator, and what each estimate's integrity (what the daemon
    reads) says of a rejection for a step (NaN: none), at the samples read (50 Hz, tests/support/thinned_ins.py:
    the estimates a run read at 200 Hz has there), and the run at those samples ("run")."""
    thin = run_ins_thinned(run)
    e = thin.estimates
    step = np.array([x.integrity.mag_step_rad if x.integrity is not None else np.nan for x in e])
    return {"q": np.array([x.q_wxyz for x in e]), "sigma_yaw_rad": np.array([x.sigma_rpy_rad[2] for x in e]),
            "integrity_step_rad": step, "ins": thin.ins, "run": thin.run}


def _true_magnetometer_step_rad(run) -> float:
    """The step of the magnetometer heading's error from the simulator's truth: the angle of the horizontal field
    turned to NED by the true attitude, 1 s after the step against 1 s before; the heading the magnetometer gives
    moves the other way."""
    m_ned = Rotation.from_quat(run.truth_q_wxyz[:, [1, 2, 3, 0]]).apply(run.mag_ut)
    angle = np.unwrap(np.arctan2(m_ned[:, 1], m_ned[:, 0]))
    before = (run.t_s > STEP_AT_S - 1.0) & (run.t_s < STEP_AT_S)
    after = (run.t_s > STEP_AT_S) & (run.t_s < STEP_AT_S + 1.0)
    return -(float(np.mean(angle[after])) - float(np.mean(angle[before])))


def test_an_iron_step_on_a_straight_road_is_caught_and_the_heading_stays_within_3_sigma(straight_step):
    run, out = straight_step
    true_step = _true_magnetometer_step_rad(run)
    assert math.radians(2.0) < abs(true_step) < math.radians(5.0)      # the case: a few degrees
    # the published heading within 3σ of the truth from the step on, through the magnetometer's re-entry (without
    # the step test: 7.7σ at 150 s)
    read = out["run"]
    _, hdg = tilt_heading_errors_deg(out["q"], read.truth_q_wxyz, read.declination_rad)
    sig = np.degrees(out["sigma_yaw_rad"])
    w = read.t_s >= STEP_AT_S
    assert np.all(np.abs(hdg[w]) <= 3.0 * sig[w]), (np.max(np.abs(hdg[w]) / sig[w]), np.max(np.abs(hdg[w])))
    report = out["ins"].heading_report()
    assert report.mag_steps == 1
    assert STEP_AT_S < report.first_step_t_s <= STEP_AT_S + 3.0, report
    # the step as seen, of the same sign, part of it (the after-window is still filling when it is declared)
    assert 0.3 < math.radians(report.first_step_deg) / true_step < 1.2, (report, true_step)


def test_the_estimates_integrity_names_the_step_while_the_magnetometer_stays_rejected_and_not_after(straight_step):
    """What the daemon reads (HeadingIntegrity.mag_step_rad): nothing before the step test rejects the magnetometer,
    then the step it saw, on every estimate while the magnetometer stays rejected; it re-enters after its 20 s of
    agreement (about 30 s after the step here), and from the check that uses it again on the integrity no longer
    names a step."""
    run, out = straight_step
    ins, said, t = out["ins"], out["integrity_step_rad"], out["run"].t_s
    report = ins.heading_report()
    t_detect = report.first_step_t_s
    assert np.all(np.isnan(said[t < t_detect]))
    used_again = [c.t_s for c in ins.heading_checks if c.t_s > t_detect and c.mag_use]
    assert used_again, "the magnetometer did not re-enter before the end of the run"
    assert used_again[0] >= t_detect + 20.0, (t_detect, used_again[0])
    # a check runs when its fix arrives, 0.1 s after the fix's time (simulate_vehicle's latency)
    while_rejected = (t > t_detect + 0.2) & (t < used_again[0])
    assert np.all(np.degrees(said[while_rejected]) == pytest.approx(report.first_step_deg, rel=1e-12))
    assert np.all(np.isnan(said[t > used_again[0] + 0.2]))


NO_STEP_SECONDS = 150.0    # the boat turns throughout; the car turns from 20 s to 120 s, then drives straight


@pytest.mark.parametrize("scenario", ["boat", "car"])
def test_no_step_is_declared_over_a_calibrated_run_with_turns_and_waves(scenario):
    """The boat in waves and the car in its turns and on the straight after them, calibrated, 150 s at the default
    site: no detection. The test's largest statistic stays far below its 5σ gate (docs/testing.md "Session 38 (cie)":
    0.44σ and 0.69σ here, 0.44σ and 1.24σ over 240 s), with any one of its variance terms left out as well."""
    run = simulate_vehicle(scenario, NO_STEP_SECONDS, 2, None)
    ins = run_ins_thinned(run, len(run.t_s)).ins         # the filter's checks only: no estimate read
    assert ins.heading_report().mag_steps == 0


def test_replay_names_the_iron_step_with_its_time_and_size(straight_step, tmp_path, capsys):
    """`ahrsd replay --gnss` of the straight-road step written as a recording (the magnetometer calibrated for the
    iron before the step, its calibration's heading error told as the daemon would): the summary names the rejection
    an iron change, when and by how much the magnetometer heading stepped — against the simulator's truth — and
    does not call it a disagreement with GNSS (there is no valid GNSS yaw on the straight road)."""
    import re

    from ahrsd.cli.main import main
    from ahrsd.core.sample import SampleFlags, make_sample
    from ahrsd.drivers.gnss.recording import GnssRecordingWriter
    from ahrsd.drivers.recording import RecordingWriter
    from bench.vehicle_accuracy import CALIBRATED_SIGMA_RAD

    run, _ = straight_step
    rec, gnss, out = tmp_path / "car.csv", tmp_path / "car.gnss.csv", tmp_path / "out.csv"
    n = int(np.searchsorted(run.t_s, REPLAYED_S))       # the step and the rejection, not the re-entry
    with RecordingWriter(rec) as w:
        for k in range(n):
            w.write(make_sample(run.t_s[k], run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k],
                                flags=SampleFlags.NEW_DATA))
    g = GnssRecordingWriter(gnss, extra_columns=("t_rx_s",))
    for fix in run.fixes:
        if fix.t_s < REPLAYED_S:
            g.write(fix)
    g.close()
    code = main(["replay", str(rec), "--gnss", str(gnss), "-o", str(out), "--date", "2026-01-01",
                 "--set", f"mag_calibration_sigma_rad={float(CALIBRATED_SIGMA_RAD)!r}"])
    err = capsys.readouterr().err
    assert code == 0, err
    found = re.findall(r"WARNING: iron changed once at ([0-9.]+) s: magnetometer heading stepped by ([-+][0-9.]+)° "
                       r"while the gyro saw no turn, magnetometer rejected \(heading reset", err)
    assert len(found) == 1, err
    t_step, step_deg = float(found[0][0]), float(found[0][1])
    assert STEP_AT_S < t_step <= STEP_AT_S + 3.0, err
    true_step_deg = math.degrees(_true_magnetometer_step_rad(run))
    assert 0.3 < step_deg / true_step_deg < 1.2, (step_deg, true_step_deg)
    assert "disagreed with GNSS" not in err, err
