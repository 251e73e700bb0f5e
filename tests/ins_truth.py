"""Truth and GNSS fixes for the `ins` tests, computed independently of the estimator: the simulator's analytic
trajectory (attitude, NED velocity) integrated into WGS-84 geodetic position with scipy, fixes drawn from that
truth with white noise, and error measures in the filter's error convention (scipy rotations)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from ahrsd.core.gnss import GnssFix, make_fix
from ahrsd.simulation import DEFAULT_SITE, open_stream

WGS84_A = 6378137.0
WGS84_E2 = 6.69437999014e-3
DECLINATION = DEFAULT_SITE.earth_field().declination_rad


def wgs84_radii(lat_rad):
    """Meridian and prime-vertical radii of curvature (Groves eqs. 2.105–2.106)."""
    s = np.sin(lat_rad)
    d = 1.0 - WGS84_E2 * s * s
    r_e = WGS84_A / np.sqrt(d)
    return r_e * (1.0 - WGS84_E2) / d, r_e


def sphere_radii(lat_rad):
    """Spherical Earth: R0 = 6 378 137 m for both radii."""
    r = np.full(np.shape(lat_rad), 6378137.0)
    return r, r


RADII = {"wgs84": wgs84_radii, "sphere": sphere_radii}


def rot(q_wxyz) -> Rotation:
    q = np.asarray(q_wxyz, dtype=float)
    return Rotation.from_quat(np.concatenate([q[..., 1:], q[..., :1]], axis=-1))


@dataclass
class Truth:
    t_s: np.ndarray
    q_wxyz: np.ndarray       # body → true NED
    vel_ned_m_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray


@dataclass
class Run:
    """A simulated IMU run: the samples fed to the estimator (calibrated magnetometer, raw gyro/accel) and the
    truth."""

    block: object
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray
    truth: Truth
    earth: str = "wgs84"
    # the samples as fed to the estimator, built once for the filters a test runs on the same run (run_ins):
    # with the arrays they were built from, so a run whose arrays were replaced builds them again
    _samples: tuple = field(default=(), init=False, repr=False, compare=False)

    def samples(self) -> list:
        from ahrsd.core.sample import SampleFlags, make_sample

        built_from = (self.truth.t_s, self.gyro, self.accel, self.mag)
        if len(self._samples) != 2 or any(a is not b for a, b in zip(self._samples[0], built_from)):
            t = self.truth.t_s
            self._samples = (built_from, [make_sample(t[k], self.gyro[k], self.accel[k], self.mag[k],
                                                      flags=SampleFlags.NEW_DATA) for k in range(len(t))])
        return self._samples[1]


def simulated_run(scenario, seconds, rate_hz=200.0, seed=1, errors="adis16405", earth_rate=True,
                  earth="wgs84", field_anomaly_ned_ut=None) -> Run:
    """The scenario's truth track as geodetic position on `earth` ("wgs84" or "sphere"); the true Earth field
    WMM's plus `field_anomaly_ned_ut` (simulation.open_stream; None: WMM's)."""
    stream = open_stream(scenario, rate_hz=rate_hz, seed=seed, errors=errors, earth_rate=earth_rate,
                         field_anomaly_ned_ut=field_anomaly_ned_ut)
    b = stream.next_block(int(round(seconds * rate_hz)))
    e = stream.errors
    mag = (np.linalg.inv(e.soft_iron) @ (b.mag_ut - e.hard_iron_ut).T).T   # the daemon feeds a calibrated field
    v = stream.scenario.velocity_ned_m_s(b.t_s)
    site = DEFAULT_SITE
    h = site.alt_m - cumulative_trapezoid(v[:, 2], b.t_s, initial=0.0)
    lat = np.full(len(b.t_s), math.radians(site.lat_deg))
    radii = RADII[earth]
    for _ in range(2):   # L̇ = V_N/(R_N + h): iterate once so R_N is taken at the moving latitude
        r_n, r_e = radii(lat)
        lat = math.radians(site.lat_deg) + cumulative_trapezoid(v[:, 0] / (r_n + h), b.t_s, initial=0.0)
    r_n, r_e = radii(lat)
    lon = math.radians(site.lon_deg) + cumulative_trapezoid(v[:, 1] / ((r_e + h) * np.cos(lat)), b.t_s, initial=0.0)
    return Run(b, b.gyro_rad_s, b.accel_m_s2, mag, Truth(b.t_s, b.truth_q_wxyz, v, lat, lon, h), earth)


def gnss_fixes(truth: Truth, rate_hz=5.0, sigma_pos_m=1.5, sigma_vel_m_s=0.05, latency_s=0.1, seed=7,
               start_s=0.5, lever_arm_m=(0.0, 0.0, 0.0), body_rate=None, sigma_alt_m=None, earth="wgs84"):
    """[(arrival time, GnssFix)] at `rate_hz`, valid at sample times, arriving `latency_s` later; white noise
    of the given 1σ, reported as the fix's accuracies. With a lever arm, the fix is the antenna's
    (p + C r, v + C (ω × r); body_rate: truth ω per sample)."""
    rng = np.random.default_rng(seed)
    t = truth.t_s
    dt = t[1] - t[0]
    out = []
    sig_alt = sigma_alt_m if sigma_alt_m is not None else 1.7 * sigma_pos_m
    arm = np.asarray(lever_arm_m, dtype=float)
    for tf in np.arange(start_s, t[-1] - latency_s, 1.0 / rate_hz):
        i = int(round((tf - t[0]) / dt))
        c = rot(truth.q_wxyz[i]).as_matrix()
        off = c @ arm
        vel = truth.vel_ned_m_s[i] + (c @ np.cross(body_rate[i], arm) if body_rate is not None else 0.0)
        r_n, r_e = RADII[earth](truth.lat_rad[i])
        h = truth.h_m[i]
        n = off[0] + rng.normal(0.0, sigma_pos_m)
        e = off[1] + rng.normal(0.0, sigma_pos_m)
        d = off[2] + rng.normal(0.0, sig_alt)
        lat = truth.lat_rad[i] + n / (r_n + h)
        lon = truth.lon_rad[i] + e / ((r_e + h) * math.cos(truth.lat_rad[i]))
        fix = make_fix(t[i], math.degrees(lat), math.degrees(lon), h - d,
                       vel + rng.normal(0.0, sigma_vel_m_s, 3),
                       h_acc_m=sigma_pos_m, v_acc_m=sig_alt, s_acc_m_s=sigma_vel_m_s, num_sats=12)
        out.append((t[i] + latency_s, fix))
    return out


@dataclass
class Result:
    q_mag: np.ndarray        # (n, 4) the estimates' q (body → magnetic NED)
    q_true: np.ndarray       # (n, 4) the filter's own attitude (body → true NED)
    flags: np.ndarray        # (n,) EstimateFlags ints
    vel: np.ndarray          # (n, 3) NaN without nav
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    cov: dict                # sample index → 15×15 covariance (at `cov_every`)
    outcomes: list           # update_gnss return values


def with_fixes_offered(t_s, fixes, offer, n=None):
    """The sample indices k (the first n of t_s; all by default), each after `offer(fix)` for every fix (the
    (arrival time, fix) pairs of `gnss_fixes`, in arrival order) that has arrived by t_s[k]: as the daemon's loop
    offers them, a fix arriving exactly at a sample's time before that sample."""
    fi = 0
    for k in range(len(t_s) if n is None else n):
        while fi < len(fixes) and fixes[fi][0] <= t_s[k]:
            offer(fixes[fi][1])
            fi += 1
        yield k


def run_ins(est, run: Run, fixes, cov_every=0, fix_filter=None, sigma_yaw_out=None, estimates_every=1,
            seconds=None) -> Result:
    """Feed the samples one at a time, each fix once the IMU time passes its arrival time; `sigma_yaw_out` (a
    list) gets each sample's published yaw σ (rad). `estimates_every` = n > 1: the estimate (q_mag, nav) is
    read at every n-th sample only (NaN at the others; q_true, the flags and the covariances as always: the flags
    from the step's view, which gives them without building the estimate): the others are stepped without building
    one (Ins.step), which changes no estimate (estimator/estimate_view.py: what a snapshot holds does not depend on
    how often snapshots are taken). `seconds`: only the run's samples before it are fed (the arrays hold those: the
    first samples of the run's)."""
    samples = run.samples()
    t = run.truth.t_s
    n = len(t) if seconds is None else int(np.searchsorted(t, seconds))
    q_mag = np.zeros((n, 4)) if estimates_every == 1 else np.full((n, 4), np.nan)
    q_true = np.zeros((n, 4))
    flags = np.zeros(n, dtype=np.int64)
    vel = np.full((n, 3), np.nan)
    lat = np.full(n, np.nan)
    lon = np.full(n, np.nan)
    h = np.full(n, np.nan)
    cov = {}
    outcomes = []

    def offer(fix):
        if fix_filter is None or fix_filter(fix):
            outcomes.append(est.update_gnss(fix))

    for k in with_fixes_offered(t, fixes, offer, n):
        if k % estimates_every:
            flags[k] = int(est.step(samples[k]).flags)
            q_true[k] = est.true_attitude_q_wxyz()
            if cov_every and k % cov_every == 0:
                cov[k] = est.covariance
            continue
        r = est.update(samples[k])
        if sigma_yaw_out is not None:
            sigma_yaw_out.append(float(r.sigma_rpy_rad[2]))
        q_mag[k] = r.q_wxyz
        q_true[k] = est.true_attitude_q_wxyz()
        flags[k] = int(r.flags)
        if r.nav is not None:
            vel[k] = r.nav.vel_ned_m_s
            lat[k] = math.radians(r.nav.lat_deg)
            lon[k] = math.radians(r.nav.lon_deg)
            h[k] = r.nav.alt_m
        if cov_every and k % cov_every == 0:
            cov[k] = est.covariance
    return Result(q_mag, q_true, flags, vel, lat, lon, h, cov, outcomes)


def run_ins_with_yaw_sigma(est, run: Run, fixes) -> tuple[Result, np.ndarray]:
    """`run_ins`, and the published yaw σ of every sample (rad)."""
    sigma_yaw = []
    res = run_ins(est, run, fixes, sigma_yaw_out=sigma_yaw)
    return res, np.asarray(sigma_yaw)


def attitude_error_ned(q_true_est, q_truth) -> np.ndarray:
    """δθ with C_true = (I + [δθ×]) C_est, rad (n, 3): NED rotation vector of C_true C_estᵀ."""
    return (rot(q_truth) * rot(q_true_est).inv()).as_rotvec()


def tilt_heading_errors_deg(q_mag_est, q_truth, declination_rad=DECLINATION):
    """Tilt error (angle between the estimated and true body z axes' verticals) and true-heading error, deg."""
    est = rot(q_mag_est)
    yaw_fix = Rotation.from_euler("z", declination_rad)
    est = yaw_fix * est
    tru = rot(q_truth)
    d = (tru * est.inv()).as_rotvec()
    tilt = np.degrees(np.hypot(d[:, 0], d[:, 1]))
    ye = est.as_euler("ZYX")[:, 0]
    yt = tru.as_euler("ZYX")[:, 0]
    heading = np.degrees((ye - yt + np.pi) % (2 * np.pi) - np.pi)
    return tilt, heading


def position_error_ned(res: Result, truth: Truth, earth="wgs84") -> np.ndarray:
    """At `res`'s samples (the run's first ones when it was fed the run's first seconds: run_ins `seconds`), m."""
    n = len(res.lat_rad)
    lat, lon, h = truth.lat_rad[:n], truth.lon_rad[:n], truth.h_m[:n]
    r_n, r_e = RADII[earth](lat)
    return np.column_stack([(lat - res.lat_rad) * (r_n + h), (lon - res.lon_rad) * (r_e + h) * np.cos(lat),
                            -(h - res.h_m)])


__all__ = ["DECLINATION", "GnssFix", "Run", "Truth", "Result", "simulated_run", "gnss_fixes", "run_ins",
           "attitude_error_ned", "tilt_heading_errors_deg", "position_error_ned", "wgs84_radii", "rot"]
