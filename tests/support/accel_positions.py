"""Orientations for multi-position accelerometer calibration tests: which body vector points up; the bench
recording of 24 held positions."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ahrsd.calibration.inertial.accel import GUIDED_TARGETS
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import RecordingWriter
from ahrsd.simulation import SensorErrors, simulate


def up_vectors(n_random: int = 0) -> np.ndarray:
    """The 6 faces + 8 corners of the guided procedure, 12 edge midpoints, and optional random ones."""
    faces_corners = [d for _, d in GUIDED_TARGETS]
    edges = [v for v in ([a, b, 0] for a in (1, -1) for b in (1, -1))] + \
            [[a, 0, b] for a in (1, -1) for b in (1, -1)] + [[0, a, b] for a in (1, -1) for b in (1, -1)]
    u = np.vstack([np.array(faces_corners, float), np.array(edges, float)])
    if n_random:
        u = np.vstack([u, Rotation.random(n_random, random_state=3).apply([0, 0, 1])])
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def roll_pitch_for_up(u: np.ndarray) -> tuple[float, float]:
    """(roll, pitch) in degrees that make the accelerometer read +g along the body vector u."""
    return math.degrees(math.atan2(-u[1], -u[2])), math.degrees(math.asin(np.clip(u[0], -1, 1)))


def position_holds(n_positions: int = 24, hold_s: float = 3.0, slew_s: float = 1.0):
    """A multi-position bench recording's trajectory: `n_positions` orientations (faces, corners, edges of
    `up_vectors`), each held still for `hold_s`, joined by smooth `slew_s` turns (what a person or a
    positioner does). Returns (scenario, hold windows [(t_start, t_end)], up vectors)."""
    from dataclasses import dataclass

    from ahrsd.simulation.scenarios import EulerScenario

    ups = up_vectors(max(0, n_positions - 26))[:n_positions]
    angles = np.array([[30.0 * k, *roll_pitch_for_up(u)[::-1]] for k, u in enumerate(ups)])  # yaw, pitch, roll
    for k in range(1, len(angles)):   # turn the short way round between positions
        angles[k] = angles[k - 1] + (angles[k] - angles[k - 1] + 180.0) % 360.0 - 180.0
    period = hold_s + slew_s
    windows = [(k * period, k * period + hold_s) for k in range(len(ups))]

    @dataclass
    class PositionHolds(EulerScenario):
        name = "position-holds"
        description = f"{len(ups)} positions held {hold_s} s, {slew_s} s smooth slews between"

        def euler_rad(self, t_s):
            t = np.atleast_1d(np.asarray(t_s, dtype=float))
            k = np.clip((t // period).astype(int), 0, len(angles) - 1)
            into = t - k * period
            nxt = np.minimum(k + 1, len(angles) - 1)
            x = np.clip((into - hold_s) / slew_s, 0.0, 1.0)
            blend = x * x * (3.0 - 2.0 * x)          # smoothstep: zero rate at both ends of a slew
            a = angles[k] + blend[:, None] * (angles[nxt] - angles[k])
            return tuple(np.radians(a[:, i]) for i in range(3))

    return PositionHolds(), windows, ups


def holds_recording(path, hold_s: float, seed: int = 5, rate_hz: float = 100.0):
    """A recording at `path` (with temp_c) of the simulated ADIS16405, its error model's bias, scale and
    misalignment injected (seed `seed`), through `position_holds(24, hold_s, 1 s slews)`: (block, windows, errors)."""
    scenario, windows, _ = position_holds(24, hold_s=hold_s, slew_s=1.0)
    errors = SensorErrors.adis16405(seed=seed)
    block = simulate(scenario, windows[-1][1], rate_hz=rate_hz, seed=seed, errors=errors)
    with RecordingWriter(path, extra_columns=("temp_c",)) as w:
        for i in range(len(block)):
            w.write(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]),
                    temp_c=block.temp_c[i])
    return block, windows, errors
