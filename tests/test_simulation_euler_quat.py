"""The simulator's scipy-free Euler attitude (simulation/euler_quat.py) gives scipy's bits, and the simulated chip's
producer computes an Euler scenario's blocks without importing scipy.spatial.

The reference is scipy's `Rotation` itself (from_euler("ZYX"), inv().apply, as_quat), compared byte for byte:
the simulator's output must not change when it stops calling scipy (docs/simulation.md)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.simulation import SCENARIOS, open_stream
from ahrsd.simulation.euler_quat import ned_to_body, quat_xyzw_from_euler_zyx
from ahrsd.simulation.scenario_base import EulerScenario
from ahrsd.simulation.scenarios import make_scenario


def _angle_sets():
    """General angles, a yaw alone, small angles with exact (signed) zeros, and the special values."""
    rng = np.random.default_rng(32)
    general = rng.uniform(-4.0, 4.0, (500, 3))
    yaw_only = np.zeros((300, 3))
    yaw_only[:, 0] = rng.uniform(-4.0, 4.0, 300)
    small = rng.normal(0.0, 1e-3, (500, 3))
    small[rng.random((500, 3)) < 0.3] = 0.0
    small[rng.random((500, 3)) < 0.1] *= -0.0
    special = rng.choice([0.0, -0.0, np.pi, -np.pi, np.pi / 2, 1.0], (300, 3))
    return [general, yaw_only, small, special, general[:1]]


@pytest.mark.parametrize("which", range(5))
def test_quaternions_and_rotated_vectors_are_scipys_bits(which):
    angles = _angle_sets()[which]
    ref = Rotation.from_euler("ZYX", angles)
    q = quat_xyzw_from_euler_zyx(angles[:, 0], angles[:, 1], angles[:, 2])
    assert q.tobytes() == ref.as_quat().tobytes()
    rng = np.random.default_rng(which)
    many = rng.normal(0.0, 10.0, (len(angles), 3))
    many[rng.random(many.shape) < 0.2] = 0.0
    for v in (many, np.array([20.0, -3.0, 45.0]), np.array([0.0, 0.0, 9.80665])):
        want = ref.inv().apply(v)
        got = ned_to_body(q, v)
        assert got.shape == want.shape
        assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("name", [n for n in SCENARIOS if isinstance(make_scenario(n), EulerScenario)])
def test_an_euler_scenarios_stream_attitude_is_scipys(name):
    """The stream's truth attitude (scalar first, w ≥ 0) and the Earth field in body axes, from scipy."""
    stream = open_stream(name, rate_hz=100.0, seed=1)
    block = stream.next_block(400)
    sc = stream.scenario
    ref = Rotation.from_euler("ZYX", np.column_stack(sc.euler_rad(block.t_s)))
    q = ref.as_quat()
    q = np.column_stack([q[:, 3], q[:, :3]])
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    assert block.truth_q_wxyz.tobytes() == q.tobytes()
    assert block.truth_mag_ut.tobytes() == ref.inv().apply(stream.earth_field.ned_ut).tobytes()


def test_the_producer_computes_an_euler_scenarios_blocks_without_scipy_spatial():
    """The chip's producer (drivers.sim_block_producer) computes its blocks with open_stream's next_block."""
    probe = ("import sys\nfrom ahrsd.simulation import open_stream\n"
             "for name in ('static', 'boat', 'car', 'plane', 'level-turns'):\n"
             "    s = open_stream(name, rate_hz=819.2, seed=1)\n"
             "    s.next_block(256); s.next_block(256)\n"
             "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
