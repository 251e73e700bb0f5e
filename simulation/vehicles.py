"""Vehicles with real translational dynamics: a boat, a car and a fixed-wing, each a few minutes of manoeuvres.

Each vehicle is driven like the real one: a speed through its medium (water, road, air), a course through the
medium that changes at a turn rate, and a climb rate, all smooth `RateProfile`s (C² blends for speed and climb
rate, raised cosine for the turn rate) with exact derivatives. From them, in closed form:

    v_NED = s [cos χ, sin χ, 0] + current + [0, 0, −climb]          (current: water or air mass, NED, constant)
    a_NED = ṡ [cos χ, sin χ, 0] + s χ̇ [−sin χ, cos χ, 0] + [0, 0, −ċlimb]

and the attitude follows from these dynamics: the car pitches with the road grade and its suspension squats,
dives and rolls outward under acceleration; the aircraft flies coordinated (body x along the air velocity, the
specific force in its body x–z plane, so bank = atan(V χ̇ / g) in a level turn); the boat heels in turns and rolls,
pitches and heaves in waves, and its heading differs from its course over ground by the leeway and the current.
Position is the integral of v_NED on the simulator's spherical Earth (`simulation.track`). All three are simulated on
a rotating Earth by default (`Scenario.rotating_earth`). Truth maths uses scipy only (via `EulerScenario`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.simulation.magnetic import VehicleIron
from ahrsd.simulation.profiles import RateProfile, Segment
from ahrsd.simulation.scenario_base import DEG, EulerScenario


@dataclass(frozen=True, slots=True)
class Leg:
    """`duration_s` of manoeuvre: each quantity blends (raised cosine) from its value at the start of the leg to
    the value given here at its end; None keeps it. Speed m/s through the medium, turn rate °/s (positive to the
    right), climb rate m/s (positive up)."""

    duration_s: float
    speed_m_s: float | None = None
    turn_deg_s: float | None = None
    climb_m_s: float | None = None


def turn(angle_deg: float, ramp_s: float, hold_s: float, **targets) -> list[Leg]:
    """A turn through `angle_deg` (signed): the rate rises over `ramp_s`, holds `hold_s`, falls over `ramp_s`
    (rate = angle / (ramp + hold), since each raised-cosine ramp turns half its duration's worth). `targets`
    (speed_m_s, climb_m_s) are reached over the first ramp and held."""
    rate = angle_deg / (ramp_s + hold_s)
    return [Leg(ramp_s, turn_deg_s=rate, **targets), Leg(hold_s), Leg(ramp_s, turn_deg_s=0.0)]


def build_profiles(legs, speed0_m_s: float, heading0_deg: float):
    """(speed, course, climb) RateProfiles with common segment boundaries from a list of Legs."""
    speed, rate, climb = float(speed0_m_s), 0.0, 0.0
    s_segs, r_segs, c_segs = [], [], []
    for leg in legs:
        s1 = speed if leg.speed_m_s is None else float(leg.speed_m_s)
        r1 = rate if leg.turn_deg_s is None else float(leg.turn_deg_s) * DEG
        c1 = climb if leg.climb_m_s is None else float(leg.climb_m_s)
        s_segs.append(Segment(leg.duration_s, speed, s1))
        r_segs.append(Segment(leg.duration_s, rate, r1))
        c_segs.append(Segment(leg.duration_s, climb, c1))
        speed, rate, climb = s1, r1, c1
    if abs(speed - speed0_m_s) > 1e-9 or abs(rate) > 1e-12 or abs(climb) > 1e-12:
        raise ValueError("legs must end at the starting speed, with zero turn and climb rate (the profile repeats)")
    # speed and climb rate blend C² (quintic): the car's suspension pitch follows ṡ and the aircraft's bank
    # follows the vertical acceleration, so their attitude rates, which follow the jerk, must not jump
    return (RateProfile(s_segs, blend="quintic"), RateProfile(r_segs, angle0=heading0_deg * DEG),
            RateProfile(c_segs, blend="quintic"))


class TrackVehicle(EulerScenario):
    """Base of the vehicles: kinematics from the speed/course/climb profiles set by `_set_legs`."""

    rotating_earth = True
    current_ned_m_s: tuple = (0.0, 0.0, 0.0)

    def _set_legs(self, legs, speed0_m_s, heading0_deg):
        self._speed, self._course, self._climb = build_profiles(legs, speed0_m_s, heading0_deg)
        self.period_s = self._speed.period_s
        self.climb_per_period_m = self._climb.angle_per_period

    def speed_m_s(self, t_s):
        """Horizontal speed through the medium (water, road, air), m/s."""
        return self._speed.rate(np.asarray(t_s, dtype=float))

    def course_rad(self, t_s):
        """Direction of the velocity through the medium (not over ground when there is a current), rad."""
        return self._course.angle(np.asarray(t_s, dtype=float))

    def turn_rate_rad_s(self, t_s):
        return self._course.rate(np.asarray(t_s, dtype=float))

    def _heave(self, t):
        """Extra vertical motion (down positive): (velocity, acceleration); none by default."""
        return 0.0, 0.0

    def velocity_ned_m_s(self, t_s):
        t = np.asarray(t_s, dtype=float)
        s, chi = self._speed.rate(t), self._course.angle(t)
        vd, _ = self._heave(t)
        v = np.column_stack([s * np.cos(chi), s * np.sin(chi), -self._climb.rate(t) + vd])
        return v + np.asarray(self.current_ned_m_s, dtype=float)

    def accel_ned_m_s2(self, t_s):
        t = np.asarray(t_s, dtype=float)
        s, s_dot = self._speed.rate(t), self._speed.accel(t)
        chi, chi_dot = self._course.angle(t), self._course.rate(t)
        _, ad = self._heave(t)
        c, sn = np.cos(chi), np.sin(chi)
        return np.column_stack([s_dot * c - s * chi_dot * sn, s_dot * sn + s * chi_dot * c,
                                -self._climb.accel(t) + ad])

    def flight_path_rad(self, t):
        """Climb angle of the velocity through the medium, atan(climb / s)."""
        return np.arctan2(self._climb.rate(t), self._speed.rate(t))


# --------------------------------------------------------------------------------------------------------------
def _waves(t, comps):
    """Σ a sin(2πt/T + φ) and its first and second time derivatives, for (amplitude, period s, phase rad)."""
    y = dy = ddy = 0.0
    for a, p, ph in comps:
        w = 2 * math.pi / p
        arg = w * t + ph
        sin = np.sin(arg)
        y = y + a * sin
        dy = dy + a * w * np.cos(arg)
        ddy = ddy - a * w * w * sin
    return y, dy, ddy


def _wave_value(t, comps):
    """Σ a sin(2πt/T + φ) alone: `_waves(t, comps)[0]`, the same operations, without the derivatives."""
    y = 0.0
    for a, p, ph in comps:
        y = y + a * np.sin(2 * math.pi / p * t + ph)
    return y


@dataclass
class Boat(TrackVehicle):
    """A motor boat at 4–5 m/s through the water, turning at up to 7 °/s, in waves and a current.

    Heading follows the helm; the boat moves through the water `leeway_deg` to starboard of its heading (wind on
    the port side) and the water moves with `current_ned_m_s`, so the course over ground differs from the heading
    by up to ~10°. Waves roll (±5.5°) and pitch (±2.8°) it and heave it (±0.45 m); it heels outward in turns by
    `heel_deg_per_m_s2` per m/s² of centripetal acceleration (a displacement hull). Turns of +90°, −180°, +90°
    and +360° with speed changes between; 209 s, then repeats. Carries the default vehicle iron.
    """

    heading0_deg: float = 20.0
    leeway_deg: float = 2.0
    current_ned_m_s: tuple = (-0.25, 0.65, 0.0)     # 0.7 m/s setting towards 111°
    heel_deg_per_m_s2: float = 3.0
    name = "boat"
    description = "boat at 4–5 m/s, turns up to 7 °/s, waves (roll ±5.5°, heave ±0.45 m), 0.7 m/s current"
    default_iron = VehicleIron.default()

    _ROLL = ((4.0, 5.3, 0.0), (1.5, 2.3, 0.9))       # deg, s, rad
    _PITCH = ((2.0, 4.1, 0.4), (0.8, 1.7, 1.3))
    _HEAVE = ((0.35, 6.2, 0.2), (0.10, 2.9, 2.1))    # m, s, rad (up positive)

    def __post_init__(self):
        legs = [Leg(15.0), *turn(90.0, 3.0, 10.0), Leg(10.0, speed_m_s=5.0), Leg(10.0),
                *turn(-180.0, 4.0, 22.0), Leg(8.0, speed_m_s=4.5), Leg(4.0, turn_deg_s=3.0), Leg(8.0, turn_deg_s=-3.0),
                Leg(4.0, turn_deg_s=0.0), *turn(90.0, 3.0, 10.0, speed_m_s=4.0), Leg(12.0),
                *turn(360.0, 4.0, 48.0), Leg(20.0)]
        self._set_legs(legs, 4.0, self.heading0_deg)

    def heading_rad(self, t_s):
        return self.course_rad(t_s) - self.leeway_deg * DEG

    def _heave(self, t):
        _, dz, ddz = _waves(t, self._HEAVE)
        return -dz, -ddz                                  # down = −up

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        centripetal = self._speed.rate(t) * self._course.rate(t)          # to starboard in a right turn
        roll = _wave_value(t, self._ROLL) * DEG - self.heel_deg_per_m_s2 * DEG * centripetal
        return self.heading_rad(t), _wave_value(t, self._PITCH) * DEG, roll


@dataclass
class Car(TrackVehicle):
    """A car: from rest to 20 m/s, 0.4 g turns, braking, a slalom, a full circle, a hill; stops; repeats.

    No side slip (heading = course). The body pitches with the road grade (atan(climb / speed)) and the suspension
    adds `pitch_deg_per_m_s2` per m/s² of longitudinal acceleration (squat nose-up accelerating, dive braking)
    and rolls outward by `roll_deg_per_m_s2` per m/s² of lateral acceleration (typical 3–6°/g roll gradients).
    Peak lateral acceleration 0.40 g, peak braking 0.64 g; 173.5 s, then repeats from rest where it stopped.
    Carries the default vehicle iron.
    """

    heading0_deg: float = 75.0
    pitch_deg_per_m_s2: float = 0.25
    roll_deg_per_m_s2: float = 0.5
    name = "car"
    description = "car 0→20 m/s, 0.4 g turns, braking to 0.64 g, slalom, circle, ±3 % hill, stops"
    default_iron = VehicleIron.default()

    def __post_init__(self):
        legs = [Leg(5.0), Leg(10.0, speed_m_s=20.0), Leg(8.0),
                *turn(90.0, 2.0, 6.0),                                        # 20 m/s · 11.25 °/s = 0.40 g
                Leg(4.0), Leg(4.0, climb_m_s=0.6), Leg(4.0, climb_m_s=0.0), Leg(4.0),    # uphill, 3 % grade
                Leg(3.0, speed_m_s=10.0), Leg(5.0),                            # braking 0.64 g
                *turn(-90.0, 1.5, 2.5),                                       # 10 m/s · 22.5 °/s = 0.40 g
                Leg(4.0, speed_m_s=15.0), Leg(6.0),
                Leg(2.0, turn_deg_s=15.0), Leg(4.0, turn_deg_s=-15.0), Leg(4.0, turn_deg_s=15.0),
                Leg(4.0, turn_deg_s=-15.0), Leg(2.0, turn_deg_s=0.0), Leg(6.0),   # slalom, 15 m/s · 15 °/s = 0.40 g
                *turn(360.0, 2.0, 22.0),                                      # full circle at 0.40 g
                Leg(4.0, speed_m_s=20.0), Leg(6.0), Leg(4.0, climb_m_s=-0.6), Leg(4.0, climb_m_s=0.0), Leg(20.0),
                Leg(6.0, speed_m_s=0.0), Leg(9.0)]                             # braking 0.64 g, stand still
        self._set_legs(legs, 0.0, self.heading0_deg)

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        s = self._speed.rate(t)
        lateral = s * self._course.rate(t)
        pitch = self.flight_path_rad(t) + self.pitch_deg_per_m_s2 * DEG * self._speed.accel(t)
        return self.course_rad(t), pitch, -self.roll_deg_per_m_s2 * DEG * lateral


@dataclass
class Plane(TrackVehicle):
    """A fixed-wing at 20–26 m/s: coordinated turns banked 20–30°, a climb, a descending turn.

    Zero angle of attack and sideslip: body x along the velocity (yaw = course, pitch = flight-path angle), and
    the bank puts the specific force f = a − g in the body x–z plane: φ = atan2(f₁_y, −f₁_z) with f₁ the specific
    force in the yawed-and-pitched frame, which is atan(V χ̇ / g) in a level turn (f along body −z, g / cos φ).
    Turns: 360° right at 22 m/s (25°), 180° left at 26 m/s (29°), a 180° right descending turn at 20 m/s (23°);
    a 48 m climb at 3 m/s and the same height lost again; 182 s. `gravity_m_s2` is set to the site's by the stream.
    """

    heading0_deg: float = 30.0
    gravity_m_s2: float = 9.80
    name = "plane"
    description = "fixed-wing 20–26 m/s, coordinated turns banked 23–29°, 48 m climb and descending turn"

    def __post_init__(self):
        legs = [Leg(10.0), *turn(360.0, 4.0, 26.0), Leg(6.0), Leg(8.0, speed_m_s=26.0),
                Leg(4.0, climb_m_s=3.0), Leg(12.0), Leg(4.0, climb_m_s=0.0), Leg(6.0),   # +48 m
                *turn(-180.0, 3.0, 12.0), Leg(6.0), Leg(8.0, speed_m_s=20.0), Leg(6.0),
                *turn(180.0, 4.0, 11.0, climb_m_s=-2.0),                      # descending turn, −34 m
                Leg(5.0), Leg(4.0, climb_m_s=0.0),                            # −14 m
                Leg(6.0, speed_m_s=22.0), Leg(26.0)]
        self._set_legs(legs, 22.0, self.heading0_deg)

    def with_gravity(self, g_m_s2: float) -> "Plane":
        """The same flight under gravity `g_m_s2` (bank coordinated with the local g)."""
        return dataclasses.replace(self, gravity_m_s2=float(g_m_s2))

    def euler_rad(self, t_s):
        t = np.asarray(t_s, dtype=float)
        chi, theta = self.course_rad(t), self.flight_path_rad(t)
        a = self.accel_ned_m_s2(t)
        f_n, f_e, f_d = a[:, 0], a[:, 1], a[:, 2] - self.gravity_m_s2
        fx = np.cos(chi) * f_n + np.sin(chi) * f_e                          # heading frame
        fy = -np.sin(chi) * f_n + np.cos(chi) * f_e
        fz1 = np.sin(theta) * fx + np.cos(theta) * f_d                      # pitched: Ry(θ)ᵀ
        return chi, theta, np.arctan2(fy, -fz1)


VEHICLES = {"boat": Boat, "car": Car, "plane": Plane}
