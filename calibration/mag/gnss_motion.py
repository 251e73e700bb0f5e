"""The accelerometer's specific force less the vehicle's own acceleration, from the GNSS speed and the gyro's turn
rate: a levelling for the accelerometer-levelled fit of `calibrate mag --gnss` (backstepping_aided.py) that a
vehicle whose speed changes does not tilt, and that needs no heading.

The accelerometer measures f = a − g·d (body frame, d = NED down), so levelled by f alone a car braking at 2 m/s²
reads a pitch 12° off and one cornering at 15 m/s and 0.3 rad/s a roll 25° off. back-stepping's own turn model
(vertical_channel.centripetal_direction with a fitted constant speed) removes the lean of a vehicle that turns at a
steady speed; a car's speed goes from 0 to 20 m/s and back, the fitted constant does not describe it, and the fit
then either leans or does not converge (docs/gnss.md "Offline").

With the vehicle moving along its body x axis over the ground (no sideslip, no current: a road vehicle), its
acceleration in the body frame is

    a = V̇·x_h + V·ψ̇·r_h          (Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation
                                   Systems, 2nd ed., §2.4: the along-track and centripetal parts)

with V the GNSS ground speed, V̇ its rate of change (the fixes' speeds differenced), ψ̇ the turn rate about the
vertical (the gyro), r_h the horizontal right direction and x_h = r_h × d the horizontal forward one. Neither needs
the heading. The true down is then ∝ g·d₀ + a (d₀ the accelerometer's own down); r_h and x_h are taken at the
corrected down, twice (the second pass changes the down by the lean's second-order part only).

A boat in a current moves over the ground by its speed through the water plus the current's, so V·ψ̇ with the
ground speed misplaces the lean; back-stepping's fitted constant speed through the water fits a boat better
(measured in docs/gnss.md "Offline"), which is why the aided fit keeps whichever levelling explains the vertical
field better.
"""

from __future__ import annotations

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2

from .observability import lowpass
from .vertical_channel import centripetal_direction

DOWN_PASSES = 2              # r_h and x_h from the corrected down: once from the accelerometer's, once again
DIRECTION_TAU_S = 0.2        # low-pass of the accelerometer for the directions only (backstepping's accel_tau_s)


def gnss_speed_and_rate(t_s: np.ndarray, fixes) -> tuple[np.ndarray, np.ndarray]:
    """The ground speed V (m/s) and its rate V̇ (m/s², central differences of the fixes with a velocity,
    np.gradient) at the times `t_s`, linearly interpolated between fixes (held before the first and after the
    last)."""
    usable = [f for f in fixes if f.has_velocity]
    if len(usable) < 2:
        raise ValueError(f"the GNSS speed needs at least 2 fixes with a velocity, got {len(usable)}")
    tf = np.array([f.t_s for f in usable], dtype=np.float64)
    v = np.array([f.ground_speed_m_s for f in usable], dtype=np.float64)
    v_dot = np.gradient(v, tf)
    return np.interp(t_s, tf, v), np.interp(t_s, tf, v_dot)


def vehicle_acceleration_body(down_body: np.ndarray, gyro_rad_s: np.ndarray, speed_m_s: np.ndarray,
                              speed_rate_m_s2: np.ndarray) -> np.ndarray:
    """a = V̇·x_h + V·ψ̇·r_h in the body frame (m/s², (n, 3)) for the unit down vectors `down_body`."""
    d = np.asarray(down_body, dtype=np.float64)
    c = np.sqrt(np.maximum(d[:, 1] ** 2 + d[:, 2] ** 2, 1e-6))
    right = np.column_stack((np.zeros(d.shape[0]), d[:, 2], -d[:, 1])) / c[:, None]   # d × x̂ / |d × x̂|
    forward = np.cross(right, d)
    turn = centripetal_direction(gyro_rad_s, d)            # ψ̇·r_h
    return speed_m_s[:, None] * turn + speed_rate_m_s2[:, None] * forward


def accel_less_gnss_motion(t_s: np.ndarray, accel_m_s2: np.ndarray, gyro_rad_s: np.ndarray, fixes) -> np.ndarray:
    """The accelerometer samples (m/s², (n, 3)) less the vehicle's acceleration the GNSS speed and the gyro give
    (the module docstring): what the accelerometer would read if the vehicle did not accelerate."""
    accel = np.asarray(accel_m_s2, dtype=np.float64)
    speed, speed_rate = gnss_speed_and_rate(np.asarray(t_s, dtype=np.float64), fixes)
    smooth = lowpass(accel, t_s, DIRECTION_TAU_S)
    d0 = -smooth / np.linalg.norm(smooth, axis=1, keepdims=True)
    d, a = d0, np.zeros_like(accel)
    for _ in range(DOWN_PASSES):
        a = vehicle_acceleration_body(d, gyro_rad_s, speed, speed_rate)
        u = STANDARD_GRAVITY_M_S2 * d0 + a
        d = u / np.linalg.norm(u, axis=1, keepdims=True)
    return np.ascontiguousarray(accel - a)
