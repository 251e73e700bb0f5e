"""estimator/lever_arm_kernel.py: the lever-arm check's innovation at a fix, compiled, gives the floats the Python it
replaced gave (InsGnssFusion.state_at's interpolation; the rows near the fix, their mean rate and C [ω×] of
tests/lever_arm_reference.py; the innovation v_fix − (v + C [ω×] r)) to rounding (to the bit on this machine: the
digests), on history rings with every case the fixes meet; its mean body rate is the Python's to the bit (rows
added newest first, then divided by their count); and that innovation is the antenna's velocity residual, checked
against scipy's rotation to rounding."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.history_rows import bracket
from ahrsd.estimator.lever_arm_fit import RATE_MEAN_S
from ahrsd.estimator.lever_arm_kernel import fix_innovation
from ahrsd.estimator.rotations import quat_to_dcm
from lever_arm_reference import mean_rate, rate_cross_ned, rows_near

H = core.H_LEN
HALF_S = 0.5 * RATE_MEAN_S


def _ring(rng, count: int, newest: int, rate_hz: float, t0_s: float = 1000.0):
    """A history ring with `count` kept rows up to `newest`, at irregular steps about 1/rate_hz (strictly increasing,
    as the kernel writes them), each with a random attitude near unit norm, velocity and body rate; the rows not kept
    hold stale times ahead of the kept ones (an older run's)."""
    hist = np.zeros(H, core.INS_HISTORY_DTYPE)
    hist["t_s"] = t0_s + 1e6
    hist["q"] = rng.normal(size=(H, 4)) * rng.uniform(0.99, 1.01, (H, 1))
    hist["q"] /= np.linalg.norm(hist["q"], axis=1, keepdims=True) * rng.uniform(0.999, 1.001, (H, 1))
    hist["vel_ned_m_s"] = rng.normal(0.0, 10.0, (H, 3))
    hist["rate_rad_s"] = rng.normal(0.0, 0.5, (H, 3))
    hist["rate_rad_s"][::7, 1] = -0.0
    times = t0_s + np.cumsum(rng.uniform(0.2, 1.8, count) / rate_hz)
    hist["t_s"][(newest - count + 1 + np.arange(count)) % H] = times
    return hist, times


def _python_terms(hist, newest: int, count: int, t_s: float, v_fix, arm):
    """What InsGnssFusion._add_to_lever_arm_fit computed before the kernel (session 38's Python), or None."""
    i0, i1, w = bracket(hist["t_s"], newest, count, t_s)
    if i0 < 0:
        return None
    rows = hist.view(np.float64).reshape(H, -1)
    a, b = rows[i0], rows[i1]
    row = a + w * (b - a)
    q, vel, rate = row[1:5], row[5:8], row[11:14]
    c_bn = quat_to_dcm(q / math.sqrt(q.dot(q)))
    near = rows_near(hist["t_s"], newest, count, t_s, HALF_S)
    rate_cross = rate_cross_ned(c_bn, mean_rate(hist["t_s"][near], hist["rate_rad_s"][near], t_s, rate))
    return v_fix - (vel + rate_cross @ arm), rate_cross, vel


CASES = [(1, 0), (2, 5), (40, 10), (H, 3), (H, H - 1), (H, 500), (700, 200)]


@pytest.mark.parametrize("count,newest", CASES)
@pytest.mark.parametrize("rate_hz", [5.0, 100.0, 819.2])
def test_the_kernels_terms_are_the_pythons(count, newest, rate_hz):
    """On rows, between rows, at the rate span's edges, after the newest row and before the oldest, a NaN time, a
    ring wrapped over its end, rows too sparse for any within the span (5 Hz: the interpolated rate), a vertical
    not used (NaN)."""
    rng = np.random.default_rng(count * 13 + newest + int(rate_hz))
    hist, times = _ring(rng, count, newest, rate_hz)
    rows = hist.view(np.float64).reshape(H, -1)
    some = times[np.unique(np.concatenate([rng.integers(0, count, 20), [0, count - 1]]))]
    queries = np.concatenate([some, some + 0.37 / rate_hz, some + HALF_S, some - HALF_S,
                              [times[0] - 1e-3, times[-1] + 1e-3, np.nan],
                              rng.uniform(times[0] - 0.1, times[-1] + 0.1, 30)])
    checked = 0
    for k, t in enumerate(queries.tolist()):
        v_fix = rng.normal(0.0, 10.0, 3)
        if k % 4 == 0:
            v_fix[2] = math.nan
        arm = rng.normal(0.0, 2.0, 3)
        found, innovation, rate_cross, vel = fix_innovation(rows, newest, count, t, v_fix, arm, HALF_S)
        want = _python_terms(hist, newest, count, t, v_fix, arm)
        assert found == (want is not None), t
        if want is None:
            continue
        checked += 1
        # to rounding, not bit for bit: the products are OpenBLAS's in both, through numpy's copy of the library and
        # scipy's (numba's); equal to the bit on the machine this was made on (tools/estimate_digest.py is the
        # bit-for-bit check), but two wheels' copies may differ in a kernel's last bit, as numpy's SIMD loops did
        # between CPUs (test_mag_rotation, session 39)
        for got, expected in zip((innovation, rate_cross, vel), want):
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12, err_msg=str(t))
    assert checked >= 4        # a one-row ring finds only the times at or after its row


@pytest.mark.parametrize("count,newest", [(40, 10), (H, 3), (H, 500)])
def test_the_kernels_mean_rate_is_the_pythons_to_the_bit(count, newest):
    """The mean body rate alone, bit for bit: every row's attitude level (q = 1, so C = I exactly and C [ω×] is
    [ω×] of the mean with no product to round), rates of magnitudes 1e-4 to 10 (so the order of the sums shows in
    the last bits), 819.2 Hz rows (~80 within the span). Broken (the rows added in another order, the sum divided
    otherwise): other bits than the reference's."""
    rng = np.random.default_rng(count + newest)
    hist, times = _ring(rng, count, newest, 819.2)
    hist["q"] = [1.0, 0.0, 0.0, 0.0]
    hist["rate_rad_s"] = rng.normal(0.0, 1.0, (H, 3)) * 10.0 ** rng.integers(-4, 2, (H, 1))
    rows = hist.view(np.float64).reshape(H, -1)
    differ = 0
    for t in rng.uniform(times[0], times[-1], 200).tolist():
        found, _, rate_cross, _ = fix_innovation(rows, newest, count, t, np.zeros(3), np.zeros(3), HALF_S)
        near = rows_near(hist["t_s"], newest, count, t, HALF_S)
        want = mean_rate(hist["t_s"][near], hist["rate_rad_s"][near], t, np.zeros(3))
        got = np.array([rate_cross[2, 1], rate_cross[0, 2], rate_cross[1, 0]])
        assert found and len(near) > 10, t
        assert got.tobytes() == want.tobytes(), (t, got - want)
        oldest_first = mean_rate(hist["t_s"][near[::-1]], hist["rate_rad_s"][near[::-1]], t, np.zeros(3))
        differ += oldest_first.tobytes() != want.tobytes()
    assert differ > 20          # the test sees the order: the other order's sums differ in a last bit here


def test_the_innovation_is_the_antennas_velocity_residual():
    """Independently of either: on a fix exactly at a row, with rows spaced wider than the rate span (the row's own
    rate), the innovation is v_fix − (v + C (ω × r)), C from scipy's rotation of the row's quaternion."""
    rng = np.random.default_rng(5)
    hist, times = _ring(rng, 50, 49, 1.0)
    rows = hist.view(np.float64).reshape(H, -1)
    for k in (3, 17, 49):
        q, v, w = hist["q"][k], hist["vel_ned_m_s"][k], hist["rate_rad_s"][k]
        arm, v_fix = rng.normal(0.0, 2.0, 3), rng.normal(0.0, 10.0, 3)
        c_bn = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()     # scipy: scalar last
        found, innovation, rate_cross, vel = fix_innovation(rows, 49, 50, float(times[k]), v_fix, arm, HALF_S)
        assert found
        np.testing.assert_allclose(innovation, v_fix - (v + c_bn @ np.cross(w, arm)), rtol=0, atol=1e-12)
        np.testing.assert_allclose(rate_cross @ arm, c_bn @ np.cross(w, arm), rtol=0, atol=1e-12)


def test_no_rows_no_terms():
    rows = np.zeros(H, core.INS_HISTORY_DTYPE).view(np.float64).reshape(H, -1)
    found, *_ = fix_innovation(rows, 0, 0, 1.0, np.zeros(3), np.zeros(3), HALF_S)
    assert not found
