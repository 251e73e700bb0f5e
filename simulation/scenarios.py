"""Truth trajectories: attitude, angular rate and the vehicle's acceleration as analytic functions of time.

Each scenario gives the body→NED attitude as a `scipy.spatial.transform.Rotation` for any array of times
(t ≥ 0, forever: scenarios repeat or keep going), the acceleration of the sensor relative to the Earth in NED
(m/s²), and an optional local magnetic disturbance (NED, µT). The body rate is the exact derivative of that
attitude: a central difference of the rotation over ±10 µs, or for scenarios defined by Euler angles the exact
Euler-rate formula with central differences of the angles over ±10 µs (errors < 1e-8 rad/s away from the
instants where a rate profile changes segment), so truth attitude, truth rate and specific force come from one
trajectory and cannot lag each other.

Truth uses scipy only (CONTRIBUTING: never `ahrsd.estimator`'s rotation maths).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ahrsd.simulation.magnetic import PassingMagnet, VehicleIron
from ahrsd.simulation.profiles import RateProfile, hold, ramp, smoothstep

# scipy's Rotation is imported where a rotation is made (here, gnss.py, bench_positions.py), not at the top: the
# daemon imports this package only for the scenario names and the simulator's site (daemon/config.py,
# daemon/position.py), its simulated chip runs in another process, and every `ahrsd run` would load scipy.spatial
# for nothing (docs/simulation.md)
if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

from ahrsd.simulation.bench_positions import AccelPositions
from ahrsd.simulation.scenario_base import (
    DEG, ConstantSpeedTrack, EulerScenario, Scenario, track_accel_ned_m_s2, track_velocity_ned_m_s,
)
from ahrsd.simulation.vehicles import VEHICLES


@dataclass
class Static(EulerScenario):
    """Level and still at a fixed heading."""

    heading_deg: float = 40.0
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    name = "static"
    description = "level and at rest, heading 40°"

    def euler_rad(self, t_s):
        n = len(np.atleast_1d(t_s))
        return (np.full(n, self.heading_deg * DEG), np.full(n, self.pitch_deg * DEG),
                np.full(n, self.roll_deg * DEG))


# --------------------------------------------------------------------------------------------------------------
# Mountings of the sensor on a single-axis rate table whose axis is vertical: each puts one body axis up or down
# (body→NED). With the table turning about NED down, the body turns about that axis. The six static holds are
# also the classic six-position accelerometer calibration set (static gravity reference, as the ADIS16405
# AHRS thesis calibrates with).
def _table_mounts() -> tuple[tuple[str, Rotation], ...]:
    from scipy.spatial.transform import Rotation

    return (
        ("z down (level)", Rotation.identity()),
        ("z up", Rotation.from_euler("X", 180, degrees=True)),
        ("x up", Rotation.from_euler("Y", 90, degrees=True)),
        ("x down", Rotation.from_euler("Y", -90, degrees=True)),
        ("y up", Rotation.from_euler("X", -90, degrees=True)),
        ("y down", Rotation.from_euler("X", 90, degrees=True)),
    )


@dataclass
class RateTable(Scenario):
    """The rate-table gyro calibration of the ADIS16405 AHRS thesis (docs/calibration.md),
    as a self-consistent sequence.

    The sensor is mounted in six positions (each body axis up, then down). In each: hold, turn `turns` full
    turns at +`rate_deg_s` (raised-cosine ramps of `ramp_s`), hold, the same at −`rate_deg_s`, hold; then the
    operator re-mounts it (a smooth `remount_s` reorientation). So every body axis sees ±rate in both
    directions with gravity along it, and the holds give six static positions. Repeats after `period_s`.
    """

    rate_deg_s: float = 90.0
    turns: int = 2
    ramp_s: float = 2.0
    hold_s: float = 5.0
    remount_s: float = 5.0
    name = "rate-table"
    description = "six mountings × ±90 °/s table rotations (2 turns each) with 5 s static holds"

    def __post_init__(self):
        w = self.rate_deg_s * DEG
        const_s = 2 * math.pi * self.turns / w - self.ramp_s  # ramps add w·ramp_s in total
        if const_s <= 0:
            raise ValueError("rate-table: turns too few for that rate and ramp time")
        table_mounts = _table_mounts()
        segs, windows = [], []
        t = 0.0
        for _ in table_mounts:
            start = t
            for sign in (1.0, -1.0):
                block = [hold(self.hold_s), ramp(self.ramp_s, 0, sign * w), hold(const_s, sign * w),
                         ramp(self.ramp_s, sign * w, 0)]
                segs += block
                t += sum(s.duration_s for s in block)
            segs.append(hold(self.hold_s))
            t += self.hold_s
            windows.append((start, t))
            segs.append(hold(self.remount_s))
            t += self.remount_s
        self._table = RateProfile(segs)
        self.period_s = self._table.period_s
        self._mount_end = np.array([w1 for _, w1 in windows])
        self._mounts = [m for _, m in table_mounts]
        # The rotation from each mount to the next, applied gradually during the remount.
        self._steps = [self._mounts[(k + 1) % 6] * self._mounts[k].inv() for k in range(6)]
        self._mount_quats = np.array([m.as_quat() for m in self._mounts])
        self._step_rotvecs = np.array([st.as_rotvec() for st in self._steps])
        self.mount_names = tuple(n for n, _ in table_mounts)

    def table_rate_rad_s(self, t_s):
        return self._table.rate(t_s)

    def mount_index(self, t_s) -> np.ndarray:
        tp = np.mod(np.asarray(t_s, dtype=float), self.period_s)
        return np.minimum(np.searchsorted(self._mount_end + self.remount_s, tp, side="right"), 5)

    def _parts(self, t):
        tp = np.mod(t, self.period_s)
        k = self.mount_index(t)
        into_remount = np.clip((tp - self._mount_end[k]) / self.remount_s, 0.0, 1.0)
        return k, into_remount, self._table.angle(t)

    def attitude(self, t_s):
        from scipy.spatial.transform import Rotation

        t = np.asarray(t_s, dtype=float)
        k, x, theta = self._parts(t)
        mounts = Rotation.from_quat(self._mount_quats[k])
        partial = Rotation.from_rotvec(self._step_rotvecs[k] * smoothstep(x)[:, None])
        table = Rotation.from_euler("Z", theta[:, None])   # about NED down, the table axis
        # Table angle is a whole number of turns outside the rotations, so remounting happens at table angle 0.
        return table * partial * mounts

    def body_rate_rad_s(self, t_s):
        """Exact: R = Rz(θ) · exp(s v) · M gives ω_n = θ̇ e_z + Rz(θ) ṡ v, and ω_b = Rᵀ ω_n."""
        from scipy.spatial.transform import Rotation

        t = np.asarray(t_s, dtype=float)
        k, x, theta = self._parts(t)
        s_dot = np.where((x > 0.0) & (x < 1.0), 6.0 * x * (1.0 - x) / self.remount_s, 0.0)   # d smoothstep / dt
        table = Rotation.from_euler("Z", theta[:, None])
        w_ned = table.apply(self._step_rotvecs[k] * s_dot[:, None])
        w_ned[:, 2] += self._table.rate(t)
        return self.attitude(t).apply(w_ned, inverse=True)


# --------------------------------------------------------------------------------------------------------------
@dataclass
class LevelTurns(EulerScenario):
    """A boat or rover turning through 360° again and again, at a varying rate, rolling and pitching in waves.

    Heading rate 9 ± 4 °/s (one full turn every ~40 s); wave roll ≤ 7.5°, pitch ≤ 5°, heave ±0.2 m; forward
    speed 2 m/s, so the turn adds a centripetal acceleration of up to 0.45 m/s². Carries the default vehicle iron.
    """

    speed_m_s: float = 2.0
    mean_turn_rate_deg_s: float = 9.0
    turn_rate_swing_deg_s: float = 4.0
    turn_rate_period_s: float = 53.0
    heading0_deg: float = 0.0
    name = "level-turns"
    description = "boat turning 360° over and over (9±4 °/s), wave roll/pitch within ±7.5°, 2 m/s"
    default_iron = VehicleIron.default()

    # wave components: (amplitude deg, period s, phase rad)
    _ROLL = ((5.0, 6.1, 0.0), (2.5, 2.7, 0.7))
    _PITCH = ((3.5, 4.3, 0.3), (1.5, 1.9, 1.1))
    _HEAVE = (0.2, 7.0)  # amplitude m, period s

    def heading_rad(self, t):
        w = 2 * math.pi / self.turn_rate_period_s
        return (self.heading0_deg * DEG + self.mean_turn_rate_deg_s * DEG * t
                + self.turn_rate_swing_deg_s * DEG / w * (1.0 - np.cos(w * t)))

    def heading_rate_rad_s(self, t):
        w = 2 * math.pi / self.turn_rate_period_s
        return (self.mean_turn_rate_deg_s + self.turn_rate_swing_deg_s * np.sin(w * t)) * DEG

    @staticmethod
    def _waves(t, comps):
        return sum(a * DEG * np.sin(2 * math.pi * t / p + ph) for a, p, ph in comps)

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return self.heading_rad(t), self._waves(t, self._PITCH), self._waves(t, self._ROLL)

    def velocity_ned_m_s(self, t_s):
        t = np.asarray(t_s, dtype=float)
        a, p = self._HEAVE
        w = 2 * math.pi / p
        return track_velocity_ned_m_s(self.speed_m_s, self.heading_rad(t), a * w * np.cos(w * t))

    def accel_ned_m_s2(self, t_s):
        t = np.asarray(t_s, dtype=float)
        a, p = self._HEAVE
        w = 2 * math.pi / p
        return track_accel_ned_m_s2(self.speed_m_s, self.heading_rad(t), self.heading_rate_rad_s(t),
                                    -a * w * w * np.sin(w * t))


# --------------------------------------------------------------------------------------------------------------
@dataclass
class CoordinatedTurn(ConstantSpeedTrack):
    """A fixed-wing at `speed_m_s` in banked, coordinated turns: the accelerometer does not point at gravity.

    Straight 10 s, roll into a right turn at `bank_deg` (4 s), hold it 60 s, roll out, straight 10 s, the same to
    the left; repeats. Coordinated: bank φ = atan(V ψ̇ / g) at every instant, so the lateral specific force is zero
    and the specific force in the turn is g / cos φ along body −z, tilted away from the vertical by φ.
    """

    speed_m_s: float = 25.0
    bank_deg: float = 30.0
    heading0_deg: float = 20.0
    straight_s: float = 10.0
    roll_in_s: float = 4.0
    turn_s: float = 60.0
    gravity_m_s2: float = 9.80            # replaced by the site's gravity by the stream
    name = "coordinated-turn"
    description = "25 m/s fixed-wing, 30° banked coordinated turns right and left (60 s each)"

    def __post_init__(self):
        self._build()

    def _build(self):
        w = self.gravity_m_s2 * math.tan(self.bank_deg * DEG) / self.speed_m_s
        segs = []
        for sign in (1.0, -1.0):
            segs += [hold(self.straight_s), ramp(self.roll_in_s, 0, sign * w), hold(self.turn_s, sign * w),
                     ramp(self.roll_in_s, sign * w, 0)]
        self._heading = RateProfile(segs, angle0=self.heading0_deg * DEG)
        self.period_s = self._heading.period_s
        self.turn_rate_rad_s = w

    def with_gravity(self, g_m_s2: float) -> "CoordinatedTurn":
        """The same manoeuvre flown under gravity `g_m_s2` (bank angle coordinated with the local g)."""
        return dataclasses.replace(self, gravity_m_s2=float(g_m_s2))

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        psi, r = self._heading.angle(t), self._heading.rate(t)
        bank = np.arctan(self.speed_m_s * r / self.gravity_m_s2)
        return psi, np.zeros_like(t), bank



# --------------------------------------------------------------------------------------------------------------
@dataclass
class Tumble(EulerScenario):
    """A hand tumble for a full-sphere calibration: every orientation within ~90 s.

    The sensor rolls continuously (90 °/s ±20 %), so each direction across its x axis is swept every ~4 s, while
    the pitch swings slowly from nose-down to nose-up and back (−90° cos(2πt/120 s)) and the heading turns at
    23 °/s: the gravity and field directions in the sensor frame spiral over the whole sphere (gaps < 12° for
    gravity and < 15° for the field after 90 s at the default site). The centre stays put. Carries the default
    vehicle iron. Peak body rate ≈ 130 °/s (inside the ±300 °/s range).
    """

    roll_rate_deg_s: float = 90.0
    yaw_rate_deg_s: float = 23.0
    pitch_period_s: float = 120.0
    name = "tumble"
    description = "rolling 90 °/s, pitch swinging ±90° over 120 s, heading 23 °/s: full sphere in ~90 s"
    default_iron = VehicleIron.default()
    _ROLL_MOD = (0.2, 17.0)  # fraction, period s

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        frac, per = self._ROLL_MOD
        w = 2 * math.pi / per
        roll = self.roll_rate_deg_s * DEG * (t + frac / w * (1.0 - np.cos(w * t)))
        pitch = -90.0 * DEG * np.cos(2 * math.pi * t / self.pitch_period_s)
        return self.yaw_rate_deg_s * DEG * t, pitch, roll


# --------------------------------------------------------------------------------------------------------------
@dataclass
class AuvOutAndBack(ConstantSpeedTrack):
    """Test 2 of Nourmohammadi & Sabet, "Back-stepping calibration algorithm for three-axial magnetometer applied
    to autonomous underwater vehicles with magnetic deviations", J. of Control 16(3), 2022, §5: an AUV runs out
    on heading 62°, turns, and comes back on −117° (= 243°); repeats.

    The paper's legs are ~10 km at a few knots (hours); here each leg lasts `leg_s` (default 240 s) so a test can
    afford it; the field at the site is WMM's (the paper's eq. 27 gives IGRF Hh 27.45 µT, Hz 40.29 µT at its
    undisclosed site; docs/simulation.md compares the default site's). A 60 s turn joins the
    legs (rate raised-cosine, up to 6 °/s), speed 1.5 m/s, small pitch (dolphin profile, ±3°) and roll (±1.5°).
    Headings are true (yaw in NED). Carries the default vehicle iron.
    """

    leg_s: float = 240.0
    turn_s: float = 60.0
    speed_m_s: float = 1.5
    out_heading_deg: float = 62.0      # the paper's test 2 (§5)
    back_heading_deg: float = -117.0   # the paper's test 2 (§5)
    name = "auv-out-and-back"
    description = "AUV legs at 62° and −117° (back-stepping paper test 2), 240 s each, 60 s turns, pitch ±3°, roll ±1.5°"
    default_iron = VehicleIron.default()

    def __post_init__(self):
        out = self.out_heading_deg
        back = (self.back_heading_deg - out) % 360.0 + out          # 243° reached by turning right 181°
        t1 = (back - out) * DEG                                       # first turn, rad
        t2 = 2 * math.pi - t1                                         # second turn, back to out + 360°
        h = self.turn_s / 2
        segs = [hold(self.leg_s), ramp(h, 0, 2 * t1 / self.turn_s), ramp(h, 2 * t1 / self.turn_s, 0),
                hold(self.leg_s), ramp(h, 0, 2 * t2 / self.turn_s), ramp(h, 2 * t2 / self.turn_s, 0)]
        self._heading = RateProfile(segs, angle0=out * DEG)
        self.period_s = self._heading.period_s

    def leg_of(self, t_s) -> np.ndarray:
        """0 on the outbound leg, 1 on the return leg, −1 while turning."""
        tp = np.mod(np.asarray(t_s, dtype=float), self.period_s)
        L, T = self.leg_s, self.turn_s
        return np.where(tp < L, 0, np.where((tp >= L + T) & (tp < 2 * L + T), 1, -1))

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        pitch = 3.0 * DEG * np.sin(2 * math.pi * t / 120.0)
        roll = 1.5 * DEG * np.sin(2 * math.pi * t / 9.0)
        return self._heading.angle(t), pitch, roll



# --------------------------------------------------------------------------------------------------------------
@dataclass
class MagDisturbance(EulerScenario):
    """A still, level vehicle (heading 40°) while a magnet (2 A·m²) is carried past at 0.3 m, twice a minute.

    The magnet starts 3 m away (field < 0.01 µT), so the first ~10 s are undisturbed; at closest approach the
    disturbance is ~15 µT. The field is a point dipole decaying with 1/r³. No vehicle iron by default.
    """

    heading_deg: float = 40.0
    magnet: PassingMagnet = field(default_factory=PassingMagnet)
    name = "mag-disturbance"
    description = "level and still at heading 40°, a 2 A·m² magnet carried past at 0.3 m twice a minute"

    def euler_rad(self, t_s):
        n = len(np.atleast_1d(t_s))
        return np.full(n, self.heading_deg * DEG), np.zeros(n), np.zeros(n)

    def disturbance_ned_ut(self, t_s):
        return self.magnet.field_ned_ut(np.asarray(t_s, dtype=float))


# --------------------------------------------------------------------------------------------------------------
@dataclass
class AuvDiverSwing(EulerScenario):
    """Test 1 of Nourmohammadi & Sabet (2022, §5): a diver rotates the floating AUV, first in roll only, then
    roll + pitch, then roll + pitch + heading (the paper's cases 1–3, 300 s / 430 s / 600 s): roll ±55°, pitch
    ±10°, heading through the full circle only in the last phase. The attitude coverage of a vehicle that cannot
    be tumbled, for the initial sphere fit of the back-stepping calibration. Not one of the contract's SCENARIOS (use
    `make_scenario("auv-diver-swing")`). Repeats after 1330 s; carries the default vehicle iron.
    """

    roll_amplitude_deg: float = 55.0     # the paper's test 1 (§5)
    pitch_amplitude_deg: float = 10.0    # the paper's test 1 (§5)
    heading_rate_deg_s: float = 3.0
    heading0_deg: float = 30.0
    name = "auv-diver-swing"
    description = "back-stepping paper test 1: diver rolls (±55°), then pitches (±10°), then turns the AUV (300/430/600 s)"
    default_iron = VehicleIron.default()
    _PHASES_S = (300.0, 430.0, 600.0)    # roll only, roll + pitch, roll + pitch + heading (the paper's Table 2)
    _ROLL_PERIOD_S = 35.0                # 38 cycles per 1330 s period: continuous when repeating
    _PITCH_PERIOD_S = 33.0
    _FADE_S = 10.0

    def __post_init__(self):
        p1, p2, p3 = self._PHASES_S
        w = self.heading_rate_deg_s * DEG
        f = self._FADE_S
        self._heading = RateProfile([hold(p1 + p2), ramp(f, 0.0, w), hold(p3 - 2 * f, w), ramp(f, w, 0.0)],
                                    angle0=self.heading0_deg * DEG)
        self.period_s = self._heading.period_s

    def phase_of(self, t_s) -> np.ndarray:
        """1 (roll only), 2 (roll + pitch) or 3 (roll + pitch + heading), as in the paper's cases 1–3."""
        tp = np.mod(np.asarray(t_s, dtype=float), self.period_s)
        p1, p2, _ = self._PHASES_S
        return np.where(tp < p1, 1, np.where(tp < p1 + p2, 2, 3))

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        tp = np.mod(t, self.period_s)
        p1 = self._PHASES_S[0]
        f = self._FADE_S
        # pitch fades in at the start of phase 2 and out at the end of the period (C¹ envelope)
        env = smoothstep((tp - p1) / f) * smoothstep((self.period_s - tp) / f)
        roll = self.roll_amplitude_deg * DEG * np.sin(2 * math.pi * t / self._ROLL_PERIOD_S)
        pitch = self.pitch_amplitude_deg * DEG * env * np.sin(2 * math.pi * t / self._PITCH_PERIOD_S)
        return self._heading.angle(t), pitch, roll


_REGISTRY = {
    "static": Static,
    "rate-table": RateTable,
    "level-turns": LevelTurns,
    "coordinated-turn": CoordinatedTurn,
    "tumble": Tumble,
    "auv-out-and-back": AuvOutAndBack,
    "mag-disturbance": MagDisturbance,
}
_REGISTRY.update(VEHICLES)
SCENARIOS: tuple[str, ...] = tuple(_REGISTRY)   # the contract's names (CONTRIBUTING, "Simulation")

EXTRA_SCENARIOS = {"auv-diver-swing": AuvDiverSwing,    # available by name, not part of the contract
                   "accel-positions": AccelPositions}


def make_scenario(name: str, **params) -> Scenario:
    """A scenario by name (SCENARIOS or EXTRA_SCENARIOS), with parameters of its class (e.g. leg_s=120)."""
    cls = _REGISTRY.get(name) or EXTRA_SCENARIOS.get(name)
    if cls is None:
        known = ", ".join(SCENARIOS + tuple(EXTRA_SCENARIOS))
        raise ValueError(f"unknown scenario {name!r}; choose one of {known}")
    return cls(**params)
