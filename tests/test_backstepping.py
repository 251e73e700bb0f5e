"""Back-stepping magnetometer calibration (Nourmohammadi & Sabet, J. of Control 16(3), 2022): the paper's arithmetic, the sphere fit, the corrective
loop on an out-and-back run, the generalised vertical-channel fit on limited-tilt data, and refusals."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag import backstepping as bs
from ahrsd.core import angles
from ahrsd.cli.plots import backstepping as bsplot
from ahrsd.calibration.mag import levelling
from ahrsd.calibration.mag import backstepping_paper as paper
from ahrsd.calibration.mag import vertical_channel as vc
from ahrsd.calibration.mag import swing
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.mag.fit import fit_mag
from ahrsd.core.wmm import earth_field
from ahrsd.core.angles import wrap_180_deg

G = 9.80665
NOISE_UT = 0.125                      # ADIS16405 magnetometer noise, 1.25 mgauss rms


# ------------------------------------------------------------------------------- a small vehicle simulator


def field_tehran():
    return earth_field(35.7, 51.4, 0.0, dt.date(2026, 1, 1))


DISTORTION = Rotation.from_euler("ZX", [2.0, 1.0], degrees=True).as_matrix() @ np.array(
    [[1.08, 0.05, -0.03], [0.05, 0.93, 0.04], [-0.03, 0.04, 1.02]])   # non-symmetric (soft iron with an asymmetric part)
HARD_IRON = np.array([28.0, -19.0, 35.0])                               # µT (280/−190/350 mgauss)


def sense(roll, pitch, yaw, field, rng, noise=NOISE_UT, distortion=DISTORTION, hard_iron=HARD_IRON,
          accel_bias=(0.03, -0.04, 0.02)):
    r = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll)))
    b = r.inv().apply(field.ned_ut)
    raw = b @ distortion.T + hard_iron + rng.normal(0, noise, b.shape)
    acc = r.inv().apply([0.0, 0.0, -G]) + np.array(accel_bias) + rng.normal(0, 0.01, b.shape)
    return raw, acc


def level_turns(tilt_deg, n=2000, seed=0, turns=2.0, noise=NOISE_UT):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 10.0
    T = n / 10.0
    yaw = 2 * math.pi * turns * t / T + 0.4
    a = math.radians(tilt_deg)
    roll = a * (0.7 * np.sin(2 * math.pi * 7 * t / T) + 0.3 * np.sin(2 * math.pi * 19 * t / T + 1))
    pitch = a * (0.7 * np.sin(2 * math.pi * 5 * t / T + 2) + 0.3 * np.sin(2 * math.pi * 23 * t / T))
    field = field_tehran()
    raw, acc = sense(roll, pitch, yaw, field, rng, noise=noise)
    return MagFitInput(t, raw, acc), dict(roll=roll, pitch=pitch, yaw=yaw, field=field)


def heading_rms_deg(model, field, tilt_deg=10.0, n=1500, seed=7):
    """(RMS, mean) heading error (degrees) of `model` against the true heading, on random attitudes tilted up to
    tilt_deg."""
    rng = np.random.default_rng(seed)
    roll = rng.uniform(-1, 1, n) * math.radians(tilt_deg)
    pitch = rng.uniform(-1, 1, n) * math.radians(tilt_deg)
    yaw = rng.uniform(-math.pi, math.pi, n)
    raw, _ = sense(roll, pitch, yaw, field, rng)
    psi = paper.magnetic_heading_deg(model.apply(raw), roll, pitch)
    err = wrap_180_deg(psi - np.degrees(yaw - field.declination_rad))
    return float(np.sqrt(np.mean(err**2))), float(np.mean(err))


# --------------------------------------------------------------------------- the paper's arithmetic


def test_corrective_step1_scales_reproduce_table3():
    # 0.19556·27999/27451 = 0.199464 (paper 0.19947); 0.09001·… = 0.091807 (paper 0.09181)
    sx, sy = paper.scale_horizontal(0.19556, 0.09001, 27999.0, 27451.0)
    assert sx == pytest.approx(0.19947, abs=1e-5)
    assert sy == pytest.approx(0.09181, abs=1e-5)


def test_corrective_step2_rescales_hz_to_table4():
    assert paper.rescale_vertical(38810.0, 0.16142, 0.20642) == pytest.approx(30350.0, abs=1.5)


def test_corrective_step3_bz_eq30_reproduces_table5():
    bz = paper.solve_vertical_bias(5362.0, 0.20642, 48752.0, 27450.0)
    assert bz == pytest.approx(-2955.0, abs=1.0)
    assert paper.solve_vertical_bias_signed(5362.0, 0.20642, 48752.0, 27450.0, -1.0) > 5362.0  # southern root
    with pytest.raises(paper.BacksteppingError):
        paper.solve_vertical_bias(5362.0, 0.2, 27000.0, 27450.0)


@pytest.mark.parametrize("table,hz,sz,bz", [
    ("3", 38810, 0.16142, -903), ("4", 30350, 0.20642, -903), ("5", 40290, 0.20642, -2955),
    ("6", 40291, 0.26142, -5171)])
def test_tables_3_to_6_imply_one_raw_vertical_reading(table, hz, sz, bz):
    # Hz = (Ĥz − bz)/sz with the same mean raw z ≈ 5362 in every table of the paper (Tables 3–6)
    assert hz * sz + bz == pytest.approx(5362.0, abs=1.0)


@pytest.mark.parametrize("hz,hh,printed,typo", [
    (38810, 27450, 47536, False), (30350, 27450, 40992, True), (40290, 27450, 48752, False),
    (40291, 27450, 48753, False), (40247, 27473, 48730, False), (40289, 27451, 48752, False)])
def test_table_magnitudes_and_the_table4_typo(hz, hh, printed, typo):
    total = math.hypot(hz, hh)
    if typo:   # Table 4 prints 40992 for √(30350² + 27450²) = 40922 (digit transposition)
        assert total == pytest.approx(40922, abs=1) and abs(total - printed) > 60
    else:
        assert total == pytest.approx(printed, abs=1.0)


def test_closed_form_vertical_recovers_table6_from_two_legs():
    total, sz, bz = 48752.0, 0.26142, -5171.0
    hh_o, hh_r = 27100.0, 27800.0
    v = lambda hh: math.sqrt(total**2 - hh**2)
    z_o, z_r = bz + sz * v(hh_o), bz + sz * v(hh_r)
    sz2, bz2 = paper.closed_form_vertical(z_o, z_r, hh_o, hh_r, total)
    assert sz2 == pytest.approx(sz, rel=1e-9) and bz2 == pytest.approx(bz, abs=1e-6)
    with pytest.raises(paper.BacksteppingError):
        paper.closed_form_vertical(z_o, z_o, hh_o, hh_o, total)


# ------------------------------------------------------------------------------------------ sphere fit


def _sphere_points(n=400, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def test_sphere_fit_exact_on_noise_free_data():
    b, s, h = np.array([-18.65, 13.85, -9.03]), np.array([0.19556, 0.09001, 0.16142]), 48.73
    raw = _sphere_points() * h * s + b
    fit = paper.sphere_fit_paper(raw, h)
    assert fit.reason is None
    np.testing.assert_allclose(fit.model.bias, b, atol=1e-9)
    np.testing.assert_allclose(fit.model.scale, s, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(fit.model.apply(raw), axis=1), h, rtol=1e-9)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(b=st.lists(st.floats(-200, 200), min_size=3, max_size=3),
       s=st.lists(st.floats(0.05, 5.0), min_size=3, max_size=3),
       h=st.floats(20.0, 70.0))
def test_sphere_fit_round_trip_property(b, s, h):
    raw = _sphere_points(200, 1) * h * np.array(s) + np.array(b)
    fit = paper.sphere_fit_paper(raw, h)
    assert fit.reason is None
    np.testing.assert_allclose(fit.model.bias, b, atol=1e-6 * max(1.0, max(map(abs, b))))
    np.testing.assert_allclose(fit.model.scale, s, rtol=1e-6)


def test_sphere_fit_reports_non_physical_coefficients_on_a_level_circle():
    th = np.linspace(0, 2 * math.pi, 200, endpoint=False)
    raw = np.column_stack((20 * np.cos(th) + 5, 25 * np.sin(th) - 3, np.full(th.size, 40.0)))
    fit = paper.sphere_fit_paper(raw, 48.0)
    assert fit.model is None and "rotation" in fit.reason


# ------------------------------------------------------------------------------ out-and-back corrective loop


def _out_and_back(seed=0, noise=NOISE_UT):
    """The paper's test 2 with its IGRF field (Hh 27.451, Hz 40.289 µT): legs at 62° and −117° with trims −3° / +1°; the vertical
    channel (z scale, z hard iron) differs from the test-1 coefficients we start from."""
    rng = np.random.default_rng(seed)
    hh, hz = 27.451, 40.289
    field = type("F", (), {"ned_ut": np.array([hh, 0.0, hz])})
    d = np.diag([1.05, 0.92, 0.88])
    h = np.array([-18.6, 13.9, -9.0])
    leg = 3000
    yaw = np.radians(np.concatenate((np.full(leg, 62.0), np.full(leg, 243.0))))
    pitch = np.radians(np.concatenate((np.full(leg, -3.0), np.full(leg, 1.0)))
                       + np.sin(np.arange(2 * leg) / 50.0))
    roll = np.radians(0.5 * np.sin(np.arange(2 * leg) / 27.0))
    raw, acc = sense(roll, pitch, yaw, field, rng, noise=noise, distortion=d, hard_iron=h, accel_bias=(0, 0, 0))
    legs = np.repeat([0, 1], leg)
    start = paper.DiagonalModel(np.array([-18.6, 13.9, -4.0]), np.array([1.05, 0.92, 0.70]))   # test-1 z wrong
    return raw, roll, pitch, legs, start, hh, hz


def test_backstep_loop_removes_the_out_and_back_step():
    raw, roll, pitch, legs, start, hh, hz = _out_and_back()
    res = paper.backstep_correct(raw, roll, pitch, legs, start, hh, hz)
    assert res.step_before_ut > 0.1                   # the sphere-fit coefficients leave a visible step
    assert res.converged and res.step_after_ut <= paper.PAPER_STEP_TOL_UT
    assert res.passes[-1].sz_source == "closed-form"
    # with noise the legs pin s_z to a few percent (the leg z readings differ by only ~1 µT: trim × H_h)
    assert res.model.scale[2] == pytest.approx(0.88, rel=0.03)
    assert res.model.bias[2] == pytest.approx(-9.0, abs=0.6)
    last = res.passes[-1]
    assert math.hypot(last.hh_ut, last.hz_ut) == pytest.approx(math.hypot(hh, hz), abs=0.02)
    assert len(res.passes) <= 4


def test_backstep_loop_is_exact_on_noise_free_legs():
    raw, roll, pitch, legs, start, hh, hz = _out_and_back(noise=0.0)
    res = paper.backstep_correct(raw, roll, pitch, legs, start, hh, hz, step_tol_ut=1e-6, field_tol_ut=1e-6)
    assert res.converged
    np.testing.assert_allclose(res.model.scale, [1.05, 0.92, 0.88], rtol=1e-6)
    np.testing.assert_allclose(res.model.bias, [-18.6, 13.9, -9.0], atol=1e-5)


def test_backstep_loop_with_one_leg_only_corrects_bz():
    raw, roll, pitch, legs, start, hh, hz = _out_and_back()
    one = legs == 0
    res = paper.backstep_correct(raw[one], roll[one], pitch[one], legs[one], start, hh, hz)
    assert "kept" in res.passes[0].sz_source
    assert res.model.scale[2] == start.scale[2]
    assert math.hypot(res.passes[-1].hh_ut, res.passes[-1].hz_ut) == pytest.approx(math.hypot(hh, hz), abs=0.05)


def test_segment_legs_finds_two_straight_runs():
    t = np.arange(0, 400, 0.5)
    heading = np.where(t < 150, 62.0, np.where(t < 180, 62 + (t - 150) * 6, 243.0)) % 360
    lab = paper.segment_legs(t, heading)
    assert set(np.unique(lab[lab >= 0])) == {0, 1}
    assert np.all(lab[(t > 10) & (t < 140)] == 0) and np.all(lab[t > 200] == 1)


# ----------------------------------------------------------------------- generalised fit on limited tilt


@pytest.fixture(scope="module")
def tilt10():
    data, truth = level_turns(10.0, n=2000, seed=3)
    return data, truth, bs.fit_backstepping(data, truth["field"], attitude="accel")


def test_general_fit_recovers_iron_on_10deg_data(tilt10):
    data, truth, res = tilt10
    assert res.ok, res.refused
    # tolerances from the noise: 0.125 µT per sample over ~2000 samples and 0.2–0.3° of accelerometer
    # roll/pitch bias (× 40 µT vertical field ≈ 0.2 µT): hard iron to ~1 µT, soft iron to ~1 %
    w_true = np.linalg.inv(DISTORTION)
    assert np.linalg.norm(res.model.hard_iron_ut - HARD_IRON) < 1.0
    assert np.abs(res.model.soft_iron - w_true).max() < 0.015
    assert abs(res.residual_rms_ut - NOISE_UT) < 0.05
    assert res.quality["predicted_heading"]["heading_dependent_std_deg"] < 0.5


def test_general_fit_heading_on_test_set_meets_target(tilt10):
    _, truth, res = tilt10
    rms, _ = heading_rms_deg(res.model, truth["field"], 10.0)
    assert rms <= 0.7           # issue #6 target (the LS ellipsoid is several degrees on the same data)
    rms30, _ = heading_rms_deg(res.model, truth["field"], 30.0, seed=8)
    assert rms30 < 1.0


def test_general_fit_beats_ls_ellipsoid_on_2deg_data():
    data, truth = level_turns(2.0, n=2000, seed=4)
    res = fit_mag("backstepping", data, truth["field"], attitude="accel")
    assert res.ok, res.refused
    rms, _ = heading_rms_deg(res.model, truth["field"], 10.0)
    init = vc._ellipsoid_init(data.mag_ut, truth["field"].total_ut)
    if init is not None:
        from ahrsd.calibration.models import MagModel
        rms_ell, _ = heading_rms_deg(MagModel(init[1], init[0]), truth["field"], 10.0)
        assert rms_ell > 2 * rms
    assert rms < 0.9


def test_gnss_course_reference_removes_the_constant_offset():
    data, truth = level_turns(5.0, n=2000, seed=5)
    rng = np.random.default_rng(9)
    t = data.t_s
    course = (np.interp(t - 2.0, t, np.degrees(np.unwrap(truth["yaw"]))) + rng.normal(0, 0.5, t.size)) % 360
    ref = swing.gnss_course_reference(t, course, np.full(t.size, 2.0), delay_s=2.0, max_turn_rate_deg_s=5.0)
    assert np.isfinite(ref).mean() > 0.8
    d2 = MagFitInput(t, data.mag_ut, data.accel_m_s2, None, ref)
    res = bs.fit_backstepping(d2, truth["field"], attitude="accel")
    assert res.ok and "heading_reference" in res.quality
    rms, mean = heading_rms_deg(res.model, truth["field"], 10.0)
    assert abs(mean) <= 0.3 and rms < 0.6
    # the 2° yaw misalignment is in the soft iron now: its rotation about z is visible
    assert abs(res.quality["heading_reference"]["folded_offset_deg"]) < 3.0


def test_free_dip_fit_without_position_on_10deg_data():
    data, truth = level_turns(10.0, n=2000, seed=6)
    res = bs.fit_backstepping(data, None, attitude="accel")
    assert res.ok, res.refused
    dip = res.quality["vertical_channel"]["dip_deg"]
    assert dip == pytest.approx(math.degrees(truth["field"].inclination_rad), abs=1.0)
    rms, _ = heading_rms_deg(res.model, truth["field"], 10.0)
    assert rms < 1.0


def test_paper_mode_runs_the_corrective_loop_and_reports_passes():
    raw, roll, pitch, legs, start, hh, hz = _out_and_back()
    # test 1 for the sphere fit: roll ±55°, pitch ±10°, full heading (the paper's test 1)
    rng = np.random.default_rng(1)
    n1 = 2000
    tt = np.arange(n1) / 10.0
    field = type("F", (), {"ned_ut": np.array([hh, 0.0, hz])})
    r1, p1, y1 = np.radians(55) * np.sin(tt / 9.5), np.radians(10) * np.sin(tt / 6 + 1), 4 * math.pi * tt / tt[-1]
    raw1, _ = sense(r1, p1, y1, field, rng, distortion=np.diag([1.05, 0.92, 0.70]),
                    hard_iron=np.array([-18.6, 13.9, -4.0]), accel_bias=(0, 0, 0))
    ref = type("Ref", (), {"total_ut": math.hypot(hh, hz), "inclination_rad": math.atan2(hz, hh),
                           "declination_rad": 0.0})
    mag = np.vstack((raw1, raw))
    t = np.arange(mag.shape[0]) / 10.0
    accel = np.zeros_like(mag)
    data = MagFitInput(t, mag, accel)
    res = bs.fit_backstepping(data, ref, model="paper", roll_rad=np.concatenate((r1, roll)),
                              pitch_rad=np.concatenate((p1, pitch)), rate_hz=None,
                              legs=np.concatenate((np.full(n1, -1), legs)),
                              calibration_mask=np.arange(mag.shape[0]) < n1, step_tol_ut=0.001)
    assert res.ok, res.refused
    q = res.quality["backstep"]
    assert q["converged"] and q["step_after_ut"] <= 0.001 and q["step_before_ut"] > 0.1
    assert q["passes"] and all("sz_source" in p for p in q["passes"])
    # two legs pin s_z only weakly (their z readings differ by ~1 µT), and the sphere fit's small horizontal
    # errors feed into it: s_z must move most of the way from the test-1 value 0.70 to the test-2 truth 0.88
    sz = 1 / res.model.soft_iron[2, 2]
    assert abs(sz - 0.88) < 0.3 * abs(0.70 - 0.88)


# ------------------------------------------------------------------------------------------- refusals


def test_refuses_a_single_heading():
    data, truth = level_turns(5.0, n=600, seed=1, turns=0.05)
    res = bs.fit_backstepping(data, truth["field"], attitude="accel")
    assert not res.ok and "heading" in res.refused and "full circle" in res.refused


def test_refuses_free_dip_without_tilt():
    data, _ = level_turns(0.5, n=1000, seed=2)
    res = bs.fit_backstepping(data, None, attitude="accel")
    assert not res.ok and "tilt" in res.refused and "--lat/--lon" in res.refused


def test_level_only_data_with_wmm_reports_what_it_cannot_determine():
    data, truth = level_turns(0.2, n=1500, seed=2)
    res = bs.fit_backstepping(data, truth["field"], attitude="accel")
    assert res.ok, res.refused
    assert any("vertical column" in u for u in res.quality["undetermined_by_data"])
    assert any("heading reference" in w for w in res.quality["warnings"])
    assert res.quality["predicted_heading"]["offset_std_deg"] > 0.5   # A is not determined by level data


def test_refuses_without_attitude():
    data, _ = level_turns(5.0, n=500)
    res = bs.fit_backstepping(MagFitInput(data.t_s, data.mag_ut), field_tehran())
    assert not res.ok and "roll and pitch" in res.refused


def test_nonfinite_rows_are_dropped_and_counted(tilt10):
    data, truth, _ = tilt10
    mag = np.array(data.mag_ut)
    mag[::97] = np.nan
    res = bs.fit_backstepping(MagFitInput(data.t_s, mag, data.accel_m_s2), truth["field"], attitude="accel")
    assert res.ok and res.quality["n_dropped_nonfinite"] == int(np.ceil(mag.shape[0] / 97))


def test_plot_shows_the_levelled_field_on_the_wmm_circle(tmp_path, tilt10, monkeypatch):
    """What the figure draws, against the simulated truth: the calibrated, levelled horizontal field on the
    circle of the WMM horizontal strength (the raw one off it), |H| calibrated at the total field."""
    from support.figures import line, saved_figures

    data, truth, res = tilt10
    out = tmp_path / "bs.png"
    with saved_figures(monkeypatch) as figs:
        bsplot.plot_backstepping(res, data, out)
    assert out.read_bytes()[:4] == b"\x89PNG" and len(figs) == 1
    levelled, over_time = figs[0].axes[0], figs[0].axes[1]
    field = truth["field"]
    h_ut = math.hypot(field.ned_ut[0], field.ned_ut[1])
    radius = np.linalg.norm(line(levelled, "calibrated"), axis=1)
    assert np.sqrt(np.mean((radius - h_ut) ** 2)) < 0.02 * h_ut, (radius.mean(), h_ut)
    raw_radius = np.linalg.norm(line(levelled, "raw (centred)"), axis=1)
    assert np.sqrt(np.mean((raw_radius - h_ut) ** 2)) > 0.05 * h_ut
    # |m| drawn as its departure from the reference F (named in the label), at the truth's total field
    (total_label,) = [ln.get_label() for ln in over_time.get_lines() if ln.get_label().startswith("|m| − WMM F")]
    reference_total = float(total_label.split("(")[1].split(" µT")[0])
    total = line(over_time, total_label)
    np.testing.assert_allclose(total[:, 0], data.t_s)
    assert np.median(np.abs((total[:, 1] + reference_total) / np.linalg.norm(field.ned_ut) - 1)) < 0.01


# --------------------------------------------------------------- the project's simulator (ahrsd.simulation)


def _simulator_case(scenario, seconds, seed=1):
    from ahrsd import simulation as sim
    stream = sim.open_stream(scenario, seed=seed)
    blk = stream.next_block(int(seconds * 819.2))
    site = sim.DEFAULT_SITE
    ref = earth_field(site.lat_deg, site.lon_deg, site.alt_m, site.date)
    data = MagFitInput(blk.t_s, blk.mag_ut, blk.accel_m_s2, blk.gyro_rad_s)
    return data, ref, stream.errors


def _envelope_heading_rms(model, ref, errors, tilt_deg=10.0, n=1500, seed=11):
    rng = np.random.default_rng(seed)
    roll = rng.uniform(-1, 1, n) * math.radians(tilt_deg)
    pitch = rng.uniform(-1, 1, n) * math.radians(tilt_deg)
    yaw = rng.uniform(-math.pi, math.pi, n)
    b = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll))).inv().apply(ref.ned_ut)
    raw = b @ errors.soft_iron.T + errors.hard_iron_ut + rng.normal(0, NOISE_UT, b.shape)
    err = wrap_180_deg(paper.magnetic_heading_deg(model.apply(raw), roll, pitch) - np.degrees(yaw - ref.declination_rad))
    return float(np.sqrt(np.mean(err**2)))


def test_simulated_boat_in_turns_with_centripetal_lean_fitted():
    # level-turns: 2 m/s at 9 ± 4 °/s: the accelerometer leans ~1.8° into the turn. Without compensation the
    # vertical channel absorbs the lean (≈ 1.6° heading RMS measured); with the fitted speed it does not.
    data, ref, errors = _simulator_case("level-turns", 120.0)
    res = bs.fit_backstepping(data, ref)
    assert res.ok, res.refused
    assert res.quality["attitude_source"].startswith("accelerometer")
    assert res.quality["vertical_channel"]["centripetal_speed_m_s"] == pytest.approx(2.0, abs=0.3)
    assert _envelope_heading_rms(res.model, ref, errors) < 0.7
    plain = bs.fit_backstepping(data, ref, speed_m_s=None)
    assert _envelope_heading_rms(plain.model, ref, errors) > 1.0


def test_simulated_tumble_needs_no_speed_model_and_beats_the_ellipsoid():
    data, ref, errors = _simulator_case("tumble", 60.0)
    res = bs.fit_backstepping(data, ref)
    assert res.ok, res.refused
    assert res.quality["vertical_channel"]["centripetal_speed_m_s"] is None   # not a vehicle: no speed model
    assert np.linalg.norm(res.model.hard_iron_ut - errors.hard_iron_ut) < 0.5
    rms = _envelope_heading_rms(res.model, ref, errors)
    # full sphere: no worse than the attitude-independent ellipsoid (which cannot see the non-symmetric part)
    init = vc._ellipsoid_init(data.mag_ut, ref.total_ut)
    from ahrsd.calibration.models import MagModel
    assert rms < 1.5 and rms < _envelope_heading_rms(MagModel(init[1], init[0]), ref, errors)


def test_estimator_attitude_source_follows_the_true_tilt_more_closely_than_the_accelerometer():
    from ahrsd import simulation as sim

    blk = sim.open_stream("level-turns", seed=1).next_block(int(20.0 * 819.2))
    data = MagFitInput(blk.t_s, blk.mag_ut, blk.accel_m_s2, blk.gyro_rad_s)
    roll, pitch = levelling.roll_pitch_from_estimator(data, "mekf")
    acc_roll, acc_pitch = angles.roll_pitch_from_accel(data.accel_m_s2)
    true_ypr = Rotation.from_quat(blk.truth_q_wxyz[:, [1, 2, 3, 0]]).as_euler("ZYX")   # scipy: scalar last
    late = data.t_s > 5.0
    for est, acc, truth in ((roll, acc_roll, true_ypr[:, 2]), (pitch, acc_pitch, true_ypr[:, 1])):
        err, acc_err = np.degrees(est - truth)[late], np.degrees(acc - truth)[late]
        # an unaided filter leans with the turn as the accelerometer does (~1.8°, plus the accelerometer's bias)
        assert abs(err.mean()) < 3.0, err.mean()
        # but it follows the waves (±7.5°) through the gyro, not through the accelerometer's noise: its error
        # changes from sample to sample by a small part of the accelerometer's (which its own tilt, returned
        # as the estimator's, would not)
        assert np.diff(err).std() < 0.1 * np.diff(acc_err).std(), (np.diff(err).std(), np.diff(acc_err).std())
    with pytest.raises(paper.BacksteppingError):
        levelling.roll_pitch_from_estimator(MagFitInput(data.t_s, data.mag_ut, data.accel_m_s2), "mekf")
    with pytest.raises(paper.BacksteppingError):
        levelling.roll_pitch_from_estimator(MagFitInput(data.t_s, data.mag_ut, data.accel_m_s2), "mekf")


def test_heading_reference_delay_is_applied_and_gaps_are_not_bridged():
    data, truth = level_turns(5.0, n=2000, seed=5)
    t = data.t_s
    rng = np.random.default_rng(4)
    delay = 2.0
    course = (np.interp(t - delay, t, np.degrees(np.unwrap(truth["yaw"]))) + rng.normal(0, 0.3, t.size)) % 360
    course[(t > 50) & (t < 120)] = np.nan                    # no GNSS for a while
    d = MagFitInput(t, data.mag_ut, data.accel_m_s2, None, course)
    with_delay = bs.fit_backstepping(d, truth["field"], attitude="accel", heading_ref_delay_s=delay)
    without = bs.fit_backstepping(d, truth["field"], attitude="accel")
    assert with_delay.ok and without.ok
    n_ref = with_delay.quality["heading_reference"]["n"]
    assert n_ref < 0.7 * 2000                                 # the gap stays a gap
    # 2 s at 7.2°/s: uncompensated, the reference lags by ~14°, which shows as a large scatter
    assert with_delay.quality["heading_reference"]["rms_before_deg"] < 1.0
    assert without.quality["heading_reference"]["rms_before_deg"] > 5.0


@settings(max_examples=8, deadline=None, derandomize=True)
@given(h=st.lists(st.floats(-60, 60), min_size=3, max_size=3),
       diag=st.lists(st.floats(0.8, 1.25), min_size=3, max_size=3),
       off=st.lists(st.floats(-0.08, 0.08), min_size=6, max_size=6),
       yaw_mis_deg=st.floats(-3, 3))
def test_vertical_channel_fit_is_exact_on_noise_free_tilted_turns(h, diag, off, yaw_mis_deg):
    d = np.diag(diag)
    d[np.triu_indices(3, 1)] = off[:3]
    d[np.tril_indices(3, -1)] = off[3:]
    d = Rotation.from_euler("Z", yaw_mis_deg, degrees=True).as_matrix() @ d
    n = 600
    t = np.arange(n) / n
    yaw = 4 * math.pi * t
    roll = math.radians(10) * np.sin(2 * math.pi * 7 * t)
    pitch = math.radians(10) * np.sin(2 * math.pi * 5 * t + 1)
    field = field_tehran()
    b = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll))).inv().apply(field.ned_ut)
    raw = b @ d.T + np.array(h)
    fit = vc.fit_vertical_channel(raw, roll, pitch, field.total_ut, field.down_ut)
    np.testing.assert_allclose(fit.soft_iron, np.linalg.inv(d), atol=1e-6)
    np.testing.assert_allclose(fit.hard_iron_ut, h, atol=1e-4)


def test_magnetic_disturbances_are_counted_and_down_weighted():
    data, truth = level_turns(10.0, n=3000, seed=3)
    mag = np.array(data.mag_ut)
    rng = np.random.default_rng(0)
    for start in rng.integers(0, 2900, 6):           # six 5-s disturbances of up to ~15 µT (10 % of the run)
        mag[start:start + 50] += np.outer(np.hanning(50), rng.normal(0, 8, 3))
    disturbed = MagFitInput(data.t_s, mag, data.accel_m_s2)
    res = bs.fit_backstepping(disturbed, truth["field"])
    assert res.ok and res.quality["disturbed_samples"] > 30
    assert any("disturbed" in w for w in res.quality["warnings"])
    assert heading_rms_deg(res.model, truth["field"])[0] < 0.8
    plain = bs.fit_backstepping(disturbed, truth["field"], robust=False)
    assert heading_rms_deg(plain.model, truth["field"])[0] > 1.5      # what the robust refit avoids


def test_options_dataclass_and_keywords_are_one_interface(tilt10):
    data, truth, by_keyword = tilt10
    by_options = bs.fit_backstepping(data, truth["field"], bs.BacksteppingOptions(attitude="accel"))
    np.testing.assert_array_equal(by_options.model.soft_iron, by_keyword.model.soft_iron)
    np.testing.assert_array_equal(by_options.model.hard_iron_ut, by_keyword.model.hard_iron_ut)
    strict = bs.BacksteppingOptions(attitude="accel", max_heading_std_deg=1e-6)
    assert "heading uncertain" in bs.fit_backstepping(data, truth["field"], strict).refused
    assert bs.fit_backstepping(data, truth["field"], strict, max_heading_std_deg=3.0).ok   # keywords override
    with pytest.raises(TypeError):
        bs.fit_backstepping(data, truth["field"], atitude="accel")   # a misspelt option is an error
    with pytest.raises(ValueError, match="unknown backstepping model"):
        bs.BacksteppingOptions(model="sphere")
    with pytest.raises(ValueError, match="unknown attitude source"):
        bs.fit_backstepping(data, truth["field"], attitude="gyro")


def test_estimator_without_gyro_is_a_refusal_with_its_reason(tilt10):
    data, truth, _ = tilt10
    res = bs.fit_backstepping(MagFitInput(data.t_s, data.mag_ut, data.accel_m_s2), truth["field"], attitude="mekf")
    assert res.refused is not None and "gyro" in res.refused



def test_centripetal_direction_is_the_turn_of_a_horizontal_track_not_the_hull_pitching():
    """A boat pitching in a wave without turning feels no centripetal force (its velocity stays horizontal);
    one turning at ψ̇ while rolled by φ feels ψ̇·V along the horizontal right direction, in body axes
    [0, cos φ, −sin φ]. Truth from scipy: the NED right vector rotated into the body."""
    roll, pitch, yaw = np.radians([20.0, -8.0, 40.0])
    rot = Rotation.from_euler("ZYX", [[yaw, pitch, roll]])
    down = rot.inv().apply([0.0, 0.0, 1.0])
    rate_pitch = np.array([[0.0, 0.3 * np.cos(roll), -0.3 * np.sin(roll)]])   # θ̇ = 0.3 rad/s, no turn
    assert np.allclose(vc.centripetal_direction(rate_pitch, down), 0.0, atol=1e-12)
    psi_dot = 0.15
    w_body = rot.inv().apply([0.0, 0.0, psi_dot])            # a pure turn about the vertical
    right_body = rot.inv().apply([-np.sin(yaw), np.cos(yaw), 0.0])
    assert np.allclose(vc.centripetal_direction(w_body, down), psi_dot * right_body, atol=1e-9)
