"""Where ins's heading error on a vehicle without magnetometer calibration comes from, split with the simulator's
truth (docs/gnss.md "The uncalibrated boat at a weak field: the vertical gyro's bias / scale split is not the
limit, its white noise is").

    .venv/bin/python bench/heading_split.py --site 69.65,18.96 [--scenario boat] [--seeds 12 13 15 16] [--rows …]
        [--iron unseen] [--seconds 900]

Each seed is run (the place's own iron or `--iron`'s, 600 s, GNSS 5 Hz) once per row:
  defaults            ins as it is, the sensor as simulated (SensorErrors.adis16405(seed)), no calibration;
  s_z truth           the vertical gyro's scale-factor error written into the filter at the simulator's value at
                      every sample, its covariance row and column cleared (an oracle: the filter's private state,
                      for diagnosis only);
  b_z truth           the vertical gyro's turn-on bias likewise (the in-run Gauss–Markov part is not in it);
  b_z truth before 180 s / from 180 s   that hold only before / only from 180 s (where the errors are counted
                      from): whether the bias error that matters is the one the start leaves or the one after;
  b_z,s_z truth       both;
  turn-on 0           the sensor without its turn-on errors (gyro and accelerometer bias, scale, misalignment,
                      temperature coefficients); white noise and in-run bias processes as simulated, filter unchanged;
  turn-on 0, no ARW   that, and the gyro's white noise (angle random walk) removed;
  turn-on 0, no VRW   that, and the accelerometer's white noise removed instead;
  turn-on 0, no in-run  that, and the in-run bias processes (gyro and accelerometer) removed instead;
  yaw aid 1°          the sensor as simulated, and at every fix a heading measurement of the truth with 1° of
                      white noise fused into the filter: what a heading reference on the straight legs (a water
                      track, a second antenna) would be worth at most;
  yaw aid 1° + 1° over 60 s   the same aid with a slowly varying error as well (first-order Gauss–Markov, 1°,
                      60 s, from 0 at the first aid: within 1 % of its stationary variance by 180 s; a water
                      track's leeway that changes with the wind), fused as ins fuses a correlated heading (its
                      variance inflated by τ/Δt, ins_core._fuse_mag_heading);
  iron at true attitude   the iron learner fed the simulator's attitude instead of the filter's (an oracle: what a
                      learner that no yaw error of its learning window reaches would give; the learner's covariance
                      still counts the filter's attitude σ) — docs/gnss.md "The learning window's yaw error";
  no magnetometer     ins without its magnetometer (`mag_enabled` false): the GNSS–inertial heading alone;
  receiver errors 0   the GNSS fixes without their position and velocity errors, their reported accuracies kept
                      (the filter weights them as before);
  receiver errors 0, noise 0   that, and the sensor without its white noise (gyro, accelerometer, magnetometer) and
                      in-run bias processes, its turn-on errors kept: what is left is what the filter's model makes
                      of the turn-on errors and the iron alone, no draw of noise (a model error, if any, shows here);
  rotation tilt term 0    the magnetometer's turning (estimator/mag_rotation.py) fitted without the term for the
                      filter's tilt moving between a window's ends (√2·tan|dip|·σ_tilt / T): an upper bound of
                      what a tilt-change model smaller than that term could give, not an honest variance —
                      docs/gnss.md "The uncalibrated boat's tail at Halifax";
  fused while learning    the rejected magnetometer fused at its learned iron's honest variance while the iron is
                      learned at every place (magnetometer_use.rejected_magnetometer_fused as where the floor keeps
                      it from ever being trusted), not only where its floor is above the trust limit;
  offset as a state   where the magnetometer is fused while its iron is learned and the learned offset is held
                      (IronLearner.hold_offset), that offset's error carried as the harmonic state c0 (prior: the
                      learner's offset variance with the window's yaw share, the other four harmonics off), the rest
                      fused as noise as before less the learner's offset variance (at least the floor) — a
                      candidate, tried, not kept (docs/gnss.md "(iron37)");
  offset as a state, with the yaw   that, c0 started correlated with the filter's yaw as own + Γ·δθ_D (Γ: how much
                      of a yaw error common to the learning window the learned offset took in; own: the learner's
                      offset variance without the share), not after a yaw reset.
Per seed and row: heading and tilt RMS from 180 s, the share of heading errors beyond 3σ (published σ) from 30 s,
the vertical gyro bias's error RMS from 180 s (°/h, against the turn-on bias) and its scale-factor error at the end.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.vehicle_accuracy import (GNSS_ERRORS, HONESTY_IRONS, estimates_in_arrival_order,  # noqa: E402
                                    honesty_site, honesty_site_arg, simulate_vehicle, tilt_heading_errors_deg)

EVERY = 8
ROWS = ("defaults", "s_z truth", "b_z truth", "b_z truth before 180 s", "b_z truth from 180 s", "b_z,s_z truth", "turn-on 0", "turn-on 0, no ARW", "turn-on 0, no VRW",
        "turn-on 0, no in-run", "yaw aid 1°", "yaw aid 1° + 1° over 60 s", "iron at true attitude",
        "no magnetometer", "receiver errors 0", "receiver errors 0, noise 0", "rotation tilt term 0", "fused while learning",
        "offset as a state", "offset as a state, with the yaw")
YAW_AID_SIGMA_DEG = 1.0
YAW_AID_DRIFT_DEG, YAW_AID_DRIFT_TAU_S = 1.0, 60.0
FIX_EVERY_S = 0.2
LATE_S = 180.0          # the heading has settled by then on every seed (docs/gnss.md, heading_timeline)


def sensor_errors(seed: int, row: str):
    """The simulated sensor's errors for `row`: SensorErrors.adis16405(seed), with the row's terms removed."""
    from ahrsd.simulation import SensorErrors

    err = SensorErrors.adis16405(seed)
    if row == "receiver errors 0, noise 0":
        return err.replace(gyro_noise_density_rad_s_rthz=0.0, accel_noise_density_m_s2_rthz=0.0,
                           mag_noise_density_ut_rthz=0.0, gyro_bias_instability_rad_s=0.0,
                           accel_bias_instability_m_s2=0.0)
    if not row.startswith("turn-on 0"):
        return err
    zero = {name: np.zeros_like(getattr(err, name)) for name in (
        "gyro_bias_rad_s", "gyro_scale", "gyro_misalignment_rad", "gyro_bias_temp_rad_s_per_c", "accel_bias_m_s2",
        "accel_scale", "accel_misalignment_rad", "accel_bias_temp_m_s2_per_c")}
    err = err.replace(**zero)
    if row.endswith("no ARW"):
        err = err.replace(gyro_noise_density_rad_s_rthz=0.0)
    elif row.endswith("no VRW"):
        err = err.replace(accel_noise_density_m_s2_rthz=0.0)
    elif row.endswith("no in-run"):
        err = err.replace(gyro_bias_instability_rad_s=0.0, accel_bias_instability_m_s2=0.0)
    return err


def _hold(est, index: int, value: float) -> None:
    """Oracle: error-state component `index` (the vertical gyro's bias or scale factor) set to `value` in the
    filter's state, its covariance row and column cleared."""
    from ahrsd.estimator import ins_core as core

    if index == core.E_BG + 2:
        est._x["gyro_bias_rad_s"][2] = value
    elif index == core.E_SG + 2:
        est._x["gyro_scale"][2] = value
    else:
        raise ValueError(f"no hold for error state {index}")
    est._P[index, :] = 0.0
    est._P[:, index] = 0.0


def _fuse_truth_heading(est, heading_error_rad: float, sigma_rad: float) -> None:
    """Oracle: a heading measurement of the truth (the caller adds its white noise to the published heading's
    error), fused as the magnetometer's heading is (row −e_yaw, ins_core._mag_heading_row: the innovation is the
    predicted heading's error, estimate − measurement)."""
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.constrained_update import scalar_update

    h = np.zeros(core.N_ERR)
    h[core.E_YAW] = -1.0
    dx = np.zeros(core.N_ERR)
    scalar_update(est._P, h, heading_error_rad, sigma_rad ** 2, 0, dx)
    core._apply_correction(est._x, est._par, dx)


def gnss_errors(row: str):
    """The receiver's errors for `row`: the benches' (vehicle_accuracy.GNSS_ERRORS), or for the "receiver errors 0"
    rows none, with the same reported accuracies (None: the benches' own)."""
    from ahrsd.simulation import GnssErrors

    if not row.startswith("receiver errors 0"):
        return None
    return GnssErrors(horizontal_m=0.0, vertical_m=0.0, velocity_m_s=0.0, h_acc_m=GNSS_ERRORS["horizontal_m"],
                      v_acc_m=GNSS_ERRORS["vertical_m"], s_acc_m_s=GNSS_ERRORS["velocity_m_s"])


def learn_iron_at_truth(est, run) -> None:
    """Oracle: `est`'s iron learner fed the simulator's attitude at the filter's latest sample instead of the
    filter's own (the rest of the learning step as it is: HeadingSupervision._learn_iron)."""
    from ahrsd.estimator.heading_supervision import HeadingSupervision
    from ahrsd.estimator.rotations import quat_to_dcm

    def learn(t_s, c_bn, field):
        k = min(int(np.searchsorted(run.t_s, float(est._x["t_last_s"]))), len(run.t_s) - 1)
        HeadingSupervision._learn_iron(est._heading, t_s, np.asarray(quat_to_dcm(run.truth_q_wxyz[k]), dtype=float), field)

    est._heading._learn_iron = learn


def without_rotation_tilt_term(est) -> None:
    """`est`'s magnetometer-rotation windows (MagRotationBias.add) given a tilt 1σ of 0: their fit leaves out the
    filter's tilt moving between the window's ends."""
    rotation = est._heading._mag_rotation
    add = rotation.add

    def add_without_tilt(*args):
        return add(*args[:-1], 0.0)

    rotation.add = add_without_tilt


def offset_as_state(est, with_yaw: bool) -> None:
    """`est`'s learned heading offset carried as the harmonic state c0 while the iron is learned, where the
    magnetometer is fused meanwhile and the offset is held (the rows "offset as a state" and "…, with the yaw"):
    MagErrorStates.select and restart_harmonics patched on the instance; with `with_yaw` the window's yaw share is
    also tracked per radian (WindowYawShare.step's recursion without the σ) for Γ."""
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator import mag_error_states as mes
    from ahrsd.estimator.mag_error_restarts import IRON_HARMONIC_YAWS_RAD, restart_harmonics

    sup, errors, iron, par = est._heading, est._mag_errors, est._learned_iron, est._par
    per_rad = np.zeros_like(iron.yaw_share.share)
    step, reset = iron.yaw_share.step, iron.yaw_share.reset

    def step_per_rad(gain, jacobian, attitude_jacobian, yaw_sigma_rad):
        step(gain, jacobian, attitude_jacobian, yaw_sigma_rad)
        k = np.asarray(gain, dtype=float)
        per_rad[:] = per_rad - k @ (np.asarray(jacobian, dtype=float) @ per_rad) \
            + k @ np.asarray(attitude_jacobian, dtype=float)[:, 2]

    def reset_per_rad():
        reset()
        per_rad[:] = 0.0

    iron.yaw_share.step, iron.yaw_share.reset = step_per_rad, reset_per_rad

    def offset_prior(p, field, declination):
        prior = np.zeros((5, 5))
        prior[0, 0] = errors.iron_prior(p, field, declination)[0, 0]
        return prior

    def correlate(field):
        # Γ: the learned magnetometer's heading error (read − true) per radian of the window's yaw error is
        # row·per_rad; c0 is the field azimuth's error, its opposite (the kernel's row is −δθ_D + c0)
        row = np.mean(iron.learner.level_heading_rows(field, IRON_HARMONIC_YAWS_RAD), axis=0)
        gamma = -float(row @ per_rad)
        P = est._P
        cross = gamma * P[core.E_YAW, :]
        P[core.E_MH, :] = cross
        P[:, core.E_MH] = cross
        P[core.E_MH, core.E_MH] = float(row @ iron.learner.cov @ row) + gamma * gamma * P[core.E_YAW, core.E_YAW]

    select, restart = errors.select, errors.restart_harmonics

    def select_offset(p, source, field, declination):
        learner = iron.learner
        if (source is None and field is not None and field[0] ** 2 + field[1] ** 2 > 0.0 and sup.monitor.learning
                and par["mag_use"] > 0.5 and learner.offset_held and sup.ever_aided and iron.learned
                and p.mag_harmonic_states and p.mag_enabled):
            was = errors.source
            errors.source = "offset"
            par["mag_harmonics_on"] = 1.0
            par["mag_harmonic_residual_var_rad2"] = max(float(par["mag_bias_var_rad2"])
                                                        - learner.offset_heading_variance(field),
                                                        mes.learned_floor_var_rad2(p, field[0] ** 2 + field[1] ** 2))
            if was != "offset":
                restart_harmonics(est._x, est._P, offset_prior(p, field, declination))
                if with_yaw:
                    correlate(field)
            errors.set_frame_tilt(p)
            return
        select(p, source, field, declination)

    def restart_offset(p, field, declination):
        if errors.source == "offset" and par["mag_harmonics_on"] > 0.0:
            restart_harmonics(est._x, est._P, offset_prior(p, field, declination))
            return
        restart(p, field, declination)

    errors.select, errors.restart_harmonics = select_offset, restart_offset


def one_run(job, late_s: float = LATE_S) -> tuple:
    """One seed and row, `_one_run`'s figures; "fused while learning" with the place's floor taken as above the trust
    limit for the run (magnetometer_use.never_trusted_here), restored after it."""
    from ahrsd.estimator import magnetometer_use

    if job[2] != "fused while learning":
        return _one_run(job, late_s)
    kept = magnetometer_use.never_trusted_here
    magnetometer_use.never_trusted_here = lambda floor_var, trusted_sigma, yaw_var: floor_var is not None
    try:
        return _one_run(job, late_s)
    finally:
        magnetometer_use.never_trusted_here = kept


def _one_run(job, late_s: float = LATE_S) -> tuple:
    """One seed and row (job = scenario, seed, row, seconds, site[, iron]); the errors from `late_s` (heading, tilt,
    bias) and from 30 s (the share beyond 3σ)."""
    from ahrsd.estimator import ins_core as core
    from ahrsd.estimator.ins import Ins

    scen, seed, row, seconds, site_label = job[:5]
    site, iron = honesty_site(site_label, job[5] if len(job) > 5 else None)
    err = sensor_errors(seed, row)
    run = simulate_vehicle(scen, seconds, seed, site, mag="uncalibrated", iron=iron, errors=err,
                           gnss_errors=gnss_errors(row))
    est = Ins(declination_rad=run.declination_rad, lever_arm_m=run.lever_arm_m,
              mag_calibration_sigma_rad=run.mag_calibration_sigma_rad, mag_enabled=row != "no magnetometer")
    if row == "iron at true attitude":
        learn_iron_at_truth(est, run)
    if row == "rotation tilt term 0":
        without_rotation_tilt_term(est)
    if row.startswith("offset as a state"):
        offset_as_state(est, with_yaw=row.endswith("with the yaw"))
    holds = {"s_z truth": [(core.E_SG + 2, err.gyro_scale[2])],
             "b_z truth": [(core.E_BG + 2, err.gyro_bias_rad_s[2])],
             "b_z truth before 180 s": [(core.E_BG + 2, err.gyro_bias_rad_s[2])],
             "b_z truth from 180 s": [(core.E_BG + 2, err.gyro_bias_rad_s[2])],
             "b_z,s_z truth": [(core.E_BG + 2, err.gyro_bias_rad_s[2]), (core.E_SG + 2, err.gyro_scale[2])]}.get(row, [])
    hold_from_s, hold_to_s = {"b_z truth before 180 s": (-math.inf, late_s),
                              "b_z truth from 180 s": (late_s, math.inf)}.get(row, (-math.inf, math.inf))
    aid = row.startswith("yaw aid")
    drift = row.endswith("over 60 s")
    rng = np.random.default_rng(seed + 2000)
    drift_rad = 0.0
    t = run.t_s
    keep = np.arange(0, len(t), EVERY)
    q = np.empty((len(keep), 4))
    sig = np.empty(len(keep))
    bz = np.empty(len(keep))
    next_aid_s = 0.0
    j = 0
    for k, e in estimates_in_arrival_order(est, run, run.fixes):
        if est._initialised:
            if hold_from_s <= t[k] < hold_to_s:
                for index, value in holds:
                    _hold(est, index, value)
            if aid and t[k] >= next_aid_s and est._x["nav_ok"] > 0.0:
                _, hdg = tilt_heading_errors_deg(e.q_wxyz[None, :], run.truth_q_wxyz[k][None, :],
                                                 run.declination_rad)
                sigma = math.radians(YAW_AID_SIGMA_DEG)
                noise_rad, var = sigma * rng.standard_normal(), sigma ** 2
                if drift:
                    phi = math.exp(-FIX_EVERY_S / YAW_AID_DRIFT_TAU_S)
                    sd = math.radians(YAW_AID_DRIFT_DEG)
                    drift_rad = phi * drift_rad + sd * math.sqrt(1.0 - phi * phi) * rng.standard_normal()
                    noise_rad += drift_rad
                    var += sd ** 2 * YAW_AID_DRIFT_TAU_S / FIX_EVERY_S
                _fuse_truth_heading(est, math.radians(float(hdg[0])) + noise_rad, math.sqrt(var))
                next_aid_s = t[k] + FIX_EVERY_S
        if k % EVERY == 0:
            q[j], sig[j], bz[j] = e.q_wxyz, e.sigma_rpy_rad[2], est._x["gyro_bias_rad_s"][2]
            j += 1
    tk = t[keep]
    tilt, hdg = tilt_heading_errors_deg(q, run.truth_q_wxyz[keep], run.declination_rad)
    late, honest = tk >= late_s, tk >= 30.0
    return job, (float(np.sqrt(np.mean(hdg[late] ** 2))), float(np.sqrt(np.mean(tilt[late] ** 2))),
                 float(np.mean(np.abs(hdg[honest]) > 3.0 * np.degrees(sig[honest]))),
                 math.degrees(float(np.sqrt(np.mean((bz[late] - err.gyro_bias_rad_s[2]) ** 2)))) * 3600.0,
                 100.0 * float(est._x["gyro_scale"][2] - err.gyro_scale[2]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="boat")
    ap.add_argument("--site", type=honesty_site_arg, default="held-out",
                    help='"held-out", "default" or a place "LAT,LON[,ALT_M[,YYYY-MM-DD]]" (default held-out)')
    ap.add_argument("--iron", choices=HONESTY_IRONS, default=None,
                    help="the vehicle iron instead of the site's own (a place's own: held-out)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[12, 13, 15, 16])
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--processes", type=int, default=1)
    args = ap.parse_args(argv)
    # the simulated sensors' and estimators' warnings would bury the table; here, in main, not in one_run:
    # the pool's workers inherit it, and a test that calls one_run keeps its logging
    logging.disable(logging.WARNING)
    jobs = [(args.scenario, s, r, args.seconds, args.site, args.iron) for s in args.seeds for r in args.rows]
    iron = f", iron {args.iron}" if args.iron else ""
    print(f"ins, {args.scenario} without calibration, site {args.site}{iron}, {args.seconds:.0f} s: heading / tilt "
          "RMS from 180 s, heading beyond 3σ from 30 s, vertical gyro bias error RMS from 180 s, its scale-factor "
          "error at the end", flush=True)
    with Pool(args.processes) as pool:
        for (_, seed, row, *_), (hdg, tilt, beyond, bz_err, sz_err) in pool.imap(one_run, jobs):
            print(f"seed {seed:3d}  {row:20s} heading {hdg:5.2f}°  tilt {tilt:5.2f}°  beyond 3σ {beyond:6.2%}  "
                  f"b_z error {bz_err:4.0f} °/h  s_z error {sz_err:+6.3f} %", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
