"""Back-stepping on the heaving, turning boat: accelerometer levelling, GNSS-aided levelling (one pass without a
magnetometer, as first built), the true attitude (an oracle), the true attitude of the accelerometer triad
(`frame`: the best any levelling from the sensors on the vehicle can give, see below), and the aided fit
(calibration.backstepping_aided: levelled with the magnetometer, heading only, calibrated by the previous fit)
levelled by the forward filter (`fix`) and by the RTS smoother over the whole run (`rts`, the default:
estimator/ins_smoother.py), with a bench accelerometer calibration (`acal`) and with it also
aligned to the housing (`afix`), side by side.

    .venv/bin/python bench/backstepping_gnss.py                 # held-out seeds 4..8 × 2 sites
    .venv/bin/python bench/backstepping_gnss.py --seeds 1 2 3   # the tuning seeds
    .venv/bin/python bench/backstepping_gnss.py --sweep         # SETTLED_TILT_SIGMA_DEG on the tuning seeds
    .venv/bin/python bench/backstepping_gnss.py --acal-sigma-mg 1 --seeds 1 2 3 9 10 11   # another acal/afix prior
    .venv/bin/python bench/backstepping_gnss.py --levelling-params '{"yaw_align_to_gnss_yaw": false}'  # the levelling
        # filter with other InsParams (fix, rts, acal, afix)

Data: the simulator's `boat` (waves, heave, turns, 0.7 m/s current, the default vehicle iron) with ADIS16405
errors, 180 s at 200 SPS, GNSS from `simulate_gnss` (5 Hz, 1.5 m / 0.05 m/s), at DEFAULT_SITE (dip 53°) and at
60.17° N 24.94° E (dip 74°: heading 2.5× more sensitive to tilt). Each calibration is fitted on the whole run
and judged four ways, true heading error RMS in degrees, the mean offset NOT removed:

- `grid`: the calibration applied to the noise-free raw field of the same sensor and iron at other attitudes
  (every 5° of heading, roll and pitch each in −8…8°), heading tilt-compensated with that true tilt: the
  calibration's own error, what the issue asks (≤ 0.3°);
- `rec`: on the recording after 30 s, tilt-compensated with the true roll/pitch (the per-sample magnetometer
  noise adds to this one: docs/magcal-vehicle.md);
- `ins`: what a user sees: the daemon's aided estimator (ins, GNSS, magnetometer on) run over the recording with
  the calibration applied and trusted as the daemon trusts a saved `calibrate mag` result (its field residual over
  the horizontal field, calibration/heading_trust.py), its true heading against the truth after 30 s; after the
  last `/`, σ honesty: the share of those heading errors beyond 3 of the estimator's own σ.

- `op`: the heading the daemon reports at the grid's attitudes, at rest: the same calibrated
  field, tilt-compensated with the tilt of the sensor's own accelerometer (its scale, misalignment and turn-on
  bias, noise-free) less the accelerometer bias the daemon's `ins` estimated over the recording. A tilt error
  that is fixed to the body enters the calibration and the daemon's tilt alike, and partly cancels here;
  `grid` keeps it.

`acal` is the `rts` fit as a user with a bench accelerometer calibration runs it: the same sensor's guided
14-position calibration (`ahrsd calibrate accel`: faces and corners, each position's mean with 0.3 mg of noise
and in-run drift) applied to the recording, and the aided levelling told the bias is known to
ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 (calibration.backstepping_aided); its `ins` and `op` use the calibrated
accelerometer too, as the daemon would. The simulated sensor keeps its turn-on bias from the bench to the boat
(no power-up repeatability error), so this is the best case of that workflow.

`afix` is `acal` with the accelerometer calibration also aligned to the housing (`ahrsd calibrate accel
--align-to-faces`, calibration/inertial/accel_alignment.py): the six faces on a surface that is level to
FACE_PLACEMENT_DEG (each face's true up direction that far off its axis, in a random direction: a surface
levelled to about 0.02° and the unit seated on it), which brings the levelling frame to the body's (the
simulator's body is the housing).

`frame` is the oracle levelled in the accelerometer triad's own frame: the true attitude rotated by the rotation
part (skew-symmetric half) of the simulated accelerometer's misalignment matrix. No sensor on the vehicle sees
the simulator's body frame; an aided filter levels the frame its accelerometer measures in (a pure rotation of
the triad changes no measurement), so its `grid` is the floor of `grid` for any levelling from the sensors.

The last column is the levelling itself: the tilt error RMS (degrees, after 30 s, √(roll² + pitch²) against the
truth) of the aided filter without a magnetometer, forward / smoothed (one pass, no safeguard).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

SITES = {"default": None, "60N": "60.17,24.94,20,2026-06-15"}
TUNING_SEEDS = (1, 2, 3)
HELD_OUT_SEEDS = (4, 5, 6, 7, 8)
SECONDS = 180.0
RATE_HZ = 200.0
SETTLE_S = 30.0
TARGET_DEG = 0.3
CALIBRATIONS = ("plain", "gnss-1pass", "oracle", "frame", "fix", "rts", "acal", "afix")
FACE_PLACEMENT_DEG = 0.025   # `afix`: a surface levelled to ~0.02° and the unit's seating on it


def _wrap_rad(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


class BoatRun:
    """One simulated run: the recording's inputs, the truth, the sensor's true magnetometer errors."""

    def __init__(self, seed: int, site_text: str | None):
        from ahrsd.calibration.mag.fit_types import MagFitInput
        from ahrsd.simulation import DEFAULT_SITE, Site, open_stream, simulate_gnss

        site = Site.parse(site_text) if site_text else DEFAULT_SITE
        stream = open_stream("boat", rate_hz=RATE_HZ, seed=seed, site=site)
        self.block = b = stream.next_block(int(round(SECONDS * RATE_HZ)))
        self.field = stream.earth_field
        self.errors = stream.errors
        self.soft_iron, self.hard_iron_ut = stream.errors.soft_iron, stream.errors.hard_iron_ut
        self.fixes = simulate_gnss(b, rate_hz=5.0, seed=seed + 1000)   # time of validity: as REC.gnss.csv
        self.data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
        q = b.truth_q_wxyz
        ypr = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")
        self.yaw, self.pitch, self.roll = ypr[:, 0], ypr[:, 1], ypr[:, 2]
        self.late = b.t_s >= SETTLE_S
        self.accel_roll, self.accel_pitch = accel_triad_roll_pitch(q, stream.errors.accel_misalignment_rad)
        self.accel_model = bench_accel_calibration(stream.errors, site.gravity_m_s2, seed)
        self.data_acal = dataclasses.replace(self.data, accel_m_s2=np.ascontiguousarray(
            self.accel_model.apply(b.accel_m_s2)))
        self.accel_model_afix = bench_accel_calibration(stream.errors, site.gravity_m_s2, seed, align=True)
        self.data_afix = dataclasses.replace(self.data, accel_m_s2=np.ascontiguousarray(
            self.accel_model_afix.apply(b.accel_m_s2)))


def bench_accel_calibration(errors, g_m_s2: float, seed: int, align: bool = False):
    """The AccelModel `ahrsd calibrate accel` fits to this sensor: the guided positions' mean specific force
    (f = g·d for target direction d), each with 0.3 mg of noise (a 10 s mean: 0.1 mg of white noise, 0.2 mg of
    in-run instability). `align`: with `--align-to-faces`, each position's true up direction FACE_PLACEMENT_DEG
    off its target in a random direction."""
    from ahrsd.calibration.inertial.accel_alignment import align_to_faces
    from ahrsd.calibration.inertial.accel import GUIDED_TARGETS, fit_accel

    d = np.array([v for _, v in GUIDED_TARGETS], dtype=float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if align:
        off = np.cross(d, np.random.default_rng(np.random.SeedSequence([seed, 0xFACE])).normal(size=d.shape))
        off *= math.radians(FACE_PLACEMENT_DEG) / np.linalg.norm(off, axis=1, keepdims=True)
        d = Rotation.from_rotvec(off).apply(d)
    f = g_m_s2 * d
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xACA1]))
    means = f @ errors.accel_matrix.T + errors.accel_bias_m_s2 + rng.normal(0.0, 0.3e-3 * STANDARD_GRAVITY_M_S2,
                                                                            f.shape)
    fit = fit_accel(means, g_m_s2)
    if align:
        fit = align_to_faces(fit, means)
    if not fit.ok:
        raise RuntimeError(f"bench accelerometer calibration refused: {fit.refused}")
    return fit.model


def accel_triad_roll_pitch(truth_q_wxyz, accel_misalignment_rad):
    """Roll, pitch (rad) of the accelerometer triad: accel = (I + O)·f with O's skew half K·v = w×v, so to
    first order the triad reads R(w)·f and its attitude is C_nb·R(w)ᵀ."""
    k = 0.5 * (accel_misalignment_rad - accel_misalignment_rad.T)
    w = np.array([k[2, 1], k[0, 2], k[1, 0]])
    body = Rotation.from_quat(np.column_stack([truth_q_wxyz[:, 1:], truth_q_wxyz[:, :1]]))
    ypr = (body * Rotation.from_rotvec(w).inv()).as_euler("ZYX")
    return ypr[:, 2], ypr[:, 1]


def _tilt_compensated_true_heading(cal_ut, pitch, roll, declination_rad):
    level = Rotation.from_euler("ZYX", np.column_stack([np.zeros_like(pitch), pitch, roll])).apply(cal_ut)
    return np.arctan2(-level[:, 1], level[:, 0]) + declination_rad


def grid_error_deg(run: BoatRun, model, tilt_deg: float = 8.0) -> np.ndarray:
    yaw, tilt = np.radians(np.arange(0.0, 360.0, 5.0)), np.radians(np.linspace(-tilt_deg, tilt_deg, 5))
    y, p, r = (a.ravel() for a in np.meshgrid(yaw, tilt, tilt, indexing="ij"))
    body = Rotation.from_euler("ZYX", np.column_stack([y, p, r])).inv().apply(run.field.ned_ut)
    raw = body @ run.soft_iron.T + run.hard_iron_ut
    psi = _tilt_compensated_true_heading(model.apply(raw), p, r, run.field.declination_rad)
    return np.degrees(_wrap_rad(psi - y))


def recording_error_deg(run: BoatRun, model) -> np.ndarray:
    psi = _tilt_compensated_true_heading(model.apply(run.block.mag_ut), run.pitch, run.roll,
                                         run.field.declination_rad)
    return np.degrees(_wrap_rad(psi - run.yaw))[run.late]


def ins_error_deg(run: BoatRun, res, data=None):
    """The daemon's aided estimator over the recording (`data`: default run.data) with the calibration `res`
    applied and trusted as the daemon trusts a saved `calibrate mag` result (calibration/heading_trust.py rule 2:
    the fit's field residual over the site's horizontal field): its true-heading error after SETTLE_S (deg), its
    heading σ there (deg), and the estimator at the end."""
    cal = dataclasses.replace(run.data if data is None else data,
                              mag_ut=np.ascontiguousarray(res.model.apply(run.block.mag_ut)))
    trust_rad = math.atan2(res.residual_rms_ut, run.field.horizontal_ut)
    yaw, sigma, est = _yaw_from_ins(cal, run, trust_rad)
    err = np.degrees(_wrap_rad(yaw + run.field.declination_rad - run.yaw))[run.late]
    return err, np.degrees(sigma)[run.late], est


def _yaw_from_ins(data, run: BoatRun, mag_calibration_sigma_rad: float):
    from ahrsd.core.sample import make_sample
    from ahrsd.estimator.ins import Ins

    est = Ins(declination_rad=run.field.declination_rad, mag_calibration_sigma_rad=mag_calibration_sigma_rad)
    yaw, sigma = np.empty(len(data)), np.empty(len(data))
    j = 0
    for i in range(len(data)):
        while j < len(run.fixes) and run.fixes[j].t_s <= data.t_s[i]:
            est.update_gnss(run.fixes[j])
            j += 1
        out = est.update(make_sample(data.t_s[i], data.gyro_rad_s[i], data.accel_m_s2[i], data.mag_ut[i]))
        yaw[i], sigma[i] = out.yaw_rad, out.sigma_rpy_rad[2]
    return yaw, sigma, est


def beyond_3_sigma_pct(err_deg, sigma_deg) -> float:
    """σ honesty: the share (%) of heading errors beyond 3 of the estimator's own σ (≈ 0.3 % if honest)."""
    err_deg, sigma_deg = np.asarray(err_deg), np.asarray(sigma_deg)
    return 100.0 * float(np.mean(np.abs(err_deg) > 3.0 * sigma_deg)) if err_deg.size else math.nan


def operational_grid_error_deg(run: BoatRun, model, accel_bias_estimate_m_s2, tilt_deg: float = 8.0,
                               accel_model=None) -> np.ndarray:
    """`op` of the docstring: true-heading error (deg) at the grid's attitudes, at rest, levelled by the
    sensor's accelerometer (through `accel_model`, if given) less the estimated bias."""
    yaw, tilt = np.radians(np.arange(0.0, 360.0, 5.0)), np.radians(np.linspace(-tilt_deg, tilt_deg, 5))
    y, p, r = (a.ravel() for a in np.meshgrid(yaw, tilt, tilt, indexing="ij"))
    to_body = Rotation.from_euler("ZYX", np.column_stack([y, p, r])).inv()
    raw_mag = to_body.apply(run.field.ned_ut) @ run.soft_iron.T + run.hard_iron_ut
    f = to_body.apply([0.0, 0.0, -STANDARD_GRAVITY_M_S2])        # specific force at rest, body frame
    f = f @ run.errors.accel_matrix.T + run.errors.accel_bias_m_s2
    f = (f if accel_model is None else accel_model.apply(f)) - accel_bias_estimate_m_s2
    roll, pitch = np.arctan2(-f[:, 1], -f[:, 2]), np.arctan2(f[:, 0], np.hypot(f[:, 1], f[:, 2]))
    psi = _tilt_compensated_true_heading(model.apply(raw_mag), pitch, roll, run.field.declination_rad)
    return np.degrees(_wrap_rad(psi - y))


def calibrations(run: BoatRun, settled_tilt_sigma_deg: float | None = None,
                 acal_sigma_m_s2: float | None = None, levelling_params: dict | None = None,
                 names=None) -> dict:
    """name -> MagFitResult. `acal_sigma_m_s2`: the `acal` bias prior (default ACCEL_BIAS_SIGMA_CALIBRATED_M_S2);
    `levelling_params`: InsParams overrides of the aided levelling filter (`filter_overrides`); `names`: only these
    calibrations (default all, CALIBRATIONS)."""
    from ahrsd.calibration.accel_trust import ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
    from ahrsd.calibration.mag.backstepping_aided import SETTLED_TILT_SIGMA_DEG, fit_backstepping_aided
    from ahrsd.calibration.mag.levelling import roll_pitch_from_estimator
    from ahrsd.calibration.mag.fit import fit_mag

    thr = SETTLED_TILT_SIGMA_DEG if settled_tilt_sigma_deg is None else settled_tilt_sigma_deg
    decl = run.field.declination_rad
    acal_sigma = acal_sigma_m_s2 or ACCEL_BIAS_SIGMA_CALIBRATED_M_S2

    def one_pass_levelled():
        roll1, pitch1 = roll_pitch_from_estimator(run.data, "ins", fixes=run.fixes, declination_rad=decl,
                                                  mag_enabled=False)
        return fit_mag("backstepping", run.data, run.field, roll_rad=roll1, pitch_rad=pitch1, speed_m_s=None)

    fits = {
        "plain": lambda: fit_mag("backstepping", run.data, run.field),
        "gnss-1pass": one_pass_levelled,
        "oracle": lambda: fit_mag("backstepping", run.data, run.field, roll_rad=run.roll, pitch_rad=run.pitch,
                                  speed_m_s=None),
        "frame": lambda: fit_mag("backstepping", run.data, run.field, roll_rad=run.accel_roll,
                                 pitch_rad=run.accel_pitch, speed_m_s=None),
        "fix": lambda: fit_backstepping_aided(run.data, run.fixes, run.field, decl, settled_tilt_sigma_deg=thr,
                                              smooth=False, filter_overrides=levelling_params),
        "rts": lambda: fit_backstepping_aided(run.data, run.fixes, run.field, decl, settled_tilt_sigma_deg=thr,
                                              smooth=True, filter_overrides=levelling_params),
        "acal": lambda: fit_backstepping_aided(run.data_acal, run.fixes, run.field, decl, settled_tilt_sigma_deg=thr,
                                               accel_bias_sigma_m_s2=acal_sigma, filter_overrides=levelling_params),
        "afix": lambda: fit_backstepping_aided(run.data_afix, run.fixes, run.field, decl, settled_tilt_sigma_deg=thr,
                                               accel_bias_sigma_m_s2=acal_sigma, filter_overrides=levelling_params),
    }
    return {name: fits[name]() for name in (CALIBRATIONS if names is None else names)}


def levelling_tilt_error_deg(run: BoatRun) -> tuple[float, float]:
    """Tilt error RMS after SETTLE_S of the aided filter without a magnetometer: forward, smoothed."""
    from ahrsd.calibration.mag.levelling import attitude_from_estimator
    from ahrsd.estimator.ins_smoother import SmoothingIns

    est = SmoothingIns(declination_rad=run.field.declination_rad, mag_enabled=False)
    roll, pitch, _ = attitude_from_estimator(run.data, "ins", fixes=run.fixes, estimator=est)
    roll_s, pitch_s, _ = est.smoothed_roll_pitch()
    return tuple(_rms(np.degrees(np.hypot(_wrap_rad(r - run.roll), _wrap_rad(p - run.pitch)))[run.late])
                 for r, p in ((roll, pitch), (roll_s, pitch_s)))


def sweep(seeds, sites) -> None:
    from ahrsd.calibration.mag.backstepping_aided import fit_backstepping_aided

    thresholds = (0.2, 0.3, 0.4, 1e9)
    print("# settled_tilt_sigma_deg sweep, grid heading RMS, degrees; 1e9 = fit every sample (the default)")
    print(f"{'site':8s} {'seed':>4s} " + "".join(f"{t:>8g}" for t in thresholds))
    cols = []
    for label, text in sites.items():
        for seed in seeds:
            run = BoatRun(seed, text)
            row = []
            for thr in thresholds:
                res = fit_backstepping_aided(run.data, run.fixes, run.field, run.field.declination_rad,
                                             settled_tilt_sigma_deg=thr)
                row.append(_rms(grid_error_deg(run, res.model)) if res.ok else math.nan)
            cols.append(row)
            print(f"{label:8s} {seed:4d} " + "".join(f"{v:8.3f}" for v in row), flush=True)
    print(f"{'mean':13s} " + "".join(f"{v:8.3f}" for v in np.nanmean(np.array(cols), axis=0)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help=f"default: held-out {HELD_OUT_SEEDS}")
    ap.add_argument("--sites", nargs="+", default=list(SITES), choices=list(SITES))
    ap.add_argument("--sweep", action="store_true", help="sweep SETTLED_TILT_SIGMA_DEG on the tuning seeds")
    ap.add_argument("--no-ins", action="store_true", help="skip the daemon-estimator column (faster)")
    ap.add_argument("--acal-sigma-mg", type=float, default=None,
                    help="the acal and afix columns' accelerometer-bias prior, mg (default: the CLI's, 2)")
    ap.add_argument("--calibrations", nargs="+", choices=CALIBRATIONS, default=list(CALIBRATIONS),
                    help="only these columns (e.g. `--calibrations afix --no-ins`: the README's column alone)")
    ap.add_argument("--offset-split", action="store_true",
                    help="per run and aided fit: its grid's constant offset beside the offset its levelling's tilt "
                         "error implies (all, slower than 20 s, faster)")
    ap.add_argument("--levelling-params", type=json.loads, default=None,
                    help="InsParams overrides of the aided levelling filter (fix, rts, acal, afix) as JSON")
    args = ap.parse_args(argv)
    logging.getLogger("ahrsd.estimator.ins").setLevel(logging.ERROR)   # the failing runs' resets: counted instead
    sites = {k: SITES[k] for k in args.sites}
    if args.sweep:
        sweep(args.seeds or TUNING_SEEDS, sites)
        return 0
    seeds = args.seeds or HELD_OUT_SEEDS
    names = tuple(args.calibrations)
    hdr = _print_header(seeds, names, args.levelling_params)
    t0 = time.perf_counter()
    acal_sigma = None if args.acal_sigma_mg is None else args.acal_sigma_mg * 1e-3 * STANDARD_GRAVITY_M_S2
    table = {n: [] for n in names}
    tilts = []
    for label, text in sites.items():
        for seed in seeds:
            run = BoatRun(seed, text)
            line = f"{label:8s} {seed:4d} "
            fits = calibrations(run, acal_sigma_m_s2=acal_sigma, levelling_params=args.levelling_params, names=names)
            for name, res in fits.items():
                cells, text_cell = _calibration_cells(run, name, res, args.no_ins)
                table[name].append(cells)
                line += text_cell
            tilts.append(levelling_tilt_error_deg(run))
            line += f"{tilts[-1][0]:7.3f}/{tilts[-1][1]:5.3f}"
            print(line, flush=True)
            for name, res in (fits.items() if args.offset_split else ()):
                if res.ok and res.levelling is not None:
                    mean, whole, slow, fast = levelling_offset_deg(run, res)
                    print(f"    {name}: grid offset {mean:+.3f}°; the levelling's tilt error as a rotation about the "
                          f"vertical {whole:+.3f}° (slower than {SLOW_S:g} s {slow:+.3f}°, faster {fast:+.3f}°)",
                          flush=True)
    print("-" * len(hdr))
    _print_aggregates(names, table, tilts)
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


def _print_header(seeds, names, levelling_params) -> str:
    """The title (which seeds: tuning, held-out or mixed) and the column header; returns the header line."""
    kind = "tuning" if set(seeds) <= set(TUNING_SEEDS) else ("held-out" if not set(seeds) & set(TUNING_SEEDS)
                                                            else "mixed")
    print(f"# back-stepping on the boat, {SECONDS:.0f} s, {kind} seeds {list(seeds)}: true-heading RMS (deg, mean "
          f"offset kept; target ≤ {TARGET_DEG}), grid / rec / ins / op (see the docstring) / ins heading errors "
          f"beyond 3σ")
    if levelling_params:
        print(f"# the aided levelling filter with {json.dumps(levelling_params)}")
    hdr = f"{'site':8s} {'seed':>4s} " + "".join(f"{n:>34s}" for n in names) + f"{'tilt fwd/rts':>14s}"
    print(hdr)
    print("-" * len(hdr))
    return hdr


def _calibration_cells(run: BoatRun, name: str, res, no_ins: bool):
    """One calibration's (grid, recording, ins, operational RMS, ins beyond 3σ %) and its table cell; NaNs and
    "refused" for a refused fit."""
    if not res.ok:
        return (math.nan,) * 5, f"{'refused':>34s}"
    g = _rms(grid_error_deg(run, res.model))
    r = _rms(recording_error_deg(run, res.model))
    data, accel_model = {"acal": (run.data_acal, run.accel_model),
                         "afix": (run.data_afix, run.accel_model_afix)}.get(name, (None, None))
    i, h, est = (math.nan, math.nan, None) if no_ins else ins_error_deg(run, res, data)
    h = math.nan if est is None else beyond_3_sigma_pct(i, h)
    o = math.nan if est is None else _rms(operational_grid_error_deg(
        run, res.model, est.accel_bias_m_s2, accel_model=accel_model))
    return (g, r, _rms(i), o, h), f"{g:8.2f}/{r:5.2f}/{_rms(i):5.2f}/{o:5.2f}/{h:4.1f}%"


SLOW_S = 20.0    # --offset-split: the levelling's tilt error slower than this (a moving mean) against the rest


def levelling_offset_deg(run: BoatRun, res) -> tuple[float, float, float, float]:
    """`--offset-split`: the fit's constant heading offset on the grid (mean of `grid`, deg) beside the offset its
    levelling's tilt error implies, all of it, its part slower than SLOW_S and the rest (deg). The fit sees a
    rotation A of the calibrated field c about body z only through the tilt: the levelled vertical c·d moves by
    A·g with g = c_x d_y − c_y d_x (d the down direction in the body), while a levelling tilt error moves it by
    e = c·δd. Least squares over the fitted samples reads e as A = Σ g e / Σ g² (centred), with c and d from the
    simulator's truth (scipy), δd the difference of the levelling's down direction from the true one."""
    from scipy.ndimage import uniform_filter1d

    roll, pitch, used = res.levelling
    q = run.block.truth_q_wxyz
    c = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).inv().apply(run.field.ned_ut)

    def down(r, p):
        return np.column_stack([-np.sin(p), np.sin(r) * np.cos(p), np.cos(r) * np.cos(p)])

    d = down(run.roll, run.pitch)
    e = np.einsum("ij,ij->i", c, down(roll, pitch) - d)
    g = c[:, 0] * d[:, 1] - c[:, 1] * d[:, 0]
    e_slow = uniform_filter1d(e, int(round(SLOW_S * RATE_HZ)))
    used = np.asarray(used, dtype=bool)
    gc = g[used] - g[used].mean()

    def offset(x):
        x = x[used] - x[used].mean()
        return math.degrees(float(np.sum(gc * x) / np.sum(gc * gc)))

    return (float(np.mean(grid_error_deg(run, res.model))), offset(e), offset(e_slow), offset(e - e_slow))


def _print_aggregates(names, table: dict, tilts: list) -> None:
    """The mean and worst row of every column (NaN-aware: refused fits and skipped ins are left out)."""
    for agg, fn in (("mean", np.nanmean), ("worst", np.nanmax)):
        line = f"{agg:13s} "
        for name in names:
            g, r, i, o, h = fn(np.array(table[name]), axis=0)
            line += f"{g:8.2f}/{r:5.2f}/{i:5.2f}/{o:5.2f}/{h:4.1f}%"
        tf, ts = fn(np.array(tilts), axis=0)
        print(line + f"{tf:7.3f}/{ts:5.3f}")


if __name__ == "__main__":
    raise SystemExit(main())
