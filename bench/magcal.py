#!/usr/bin/env python3
"""Magnetometer calibration benchmark for vehicles that cannot be tumbled.

Simulated vehicle: WMM2025 field at the site, non-symmetric soft iron (a 2° yaw and 1° roll misalignment
times a symmetric distortion), hard iron of several hundred mgauss, ADIS16405
magnetometer noise (1.25 mgauss = 0.125 µT rms, datasheet), accelerometer noise and bias (roll/pitch come from
the low-passed accelerometer, as the daemon would compute them on a calm vehicle). Training data cover full
heading with tilt limited to ±2°, ±10°, ±30° or a full sphere. Independent test sets: ±10° envelope, pitch ±30°
(diving AUV) and random attitudes. Per method: hard-iron error, soft-iron shape error, heading RMS, time.

Methods: a plain least-squares ellipsoid (algebraic), an ArduPilot-style LM sphere→ellipsoid fit (the
CompassCalibrator.cpp schedule: sample thinning, 10 sphere iterations, then 15 sphere + 20 ellipsoid, λ/10
trial, fit_acceptable() checks), the sphere fit of Nourmohammadi & Sabet (J. of Control 16(3), 2022), and
ahrsd's back-stepping (vertical-channel) fit,
alone and with a GNSS-course heading reference; beside them the "field session": the same samples fed to the
field-calibration session a MAVLink client drives (it stops once its coverage is complete, so it fits on the
part of the recording it needed, and chooses its fit itself). A second table reproduces that paper's test-2 out-and-back
run (its IGRF components, legs at 62° and −117°).

    .venv/bin/python bench/magcal.py            # all tables (~1–2 min on 2 cores)
    .venv/bin/python bench/magcal.py --quick    # one seed, fewer samples
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag import backstepping as bs
from ahrsd.calibration.mag import backstepping_paper as paper
from ahrsd.calibration.mag import vertical_channel as vc
from ahrsd.calibration.mag import swing
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.calibration.models import MagModel
from ahrsd.core.angles import wrap_180_deg

G = 9.80665
SITE = dict(lat_deg=35.7, lon_deg=51.4)           # Tehran: a mid-northern-latitude site
ADIS_MAG_NOISE_UT = 0.125                          # ADIS16405 datasheet: 1.25 mgauss rms
ADIS_ACCEL_NOISE_M_S2 = 0.0353                     # ADIS16405: 3.6 mg rms (SENS_AVG default)  -> averaged below
ACCEL_BIAS_M_S2 = (0.03, -0.04, 0.02)              # ≈ 0.2–0.3° of roll/pitch error
HARD_IRON_UT = np.array([28.0, -19.0, 35.0])       # 280/−190/350 mgauss
SYM_DISTORTION = np.array([[1.08, 0.05, -0.03], [0.05, 0.93, 0.04], [-0.03, 0.04, 1.02]])  # chosen


def vehicle_distortion() -> np.ndarray:
    """measured = D·true + h, D = Rz(2°)·Rx(1°)·S (non-symmetric: a 2° constant heading error)."""
    return Rotation.from_euler("ZX", [2.0, 1.0], degrees=True).as_matrix() @ SYM_DISTORTION


def earth_field_ned():
    from ahrsd.core.wmm import earth_field
    import datetime as dt

    ef = earth_field(SITE["lat_deg"], SITE["lon_deg"], 0.0, dt.date(2026, 1, 1))
    return ef


def trajectory(kind: str, tilt_deg: float, n: int, rate_hz: float, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """roll, pitch, yaw (rad): full heading (two turns) with smooth tilt within ±tilt_deg, or 'sphere'."""
    t = np.arange(n) / rate_hz
    T = t[-1] + 1 / rate_hz
    if kind == "sphere":
        yaw = 2 * math.pi * 3 * t / T + 0.3 * np.sin(2 * math.pi * 7 * t / T)
        roll = math.pi * np.sin(2 * math.pi * 5.3 * t / T + rng.uniform(0, 6))
        pitch = math.radians(80) * np.sin(2 * math.pi * 3.7 * t / T + rng.uniform(0, 6))
        return roll, pitch, yaw
    a = math.radians(tilt_deg)
    yaw = 2 * math.pi * 2 * t / T + rng.uniform(0, 2 * math.pi)
    f = rng.uniform(5, 9, size=4)
    ph = rng.uniform(0, 2 * math.pi, size=4)
    roll = a * (0.7 * np.sin(2 * math.pi * f[0] * t / T + ph[0]) + 0.3 * np.sin(2 * math.pi * 3.1 * f[1] * t / T + ph[1]))
    pitch = a * (0.7 * np.sin(2 * math.pi * f[2] * t / T + ph[2]) + 0.3 * np.sin(2 * math.pi * 2.7 * f[3] * t / T + ph[3]))
    return roll, pitch, yaw


def test_attitudes(kind: str, n: int, rng):
    yaw = rng.uniform(-math.pi, math.pi, n)
    if kind == "level10":
        return rng.uniform(-1, 1, n) * math.radians(10), rng.uniform(-1, 1, n) * math.radians(10), yaw
    if kind == "pitch30":
        return rng.uniform(-1, 1, n) * math.radians(10), rng.uniform(-1, 1, n) * math.radians(30), yaw
    if kind == "random":
        e = Rotation.random(n, random_state=rng.integers(1 << 30)).as_euler("ZYX")
        return e[:, 2], e[:, 1], e[:, 0]
    raise ValueError(kind)


def sense(roll, pitch, yaw, field, distortion, hard_iron, rng, noise_ut=ADIS_MAG_NOISE_UT, accel=True):
    """Raw magnetometer (and accelerometer) readings for true Euler angles (body→NED ZYX)."""
    r = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll)))
    b = r.inv().apply(field.ned_ut)
    raw = b @ distortion.T + hard_iron + rng.normal(0, noise_ut, b.shape)
    acc = None
    if accel:
        acc = r.inv().apply([0.0, 0.0, -G]) + np.array(ACCEL_BIAS_M_S2) + rng.normal(0, 0.01, b.shape)
    return raw, acc, b


def simulate(kind: str, tilt_deg: float, n: int = 3000, rate_hz: float = 10.0, seed: int = 0,
             distortion=None, hard_iron=None):
    """A training recording: MagFitInput plus the truth."""
    rng = np.random.default_rng(seed)
    field = earth_field_ned()
    distortion = vehicle_distortion() if distortion is None else distortion
    hard_iron = HARD_IRON_UT if hard_iron is None else hard_iron
    roll, pitch, yaw = trajectory(kind, tilt_deg, n, rate_hz, rng)
    raw, acc, _ = sense(roll, pitch, yaw, field, distortion, hard_iron, rng)
    t = np.arange(n) / rate_hz
    return MagFitInput(t, raw, acc), dict(roll=roll, pitch=pitch, yaw=yaw, field=field, distortion=distortion,
                                          hard_iron=hard_iron)


def heading_errors_deg(model: MagModel, test_kind: str, truth: dict, n: int = 2000, seed: int = 99) -> np.ndarray:
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = test_attitudes(test_kind, n, rng)
    raw, _, _ = sense(roll, pitch, yaw, truth["field"], truth["distortion"], truth["hard_iron"], rng, accel=False)
    psi = paper.magnetic_heading_deg(model.apply(raw), roll, pitch)
    true_mag = np.degrees(yaw - truth["field"].declination_rad)
    return wrap_180_deg(psi - true_mag)


def shape_error(model: MagModel, truth: dict) -> float:
    w_true = np.linalg.inv(truth["distortion"])
    a, b = model.soft_iron.T @ model.soft_iron, w_true.T @ w_true
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ------------------------------------------------------------------------------------------------ baselines


def ls_ellipsoid(raw: np.ndarray, field_ut: float) -> MagModel | None:
    """Plain algebraic least-squares ellipsoid (10 parameters), symmetric soft iron scaled to |F|."""
    init = vc._ellipsoid_init(raw, field_ut)
    if init is None:
        return None
    w, c = init
    return MagModel(c, w)


COMPASS_CAL_NUM_SAMPLES = 300          # CompassCalibrator.h
FITNESS_TOLERANCE_MG = 16.0            # COMPASS_CAL_FIT default


def _ap_thin(samples_mg, radius_mg, start=None):
    """ArduPilot accept_sample(): keep a sample only if it is ≥ radius·2·sin(θ/2) from every kept one,
    θ from the 300-sample circle packing: A = 4π/(3F) + π/3, θ = ½·acos(cos A/(1 − cos A)), F = 2·300 − 4."""
    faces = 2 * COMPASS_CAL_NUM_SAMPLES - 4
    a = 4 * math.pi / (3 * faces) + math.pi / 3
    theta = 0.5 * math.acos(math.cos(a) / (1 - math.cos(a)))
    min_d = radius_mg * 2 * math.sin(theta / 2)
    kept = [] if start is None else list(start)
    for s in samples_mg:
        if len(kept) >= COMPASS_CAL_NUM_SAMPLES:
            break
        if not kept or np.min(np.linalg.norm(np.array(kept) - s, axis=1)) >= min_d:
            kept.append(s)
    return np.array(kept)


def _ap_residual(params, s):
    r, o, diag, off = params["radius"], params["offset"], params["diag"], params["offdiag"]
    S = np.array([[diag[0], off[0], off[1]], [off[0], diag[1], off[2]], [off[1], off[2], diag[2]]])
    return r - np.linalg.norm((s + o) @ S.T, axis=1), S


def _ap_jacobians(params, s, ellipsoid: bool):
    o, diag, off = params["offset"], params["diag"], params["offdiag"]
    res, S = _ap_residual(params, s)
    v = s + o
    A, B, C = (v @ S.T).T
    length = np.sqrt(A * A + B * B + C * C)
    jo = -np.column_stack((diag[0] * A + off[0] * B + off[1] * C, off[0] * A + diag[1] * B + off[2] * C,
                           off[1] * A + off[2] * B + diag[2] * C)) / length[:, None]
    if not ellipsoid:
        return np.column_stack((np.ones_like(A), jo)), res
    jd = -np.column_stack((v[:, 0] * A, v[:, 1] * B, v[:, 2] * C)) / length[:, None]
    joff = -np.column_stack((v[:, 1] * A + v[:, 0] * B, v[:, 2] * A + v[:, 0] * C, v[:, 2] * B + v[:, 1] * C)) / length[:, None]
    return np.column_stack((jo, jd, joff)), res


def _ap_get(params, ellipsoid):
    if ellipsoid:
        return np.concatenate((params["offset"], params["diag"], params["offdiag"]))
    return np.concatenate(([params["radius"]], params["offset"]))


def _ap_set(params, vec, ellipsoid):
    p = dict(params)
    if ellipsoid:
        p["offset"], p["diag"], p["offdiag"] = vec[:3], vec[3:6], vec[6:9]
    else:
        p["radius"], p["offset"] = vec[0], vec[1:4]
    return p


def _ap_lm_step(params, s, lam, fitness, ellipsoid):
    """One CompassCalibrator run_sphere_fit()/run_ellipsoid_fit() iteration (λ and λ/10 trials)."""
    j, res = _ap_jacobians(params, s, ellipsoid)
    jtj, jtf = j.T @ j, j.T @ res
    x = _ap_get(params, ellipsoid)
    cands = []
    for l in (lam, lam / 10):
        try:
            cands.append(x - np.linalg.solve(jtj + l * np.eye(len(x)), jtf))
        except np.linalg.LinAlgError:
            return params, lam, fitness
    fits = [float(np.mean(_ap_residual(_ap_set(params, c, ellipsoid), s)[0] ** 2)) for c in cands]
    fit1, fit2 = fits
    new_params, new_fit = params, fitness
    if fit1 > fitness and fit2 > fitness:
        lam *= 10
    elif fit2 < fitness and fit2 < fit1:
        lam /= 10
        new_params, new_fit = _ap_set(params, cands[1], ellipsoid), fit2
    elif fit1 < fitness:
        new_params, new_fit = _ap_set(params, cands[0], ellipsoid), fit1
    return new_params, lam, new_fit


def ardupilot_lm(raw_ut: np.ndarray, field_ut: float):
    """ArduPilot CompassCalibrator schedule in mgauss. Returns (MagModel | None, info dict)."""
    s_all = raw_ut * 10.0
    step1 = _ap_thin(s_all, 200.0)   # radius initialised to 200 mG
    params = dict(radius=200.0, offset=-step1.mean(axis=0), diag=np.ones(3), offdiag=np.zeros(3))
    fitness = float(np.mean(_ap_residual(params, step1)[0] ** 2))
    lam = 1.0
    for _ in range(10):
        params, lam, fitness = _ap_lm_step(params, step1, lam, fitness, False)
    # step two: thin with the fitted radius, refill to 300 from the data
    step2 = _ap_thin(step1, params["radius"])
    step2 = _ap_thin(s_all, params["radius"], start=step2)
    n2 = len(step2)
    fitness = float(np.mean(_ap_residual(params, step2)[0] ** 2))
    lam_s, lam_e = 1.0, 1.0
    for _ in range(15):
        params, lam_s, fitness = _ap_lm_step(params, step2, lam_s, fitness, False)
    for _ in range(20):
        params, lam_e, fitness = _ap_lm_step(params, step2, lam_e, fitness, True)
    fit_mg = math.sqrt(fitness)
    r = params["radius"]
    ok = (np.isfinite(fit_mg) and 150 < r < 950 and np.all(np.abs(params["offset"]) < 1800)
          and np.all((params["diag"] > 0.2) & (params["diag"] < 5)) and np.all(np.abs(params["offdiag"]) < 1)
          and fit_mg <= FITNESS_TOLERANCE_MG)
    _, S = _ap_residual(params, step2[:1])
    model = MagModel(-params["offset"] / 10.0, S * (field_ut * 10.0 / r))
    return model, {"fitness_mg": fit_mg, "accepted": bool(ok), "step2_samples": n2}


# ----------------------------------------------------------------------------------------------- benchmark


def gnss_reference(data: MagFitInput, truth: dict, rng, delay_s=2.0, noise_deg=0.5):
    """GNSS course (true heading + noise, no crab), reported delay_s late, gated with swing.gnss_course_reference."""
    t = data.t_s
    true_heading = np.degrees(truth["yaw"]) % 360.0
    reported = np.interp(t - delay_s, t, np.degrees(np.unwrap(truth["yaw"]))) % 360.0 + rng.normal(0, noise_deg, t.size)
    speed = np.full(t.size, 2.0)
    ref = swing.gnss_course_reference(t, reported, speed, delay_s=delay_s, max_turn_rate_deg_s=5.0)
    return ref, true_heading


def field_session(data: MagFitInput, roll, pitch, yaw, reference, gyro_truth=None):
    """The same samples through the field-calibration session (calibration/field.py: what a MAVLink session
    runs), with the true attitude standing in for the estimator (the session uses it for heading coverage;
    the fit levels with the accelerometer, as the offline fit does). Returns (model or None, seconds of data
    the session needed, info)."""

    from ahrsd.calibration.field import CalStatus, FieldAttitude, FieldCalConfig, FieldCalibration
    from ahrsd.calibration.models import Calibration
    from ahrsd.core.sample import make_sample

    session = FieldCalibration(Calibration.identity(), FieldCalConfig(timeout_s=1e9), reference)
    session.start()
    zeros = np.zeros(3)
    for i in range(len(data.t_s)):
        gyro = data.gyro_rad_s[i] if data.gyro_rad_s is not None else zeros
        est = FieldAttitude(roll_rad=roll[i], pitch_rad=pitch[i], yaw_rad=yaw[i],
                              rate_rad_s=None if gyro_truth is None else gyro_truth[i])
        session.add_sample(make_sample(data.t_s[i], gyro, data.accel_m_s2[i], data.mag_ut[i]), est)
        if session.status.finished:
            break
    used_s = float(data.t_s[i] - data.t_s[0])
    res = session.result
    if session.status != CalStatus.SUCCESS or res is None:
        return None, used_s, {"refused": session.fail_reason or "did not finish"}
    return res.model, used_s, {"note": f"{res.method} after {used_s:.0f} s; {res.accuracy_text()[9:]}"}


def run_methods(data, truth, *, with_reference=False, seed=0):
    field = truth["field"]
    F = field.total_ut
    out = {}
    t0 = time.perf_counter()
    m = ls_ellipsoid(data.mag_ut, F)
    out["LS ellipsoid"] = (m, time.perf_counter() - t0, {})
    t0 = time.perf_counter()
    m, info = ardupilot_lm(data.mag_ut, F)
    out["ArduPilot LM"] = (m, time.perf_counter() - t0, info)
    t0 = time.perf_counter()
    sph = paper.sphere_fit_paper(data.mag_ut, F)
    out["back-stepping paper sphere"] = (sph.model.to_mag_model() if sph.model else None, time.perf_counter() - t0, {})
    t0 = time.perf_counter()
    r = bs.fit_backstepping(data, field, attitude="accel")
    out["backstepping"] = (r.model if r.ok else None, time.perf_counter() - t0, {"refused": r.refused, "q": r.quality})
    t0 = time.perf_counter()
    m, _used_s, info = field_session(data, truth["roll"], truth["pitch"], truth["yaw"], field)
    out["field session"] = (m, time.perf_counter() - t0, info)
    if with_reference:
        rng = np.random.default_rng(seed + 1000)
        ref, _ = gnss_reference(data, truth, rng)
        d2 = MagFitInput(data.t_s, data.mag_ut, data.accel_m_s2, None, ref)
        t0 = time.perf_counter()
        r2 = bs.fit_backstepping(d2, field, attitude="accel")
        out["backstepping+GNSS"] = (r2.model if r2.ok else None, time.perf_counter() - t0,
                                    {"refused": r2.refused, "q": r2.quality})
        # known headings: a classical swing, the vehicle passing the 8 cardinal/intercardinal headings with a
        # 0.5° reference (compass-swing table), only the samples within ±2° of them
        true_heading = np.degrees(truth["yaw"]) % 360.0
        near = np.min(np.abs(wrap_180_deg(true_heading[:, None] - np.arange(0, 360, 45.0)[None, :])), axis=1) < 2.0
        known = np.where(near, true_heading + rng.normal(0, 0.5, true_heading.size), np.nan)
        d3 = MagFitInput(data.t_s, data.mag_ut, data.accel_m_s2, None, known)
        t0 = time.perf_counter()
        r3 = bs.fit_backstepping(d3, field, attitude="accel")
        out["backstepping+8 known headings"] = (r3.model if r3.ok else None, time.perf_counter() - t0,
                                                {"refused": r3.refused, "q": r3.quality})
    return out


def calibration_table(seeds, n):
    cases = [("sphere", 0.0), ("tilt ±30°", 30.0), ("tilt ±10°", 10.0), ("tilt ±2°", 2.0), ("tilt ±0.5°", 0.5)]
    rows = []
    for label, tilt in cases:
        agg: dict = {}
        for seed in seeds:
            data, truth = simulate("sphere" if label == "sphere" else "tilt", tilt, n=n, seed=seed)
            res = run_methods(data, truth, with_reference=True, seed=seed)
            for name, (model, dt, info) in res.items():
                a = agg.setdefault(name, {"hi": [], "shape": [], "h10": [], "h30": [], "hr": [], "bias10": [],
                                          "t": [], "fail": 0, "notes": set()})
                a["t"].append(dt)
                if model is None:
                    a["fail"] += 1
                    if info.get("refused"):
                        a["notes"].add("refused: " + info["refused"][:60])
                    continue
                e10 = heading_errors_deg(model, "level10", truth)
                a["hi"].append(np.linalg.norm(model.hard_iron_ut - truth["hard_iron"]))
                a["shape"].append(shape_error(model, truth) * 100)
                a["h10"].append(np.sqrt(np.mean(e10**2)))
                a["bias10"].append(np.mean(e10))
                a["h30"].append(np.sqrt(np.mean(heading_errors_deg(model, "pitch30", truth) ** 2)))
                a["hr"].append(np.sqrt(np.mean(heading_errors_deg(model, "random", truth) ** 2)))
                if "accepted" in info:
                    a["notes"].add(f"AP accept {info['accepted']} fit {info['fitness_mg']:.1f} mG n2 {info['step2_samples']}")
                if "note" in info and seed == seeds[0]:
                    a["notes"].add(info["note"])
        for name, a in agg.items():
            rows.append((label, name, a))
    print("\n## Calibration accuracy (medians over seeds %s, %d samples at 10 Hz)\n" % (list(seeds), n))
    print("| training data | method | HI err µT | SI shape err % | heading RMS ±10° test | mean (offset) ±10° | "
          "RMS pitch ±30° | RMS random att. | time s | fails | notes |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    med = lambda v: float(np.median(v)) if v else float("nan")
    for label, name, a in rows:
        notes = "; ".join(sorted(a["notes"]))[:120]
        print(f"| {label} | {name} | {med(a['hi']):.2f} | {med(a['shape']):.2f} | {med(a['h10']):.2f}° | "
              f"{med(a['bias10']):+.2f}° | {med(a['h30']):.2f}° | {med(a['hr']):.2f}° | {med(a['t']):.3f} | "
              f"{a['fail']}/{len(seeds)} | {notes} |")


# ------------------------------------------------------------------------------------- AUV out-and-back


PAPER_TEST2_HH_UT, PAPER_TEST2_HZ_UT = 27.451, 40.289   # Nourmohammadi & Sabet eq. 27 (IGRF, test-2 midpoint)


class _PaperField:
    """The paper's test-2 IGRF field as an EarthField-like object (declination ignored, eq. 5)."""

    north_ut, east_ut, down_ut = PAPER_TEST2_HH_UT, 0.0, PAPER_TEST2_HZ_UT
    declination_rad = 0.0
    inclination_rad = math.atan2(PAPER_TEST2_HZ_UT, PAPER_TEST2_HH_UT)
    ned_ut = np.array([PAPER_TEST2_HH_UT, 0.0, PAPER_TEST2_HZ_UT])
    horizontal_ut = PAPER_TEST2_HH_UT
    total_ut = math.hypot(PAPER_TEST2_HH_UT, PAPER_TEST2_HZ_UT)


def auv_out_and_back(seed: int = 0, coupling: bool = False):
    """Tests 1 and 2 of Nourmohammadi & Sabet (2022) on a steel-hull AUV. Test 1 = diver rotation (roll ±55°,
    pitch ±10°, full heading);
    test 2 = out-and-back at 62° and −117° (10 min legs, 1 min turn) with different trims on the two legs
    (−3° out, +1° back: current/ballast) and a little pitch/roll motion.

    coupling=False: the paper's situation — the vehicle is axis-aligned (diagonal model) but its vertical
    channel differs between the tests (test 1 near the surface with a diver; the paper's §4: coefficients of
    one test do not perform as expected in another): z scale ×0.62 (the paper's s_z ratio 0.16142/0.26142), z hard iron
    +10 µT in test 1. The back-stepping loop
    must recover the test-2 vertical channel.
    coupling=True: the steel hull also couples horizontal field into z (off-diagonal soft iron), which the
    diagonal model cannot represent."""
    rng = np.random.default_rng(seed)
    field = _PaperField()
    hard_iron = np.array([-18.6, 13.9, -9.0])           # the paper's eq. 26 magnitudes, in µT
    d2 = np.diag([1.05, 0.92, 0.88])
    if coupling:
        d2 = d2 + np.array([[0, 0.03, 0.02], [0.02, 0, -0.03], [0.06, -0.04, 0]])
    d1, h1 = d2.copy(), hard_iron.copy()
    if not coupling:
        d1[2, 2] *= 0.62         # the paper: s_z went 0.16142 → 0.26142 between the sphere fit and Table 6
        h1[2] += 10.0
    n1 = 3000                                            # test 1: 300 s at 10 Hz
    t1 = np.arange(n1) / 10.0
    yaw1 = 2 * math.pi * 2 * t1 / t1[-1]
    roll1 = math.radians(55) * np.sin(2 * math.pi * t1 / 60.0)
    pitch1 = math.radians(10) * np.sin(2 * math.pi * t1 / 37.0 + 1.0)
    raw1, acc1, _ = sense(roll1, pitch1, yaw1, field, d1, h1, rng)
    leg, turn = 6000, 600
    yaw2 = np.concatenate((np.full(leg, 62.0), np.linspace(62.0, 243.0, turn), np.full(leg, 243.0)))
    n2 = yaw2.size
    t2 = t1[-1] + 10.0 + np.arange(n2) / 10.0
    trim = np.concatenate((np.full(leg, -3.0), np.linspace(-3.0, 1.0, turn), np.full(leg, 1.0)))
    pitch2 = np.radians(trim + 1.0 * np.sin(2 * math.pi * np.arange(n2) / 300.0))
    roll2 = np.radians(0.5 * np.sin(2 * math.pi * np.arange(n2) / 170.0))
    raw2, acc2, _ = sense(roll2, pitch2, np.radians(yaw2), field, d2, hard_iron, rng)
    legs = np.concatenate((np.full(n1, -1), np.zeros(leg, int), np.full(turn, -1), np.ones(leg, int)))
    cal_mask = np.concatenate((np.ones(n1, bool), np.zeros(n2, bool)))
    t = np.concatenate((t1, t2))
    data = MagFitInput(t, np.vstack((raw1, raw2)), np.vstack((acc1, acc2)))
    truth = dict(field=field, distortion=d2, hard_iron=hard_iron,
                 roll=np.concatenate((roll1, roll2)), pitch=np.concatenate((pitch1, pitch2)),
                 yaw=np.concatenate((yaw1, np.radians(yaw2))))
    return data, truth, legs, cal_mask


def auv_table(seed: int = 0, coupling: bool = False):
    data, truth, legs, cal_mask = auv_out_and_back(seed, coupling)
    field = truth["field"]
    res = bs.fit_backstepping(data, field, model="paper", attitude="accel", legs=legs, calibration_mask=cal_mask,
                              rate_hz=None)
    print("\n## AUV out-and-back after Nourmohammadi & Sabet 2022 test 2"
          " (IGRF Hh 27451 nT, Hz 40289 nT; legs 62° / −117°)"
          + (" — hull with horizontal→z coupling\n" if coupling else " — vertical channel changed since test 1\n"))
    if not res.ok:
        print("refused:", res.refused)
        return
    q = res.quality["backstep"]
    sph = res.quality["sphere_fit_paper"]
    print(f"sphere fit on test 1 (roll ±55°, pitch ±10°): b = {np.round(sph['b_ut'], 3).tolist()} µT, "
          f"s = {np.round(sph['s'], 5).tolist()}")
    print(f"inter-leg |H| step with the sphere-fit coefficients: {q['step_before_ut'] * 1000:.0f} nT "
          "(paper Fig. 8: ≈1400 nT)\n")
    print("| pass | sx | sy | sz | bz µT | H_z nT | H_h nT | |H| nT | step nT | s_z from |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for p in q["passes"]:
        print(f"| {p['pass']} | {p['s'][0]:.5f} | {p['s'][1]:.5f} | {p['s'][2]:.5f} | {p['b'][2]:.3f} | "
              f"{p['hz_ut'] * 1000:.0f} | {p['hh_ut'] * 1000:.0f} | {p['total_ut'] * 1000:.0f} | {(p['step_ut'] if p['step_ut'] is not None else float('nan')) * 1000:.1f} | "
              f"{p['sz_source']} |")
    print(f"\nstop: {q['stop_reason']} (paper Table 6: 20 nT after 3 passes). Reference: H_z 40289, H_h 27451, "
          f"|H| 48752 nT.")
    gen = bs.fit_backstepping(data, field, attitude="accel", rate_hz=None, legs=legs)
    if gen.ok and "out_and_back" in gen.quality:
        print(f"general vertical-channel fit (tests 1 + 2, full soft iron): step "
              f"{gen.quality['out_and_back']['step_after_ut'] * 1000:.1f} nT")
    leg_only = bs.fit_backstepping(data.select(legs >= 0), field, attitude="accel", rate_hz=None)
    if not leg_only.ok:
        print(f"general fit on the two legs alone: refused — {leg_only.refused}")
    # heading on the legs (true heading known in the simulation)
    for name, r in (("paper (diagonal)", res), ("general", gen)):
        if r.ok:
            sel = legs >= 0
            psi = paper.magnetic_heading_deg(r.model.apply(data.mag_ut[sel]), truth["roll"][sel], truth["pitch"][sel])
            err = wrap_180_deg(psi - np.degrees(truth["yaw"][sel]))
            if name.startswith("paper"):
                for w in r.quality.get("warnings", []):
                    print("warning:", w)
            print(f"heading error on the legs, {name}: mean {err.mean():+.2f}°, RMS {np.sqrt(np.mean(err**2)):.2f}°")


# ---------------------------------------------------------------------------------- the project's simulator


def simulator_table(seed: int = 1):
    """ahrsd.simulation scenarios at 819.2 Hz with the ADIS16405 error model and the default vehicle iron;
    test sets from the same vehicle errors at other attitudes."""
    from ahrsd.simulation import DEFAULT_SITE, make_scenario, open_stream
    from ahrsd.core.wmm import earth_field

    site = DEFAULT_SITE
    ref = earth_field(site.lat_deg, site.lon_deg, site.alt_m, site.date)
    print("\n## Project simulator (ahrsd.simulation, 819.2 Hz, ADIS16405 errors, default vehicle iron)\n")
    print("| scenario | method | HI err µT | SI shape err % | heading RMS ±10° test | RMS pitch ±30° | time s | notes |")
    print("|---|---|---|---|---|---|---|---|")
    for scen, seconds in (("level-turns", 150.0), ("tumble", 90.0), ("auv-out-and-back", 600.0)):
        stream = open_stream(scen, seed=seed)
        blk = stream.next_block(int(seconds * 819.2))
        err = stream.errors
        truth = dict(field=ref, distortion=err.soft_iron, hard_iron=err.hard_iron_ut)
        data = MagFitInput(blk.t_s, blk.mag_ut, blk.accel_m_s2, blk.gyro_rad_s)
        runs = []
        t0 = time.perf_counter()
        runs.append(("LS ellipsoid", ls_ellipsoid(blk.mag_ut[::82], ref.total_ut), time.perf_counter() - t0, ""))
        t0 = time.perf_counter()
        m, info = ardupilot_lm(blk.mag_ut[::82], ref.total_ut)
        runs.append(("ArduPilot LM", m, time.perf_counter() - t0,
                     f"accept {info['accepted']}, fitness {info['fitness_mg']:.1f} mG, step-2 samples {info['step2_samples']}"))
        legs = None
        if scen == "auv-out-and-back":
            legs = make_scenario(scen).leg_of(blk.t_s)
        for label, kw in (("backstepping (auto)", {}), ("backstepping, accel, no centripetal", dict(attitude="accel", speed_m_s=None)),
                          ("backstepping, MEKF roll/pitch", dict(attitude="mekf", speed_m_s=None))):
            t0 = time.perf_counter()
            r = bs.fit_backstepping(data, ref, legs=legs, **kw)
            dt = time.perf_counter() - t0
            note = r.refused or f"attitude {r.quality['attitude_source']}"
            if r.ok:
                v = r.quality["vertical_channel"].get("centripetal_speed_m_s")
                if isinstance(v, float):
                    note += f", fitted speed {v:.2f} m/s"
                ob = r.quality.get("out_and_back")
                if ob:
                    note += (f", inter-leg step {ob['step_after_ut'] * 1000:.1f} nT (paper sphere fit on the same data: "
                             f"{ob.get('step_sphere_fit_ut', float('nan')) * 1000:.1f} nT)")
            runs.append((label, r.model if r.ok else None, dt, note))
        q = blk.truth_q_wxyz
        ypr = Rotation.from_quat(np.column_stack((q[:, 1:], q[:, :1]))).as_euler("ZYX")
        t0 = time.perf_counter()
        m, _used_s, info = field_session(data, ypr[:, 2], ypr[:, 1], ypr[:, 0], ref, blk.truth_gyro_rad_s)
        runs.append(("field session", m, time.perf_counter() - t0, info.get("note") or info.get("refused")))
        if scen == "auv-out-and-back":
            # GNSS course on the straight legs (2 s late, 0.5° noise), gated by speed and straightness
            q = blk.truth_q_wxyz
            yaw = Rotation.from_quat(np.column_stack((q[:, 1:], q[:, :1]))).as_euler("ZYX")[:, 0]
            rng = np.random.default_rng(seed)
            step = 82                                      # GNSS at 10 Hz
            tg = blk.t_s[::step]
            course = (np.interp(tg - 2.0, blk.t_s, np.degrees(np.unwrap(yaw))) + rng.normal(0, 0.5, tg.size)) % 360
            ref_deg = swing.gnss_course_reference(tg, course, np.full(tg.size, 1.5), delay_s=2.0, at_t_s=blk.t_s)
            d2 = MagFitInput(blk.t_s, blk.mag_ut, blk.accel_m_s2, blk.gyro_rad_s, ref_deg)
            t0 = time.perf_counter()
            r = bs.fit_backstepping(d2, ref, legs=legs)
            dt = time.perf_counter() - t0
            hr = r.quality.get("heading_reference", {}) if r.ok else {}
            note = r.refused or (f"GNSS course on the legs: A = {hr.get('A_only_deg', float('nan')):+.2f}° folded "
                                 f"({hr.get('note', 'full card')})")
            runs.append(("backstepping + GNSS course (legs)", r.model if r.ok else None, dt, note))
        for label, model, dt, note in runs:
            if model is None:
                print(f"| {scen} | {label} | – | – | – | – | {dt:.2f} | {note} |")
                continue
            e10 = heading_errors_deg(model, "level10", truth)
            e30 = heading_errors_deg(model, "pitch30", truth)
            print(f"| {scen} | {label} | {np.linalg.norm(model.hard_iron_ut - err.hard_iron_ut):.2f} | "
                  f"{shape_error(model, truth) * 100:.2f} | {np.sqrt(np.mean(e10**2)):.2f}° (mean {e10.mean():+.2f}°) | "
                  f"{np.sqrt(np.mean(e30**2)):.2f}° | {dt:.2f} | {note} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed, 1500 samples")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--no-simulator", action="store_true", help="skip the ahrsd.simulation scenarios (slowest part)")
    args = ap.parse_args(argv)
    seeds = [0] if args.quick else list(range(args.seeds))
    n = 1500 if args.quick else 3000
    t0 = time.perf_counter()
    calibration_table(seeds, n)
    auv_table(0, coupling=False)
    auv_table(0, coupling=True)
    if not args.no_simulator:
        simulator_table()
    print(f"\n(total bench time {time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
