"""Simulated vehicles for the field-calibration tests: the project simulator's level-turns boat with its wave
roll/pitch scaled to ±2°, ±10° or ±30°, strong non-symmetric vehicle iron, optional straight runs and a
current, GNSS course made from the simulation truth; and the scoring of a magnetometer model on attitudes the
session never saw, against the injected iron.

Truth comes from the simulator (scipy rotations), never from the code under test. scipy.spatial is imported by
the functions that score, not at the top: a daemon that imports this module to record its vehicle
(test_magcal_field_daemon's) would load scipy.spatial for nothing."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from ahrsd.core.sample import make_sample
from ahrsd.core.wmm import earth_field
from ahrsd.simulation import DEFAULT_SITE, open_stream
from ahrsd.simulation.magnetic import VehicleIron
from ahrsd.simulation.scenarios import LevelTurns

DEG = math.pi / 180.0
RATE_HZ = 100.0
# strong, non-symmetric: ~330-450 mG of hard iron, ±12 % scale, cross-coupling, and a skew part (a ~2.9° rotation
# about z: the constant heading offset no field fit sees on level data)
STRONG_IRON = VehicleIron(hard_iron_ut=np.array([33.0, -41.0, 26.0]),
                          soft_iron=np.array([[1.12, 0.07, -0.04], [-0.03, 0.90, 0.05], [0.08, -0.02, 1.05]]))
SITE_FIELD = earth_field(DEFAULT_SITE.lat_deg, DEFAULT_SITE.lon_deg, DEFAULT_SITE.alt_m, DEFAULT_SITE.date)


@dataclass
class TiltedTurns(LevelTurns):
    """LevelTurns with the wave roll and pitch each scaled to peak at ±tilt_deg (±30°: tilt up to ~40°).
    straight_runs: the turn rate follows r·(1 − cos 2πt/P) (P = 30 s, 135° of heading per period), so the
    boat holds a nearly straight course for ~9 s at 8 different headings per three turns."""

    tilt_deg: float = 10.0
    straight_runs: bool = False
    run_period_s: float = 30.0

    def _scale(self, comps) -> float:
        return self.tilt_deg / sum(a for a, _p, _ph in comps)

    def heading_rad(self, t):
        if not self.straight_runs:
            return super().heading_rad(t)
        r = 135.0 / self.run_period_s * DEG
        w = 2 * math.pi / self.run_period_s
        return self.heading0_deg * DEG + r * (t - np.sin(w * t) / w)

    def heading_rate_rad_s(self, t):
        if not self.straight_runs:
            return super().heading_rate_rad_s(t)
        r = 135.0 / self.run_period_s * DEG
        return r * (1.0 - np.cos(2 * math.pi * t / self.run_period_s))

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return (self.heading_rad(t), self._scale(self._PITCH) * self._waves(t, self._PITCH),
                self._scale(self._ROLL) * self._waves(t, self._ROLL))


def vehicle(tilt_deg: float, straight_runs: bool = False) -> TiltedTurns:
    return TiltedTurns(tilt_deg=tilt_deg, straight_runs=straight_runs)


def record(scenario: LevelTurns, seconds: float, seed: int = 0, iron: VehicleIron | str = STRONG_IRON) -> SimpleNamespace:
    """`seconds` of the scenario at RATE_HZ with ADIS16405 errors and `iron` (STRONG_IRON; "scenario": the
    scenario's own, as `ahrsd run --sim level-turns`). The accelerometer is
    corrected with the simulator's own turn-on bias/scale/misalignment, as a unit whose accelerometer was
    calibrated on the bench before the field (docs/magcal-vehicle.md: roll/pitch quality matters)."""
    stream = open_stream(scenario, RATE_HZ, seed=seed, vehicle_iron=iron)
    b = stream.next_block(int(round(seconds * RATE_HZ)))
    e = stream.errors
    accel = (b.accel_m_s2 - e.accel_bias_m_s2) @ np.linalg.inv(e.accel_matrix).T
    return SimpleNamespace(t_s=b.t_s, gyro_rad_s=b.gyro_rad_s, accel_m_s2=accel, mag_ut=b.mag_ut,
                           truth_q_wxyz=b.truth_q_wxyz, truth_gyro_rad_s=b.truth_gyro_rad_s)


def truth_euler(block) -> np.ndarray:
    """(n, 3) yaw, pitch, roll of the truth attitude (rad)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(block.truth_q_wxyz[:, [1, 2, 3, 0]]).as_euler("ZYX")


def samples(block):
    for i in range(len(block.t_s)):
        yield make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i])


def course_fixes(scenario: TiltedTurns, t_end_s: float, *, rate_hz: float = 5.0, current_ne_m_s=(0.0, 0.0),
                 noise_deg: float = 0.5, latency_s: float = 0.1, seed: int = 11):
    """GNSS course from the truth: ground velocity = the vehicle's velocity through the water + a constant
    current; fix k is valid at tv_k and arrives latency_s later. Returns arrays (arrival t, time of validity,
    course rad, ground speed m/s)."""
    rng = np.random.default_rng(seed)
    tv = np.arange(1.0, t_end_s, 1.0 / rate_hz)
    v = scenario.velocity_ned_m_s(tv)[:, :2] + np.asarray([current_ne_m_s[0], current_ne_m_s[1]])
    course = (np.arctan2(v[:, 1], v[:, 0]) + rng.normal(0.0, noise_deg * DEG, tv.size)) % (2 * math.pi)
    return tv + latency_s, tv, course, np.hypot(v[:, 0], v[:, 1])


def test_attitudes(n_headings: int = 24):
    """Attitudes the session did not see: every 15° of heading at level, ±10° and ±30° roll and pitch."""
    out = []
    for tilt in (10.0, 30.0):
        for r, p in ((0, 0), (tilt, 0), (-tilt, 0), (0, tilt), (0, -tilt), (tilt / 1.4, tilt / 1.4)):
            for k in range(n_headings):
                out.append((k * 360.0 / n_headings, p, r))
    return np.radians(np.array(out))


def injected_iron(seed: int = 0, scenario: LevelTurns | None = None, iron: VehicleIron | str = STRONG_IRON) -> VehicleIron:
    """The whole distortion of the recording made with `seed` (and `scenario`, `iron` as given to `record`):
    vehicle iron and the sensor's own, as the simulator reports it (measured = soft_iron · true + hard_iron)."""
    e = open_stream(scenario or TiltedTurns(), RATE_HZ, seed=seed, vehicle_iron=iron).errors
    return VehicleIron(e.hard_iron_ut, e.soft_iron)


def heading_errors_deg(model, iron: VehicleIron, field=SITE_FIELD) -> np.ndarray:
    """Heading error of `model` on test_attitudes(): the raw field the injected iron makes (no noise),
    calibrated with `model`, levelled with the true roll/pitch (scipy), its heading minus the true magnetic
    heading."""
    from scipy.spatial.transform import Rotation

    ypr = test_attitudes()
    rot = Rotation.from_euler("ZYX", ypr)
    raw = rot.inv().apply(field.ned_ut) @ iron.soft_iron.T + iron.hard_iron_ut
    level = Rotation.from_euler("ZYX", np.column_stack((np.zeros(len(ypr)), ypr[:, 1], ypr[:, 2])))
    c = level.apply(model.apply(raw))            # = Rz(yaw)ᵀ · field for a perfect model
    psi = -np.arctan2(c[:, 1], c[:, 0]) + math.atan2(field.ned_ut[1], field.ned_ut[0])   # estimated true heading
    return np.degrees(np.angle(np.exp(1j * (psi - ypr[:, 0]))))


def heading_rms_deg(model, iron: VehicleIron, remove_mean: bool = False) -> float:
    e = heading_errors_deg(model, iron)
    if remove_mean:
        e = e - np.mean(e)
    return float(np.sqrt(np.mean(e**2)))
