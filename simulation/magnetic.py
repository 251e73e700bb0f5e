"""The magnetic environment around the sensor besides the main field: vehicle iron and passing magnets.

Model (CONTRIBUTING, "Simulation"): measured = soft_iron_distortion · true + hard_iron, so a perfect
calibration is inv(soft_iron_distortion) · (raw − hard_iron). Vehicle iron multiplies every external field the
sensor sees, the main field and local disturbances alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MU0_OVER_4PI = 1e-7  # T·m/A (exact enough: CODATA μ0/4π = 1.00000000055e-7)


@dataclass(frozen=True, eq=False)
class VehicleIron:
    """Magnetic distortion caused by the vehicle the sensor is bolted to.

    hard_iron_ut: (3,) permanent field of the vehicle at the sensor, body frame, µT.
    soft_iron: (3,3) dimensionless distortion matrix (induced magnetisation), measured = soft_iron · B + hard.
    """

    hard_iron_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        h = np.array(self.hard_iron_ut, dtype=float).reshape(3)
        s = np.array(self.soft_iron, dtype=float).reshape(3, 3)
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(s))):
            raise ValueError("vehicle iron must be finite")
        if abs(np.linalg.det(s)) < 1e-6:
            raise ValueError("soft-iron matrix is singular")
        h.flags.writeable = False
        s.flags.writeable = False
        object.__setattr__(self, "hard_iron_ut", h)
        object.__setattr__(self, "soft_iron", s)

    @classmethod
    def none(cls) -> "VehicleIron":
        return cls()

    @classmethod
    def default(cls) -> "VehicleIron":
        """The simulator's default vehicle: a steel-framed boat/AUV with a few hundred mgauss of hard iron.

        Hard iron 280/−350/220 mgauss (1 mgauss = 0.1 µT) and a non-symmetric soft-iron matrix with ±8 %
        scale and a few % cross-coupling, so the field fits (ellipsoid, back-stepping) have something to find.
        Chosen values, not measured on a vehicle; Nourmohammadi & Sabet (J. of Control 16(3), 2022)
        Table 2 reports biases of 1–5 µT and scale
        differences of ~10 % on a steel AUV hull, the same order.
        """
        return cls(
            hard_iron_ut=np.array([28.0, -35.0, 22.0]),
            soft_iron=np.array([
                [1.08, 0.05, -0.03],
                [-0.02, 0.94, 0.04],
                [0.06, -0.01, 1.03],
            ]),
        )


    @classmethod
    def held_out(cls) -> "VehicleIron":
        """Another strong non-symmetric vehicle iron, for figures measured on vehicles the estimators were not
        tuned on: hard iron −310/240/−180 mgauss, soft iron with −7…+9 % scale and up to 6 % cross-coupling.
        Chosen values, of the same order as `default`."""
        return cls(
            hard_iron_ut=np.array([-31.0, 24.0, -18.0]),
            soft_iron=np.array([
                [0.93, -0.06, 0.04],
                [0.03, 1.09, -0.05],
                [-0.05, 0.02, 0.96],
            ]),
        )

    @classmethod
    def unseen(cls) -> "VehicleIron":
        """A third strong non-symmetric vehicle iron, never used to choose anything: only for figures at places
        and irons nobody tuned on (issue 28's "held-back vehicles"). Drawn once, not chosen:
        `rng = np.random.default_rng(2028)`; hard iron `rng.uniform(20, 40, 3) * rng.choice([-1, 1], 3)` µT;
        soft iron `I + diag(rng.uniform(-0.10, 0.10, 3))` plus `rng.uniform(-0.10, 0.10, (3, 3))` with its
        diagonal zeroed (±10 % cross-coupling, not symmetric); rounded to 0.1 µT and 0.001. Its hard iron is
        several times the horizontal Earth field at a high dip."""
        return cls(
            hard_iron_ut=np.array([-27.7, 31.9, 34.7]),
            soft_iron=np.array([
                [0.980, -0.085, -0.097],
                [-0.046, 1.066, 0.019],
                [0.028, -0.091, 0.996],
            ]),
        )


def dipole_field_ut(moment_a_m2: np.ndarray, r_m: np.ndarray) -> np.ndarray:
    """Field (µT) of point dipoles with moment `moment_a_m2` (…,3) at offset `r_m` (…,3) from dipole to sensor.

    B = μ0/4π · (3 r̂ (r̂·m) − m) / |r|³.
    """
    r = np.asarray(r_m, dtype=float)
    m = np.asarray(moment_a_m2, dtype=float)
    dist = np.linalg.norm(r, axis=-1, keepdims=True)
    rhat = r / dist
    b_t = MU0_OVER_4PI * (3.0 * rhat * np.sum(rhat * m, axis=-1, keepdims=True) - m) / dist**3
    return b_t * 1e6


@dataclass(frozen=True)
class PassingMagnet:
    """A magnet carried back and forth past the sensor along a straight line (fixed in NED).

    Position of the magnet relative to the sensor: closest_approach_m · u_perp + x(t) · u_path, with
    x(t) = −half_path_m · cos(2π t / period_s), so it sweeps in from far away, passes at the closest approach,
    goes out to the other end and comes back: two passes per period, smooth in time (no jump when repeating).
    """

    moment_ned_a_m2: tuple = (1.2, -1.6, 0.0)    # |m| = 2 A·m²: a large hand-held magnet or a tool
    closest_approach_m: float = 0.3
    half_path_m: float = 3.0
    period_s: float = 60.0
    path_dir_ned: tuple = (1.0, 0.0, 0.0)
    offset_dir_ned: tuple = (0.0, 1.0, 0.0)

    def position_ned_m(self, t_s) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        x = -self.half_path_m * np.cos(2.0 * np.pi * t / self.period_s)
        u = np.asarray(self.path_dir_ned, dtype=float)
        v = np.asarray(self.offset_dir_ned, dtype=float)
        return self.closest_approach_m * v + x[:, None] * u

    def field_ned_ut(self, t_s) -> np.ndarray:
        """Disturbance field at the sensor, NED, µT (the sensor is at the origin)."""
        r_sensor_from_magnet = -self.position_ned_m(t_s)
        return dipole_field_ut(np.asarray(self.moment_ned_a_m2, dtype=float), r_sensor_from_magnet)
