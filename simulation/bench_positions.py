"""`accel-positions`: an operator taking the unit through `ahrsd calibrate accel --live --align-to-faces` on a bench
whose surface is not quite level.

Each of the six faces up twice — the second time turned half round about the surface's normal — then the eight
corners (an axis pair's diagonal up), each held `hold_s` and moved to the next in `move_s` (one smooth rotation).
The surface is tilted `surface_tilt_deg` towards `tilt_azimuth_deg`, so every placement's up direction is that far
off its axis, in a direction that turns half round with the unit: the mean of a face's pair is on the axis
(calibration/inertial/accel_alignment.py). After the last position the unit stays there. Not one of the contract's
SCENARIOS (`make_scenario("accel-positions")`, `--sim accel-positions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ahrsd.simulation.profiles import smoothstep
from ahrsd.simulation.scenario_base import Scenario

if TYPE_CHECKING:   # imported where a rotation is made (simulation/scenarios.py says why)
    from scipy.spatial.transform import Rotation

_UP_NED = np.array([0.0, 0.0, -1.0])
# the body direction that points up in each position (FRD: level is −z up)
FACES = ((0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0))
CORNERS = tuple((sx, sy, sz) for sx in (1.0, -1.0) for sy in (1.0, -1.0) for sz in (1.0, -1.0))


def _up_along(d) -> Rotation:
    """A body→NED rotation that points the body direction d up."""
    from scipy.spatial.transform import Rotation

    d = np.asarray(d, dtype=float) / np.linalg.norm(d)
    c = float(d @ _UP_NED)
    if c > 1.0 - 1e-12:
        return Rotation.identity()
    if c < -1.0 + 1e-12:
        return Rotation.from_euler("X", 180.0, degrees=True)
    axis = np.cross(d, _UP_NED)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.acos(c))


@dataclass
class AccelPositions(Scenario):
    """See the module docstring."""

    hold_s: float = 8.0
    move_s: float = 4.0
    surface_tilt_deg: float = 0.2
    tilt_azimuth_deg: float = 30.0
    heading_deg: float = 40.0
    name = "accel-positions"
    description = ("the live accelerometer calibration's 20 positions (each face twice, turned half round; the "
                   "corners) on a surface 0.2° off level")

    def __post_init__(self):
        from scipy.spatial.transform import Rotation

        az = math.radians(self.tilt_azimuth_deg)
        tilt_axis = np.array([-math.sin(az), math.cos(az), 0.0])     # horizontal, normal to the tilt's azimuth
        surface = Rotation.from_rotvec(math.radians(self.surface_tilt_deg) * tilt_axis)
        placements = [(d, turn) for d in FACES for turn in (0.0, 180.0)] + [(d, 0.0) for d in CORNERS]
        self.up_directions = np.array([np.asarray(d) / np.linalg.norm(d) for d, _ in placements])
        rots = [surface * Rotation.from_euler("Z", self.heading_deg + turn, degrees=True) * _up_along(d)
                for d, turn in placements]
        self._quats = np.array([r.as_quat() for r in rots])
        self._steps = np.array([(rots[k].inv() * rots[k + 1]).as_rotvec() for k in range(len(rots) - 1)]
                               + [np.zeros(3)])
        self.surface_normal_ned = surface.apply(_UP_NED)

    @property
    def n_positions(self) -> int:
        return len(self._quats)

    def attitude(self, t_s):
        from scipy.spatial.transform import Rotation

        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        period = self.hold_s + self.move_s
        k = np.clip(np.floor(t / period).astype(int), 0, self.n_positions - 1)
        x = np.clip((t - k * period - self.hold_s) / self.move_s, 0.0, 1.0)
        x = np.where(k == self.n_positions - 1, 0.0, x)
        return Rotation.from_quat(self._quats[k]) * Rotation.from_rotvec(self._steps[k] * smoothstep(x)[:, None])
