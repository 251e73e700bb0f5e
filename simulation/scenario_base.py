"""The scenario base: a truth trajectory's interface (`Scenario`), the Euler-angle form most scenarios take
(`EulerScenario`) and the constant-speed track the vehicles follow — apart from the scenarios themselves, so the
modules that build on them (scenarios.py, vehicles.py, bench_positions.py) import it without importing each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ahrsd.simulation.euler_quat import quat_xyzw_from_euler_zyx
from ahrsd.simulation.magnetic import VehicleIron
from ahrsd.simulation.profiles import RateProfile

# scipy's Rotation is imported where a rotation is made (scenarios.py says why)
if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

DEG = math.pi / 180.0
_RATE_STEP_S = 1e-5  # half-width of the central difference for the body rate


def euler_zyx(yaw, pitch, roll) -> Rotation:
    """C_b^n = Rz(yaw) Ry(pitch) Rx(roll) (ZYX Euler, body→NED)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))


class Scenario:
    """Base class. Subclasses implement `attitude`; motion and disturbances default to none."""

    name: str = ""
    description: str = ""
    default_iron: VehicleIron | None = None  # the vehicle iron this scenario carries unless overridden
    rotating_earth: bool = False  # simulated on a rotating Earth unless open_stream(earth_rate=...) says otherwise

    def attitude(self, t_s: np.ndarray) -> Rotation:
        raise NotImplementedError

    def attitude_xyzw(self, t_s: np.ndarray) -> np.ndarray:
        """The attitude as (n, 4) quaternions, scalar last: `attitude(t_s).as_quat()`."""
        return self.attitude(t_s).as_quat()

    def body_rate_rad_s(self, t_s: np.ndarray) -> np.ndarray:
        """ω of body w.r.t. NED, in body axes: R(t+h) = R(t−h) exp(2h ω)."""
        t = np.asarray(t_s, dtype=float)
        tp, tm = t + _RATE_STEP_S, t - _RATE_STEP_S
        rel = self.attitude(tm).inv() * self.attitude(tp)
        return rel.as_rotvec() / (tp - tm)[:, None]

    def attitude_and_rate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(`attitude_xyzw(t_s)`, `body_rate_rad_s(t_s)`): what a stream needs at its sample times."""
        return self.attitude_xyzw(t_s), self.body_rate_rad_s(t_s)

    def body_angular_accel_rad_s2(self, t_s: np.ndarray) -> np.ndarray:
        """dω/dt in body axes (central difference of the body rate over ±0.1 ms; for lever-arm effects)."""
        t = np.asarray(t_s, dtype=float)
        h = 100 * _RATE_STEP_S
        return (self.body_rate_rad_s(t + h) - self.body_rate_rad_s(t - h)) / (2 * h)

    def accel_ned_m_s2(self, t_s: np.ndarray) -> np.ndarray:
        """Acceleration of the sensor relative to the Earth, NED, m/s² (zero for a vehicle that stays put)."""
        return np.zeros((len(t_s), 3))

    def velocity_ned_m_s(self, t_s: np.ndarray) -> np.ndarray:
        return np.zeros((len(t_s), 3))

    def disturbance_ned_ut(self, t_s: np.ndarray) -> np.ndarray | None:
        """Local magnetic disturbance (not the Earth's field, not vehicle iron), NED, µT; None when absent."""
        return None

    def with_gravity(self, g_m_s2: float) -> "Scenario":
        """The scenario under the local gravity `g_m_s2` (a stream's site): itself, unless its motion depends on g
        (a coordinated turn banks by atan(v·ω/g): simulation.scenarios.CoordinatedTurn, vehicles.Plane)."""
        return self


class EulerScenario(Scenario):
    """A scenario whose attitude is given by ZYX Euler angles (yaw, pitch, roll) as smooth functions of time.

    The body rate then follows from the Euler rates without evaluating the rotation three times:
    ω_b = [φ̇ − ψ̇ sinθ,  θ̇ cosφ + ψ̇ sinφ cosθ,  −θ̇ sinφ + ψ̇ cosφ cosθ]   (ω_b = φ̇ e_x + Rx(φ)ᵀ θ̇ e_y
    + (Ry(θ) Rx(φ))ᵀ ψ̇ e_z), with the Euler rates from central differences of the angle functions (±10 µs).
    The tests integrate this rate and compare with scipy's attitude, so the formula is checked, not trusted.
    """

    def euler_rad(self, t_s: np.ndarray):
        """(yaw, pitch, roll) arrays in rad, ZYX, body→NED."""
        raise NotImplementedError

    def attitude(self, t_s):
        return euler_zyx(*self.euler_rad(np.asarray(t_s, dtype=float)))

    def attitude_xyzw(self, t_s):
        # without scipy (the same bits as euler_zyx's): the simulated chip's producer computes its blocks with this
        return quat_xyzw_from_euler_zyx(*self.euler_rad(np.asarray(t_s, dtype=float)))

    def attitude_and_rate(self, t_s):
        cls = type(self)
        if (cls.attitude_xyzw is not EulerScenario.attitude_xyzw
                or cls.body_rate_rad_s is not EulerScenario.body_rate_rad_s):    # a subclass's own: use them
            return super().attitude_and_rate(t_s)
        # the angles at t_s once, for both (each would evaluate them)
        t = np.asarray(t_s, dtype=float)
        euler = self.euler_rad(t)
        return quat_xyzw_from_euler_zyx(*euler), self._body_rate(t, euler)

    def body_rate_rad_s(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return self._body_rate(t, self.euler_rad(t))

    def _body_rate(self, t, euler):
        """The body rate at t from the angles there, `euler` = euler_rad(t), and the angles' central differences."""
        tp, tm = t + _RATE_STEP_S, t - _RATE_STEP_S
        _, th, ph = euler
        ap, am = self.euler_rad(tp), self.euler_rad(tm)
        dpsi, dth, dph = ((x1 - x0) / (tp - tm) for x1, x0 in zip(ap, am))
        sph, cph, sth, cth = np.sin(ph), np.cos(ph), np.sin(th), np.cos(th)
        return np.column_stack([dph - dpsi * sth, dth * cph + dpsi * sph * cth, -dth * sph + dpsi * cph * cth])


# --------------------------------------------------------------------------------------------------------------
def track_velocity_ned_m_s(speed_m_s: float, psi_rad, vz_m_s) -> np.ndarray:
    """NED velocity of a vehicle moving at constant speed along heading psi, with vertical speed vz."""
    return np.column_stack([speed_m_s * np.cos(psi_rad), speed_m_s * np.sin(psi_rad), vz_m_s])


def track_accel_ned_m_s2(speed_m_s: float, psi_rad, rate_rad_s, az_m_s2) -> np.ndarray:
    """NED acceleration of that vehicle: the centripetal term of turning at rate r, plus vertical az."""
    return np.column_stack([-speed_m_s * rate_rad_s * np.sin(psi_rad), speed_m_s * rate_rad_s * np.cos(psi_rad),
                            az_m_s2])


class ConstantSpeedTrack(EulerScenario):
    """An EulerScenario moving level at `speed_m_s` along the heading profile `self._heading` (a RateProfile)."""

    def velocity_ned_m_s(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return track_velocity_ned_m_s(self.speed_m_s, self._heading.angle(t), np.zeros_like(t))

    def accel_ned_m_s2(self, t_s):
        t = np.asarray(t_s, dtype=float)
        return track_accel_ned_m_s2(self.speed_m_s, self._heading.angle(t), self._heading.rate(t), np.zeros_like(t))
