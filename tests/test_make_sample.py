"""core.sample.make_sample: every vector becomes a float64 array of shape (3,) with the values given, whatever it was
given as; a row of an (n, 3) float64 array (what per-sample loops pass) is taken without a copy."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.core.sample import SampleFlags, make_sample


@pytest.mark.parametrize("given", [
    [1, 2, 3],                                        # ints
    (0.5, -1.25, 3e-9),
    np.array([1.5, 2.5, 3.5], dtype=np.float32),
    np.array([[1.0], [2.0], [3.0]]),                  # (3, 1)
    np.array([[1.0, 2.0, 3.0]]),                      # (1, 3)
    np.arange(9.0).reshape(3, 3)[:, 1],               # a strided column
    np.arange(6.0).reshape(2, 3)[1],                  # a row
])
def test_each_vector_is_float64_of_shape_3_with_the_values_given(given):
    s = make_sample(1, given, given, given, flags=SampleFlags.NEW_DATA)
    expected = np.array(given, dtype=np.float64).reshape(3)   # numpy's own conversion, element by element
    for v in (s.gyro_rad_s, s.accel_m_s2, s.mag_ut):
        assert type(v) is np.ndarray and v.dtype == np.float64 and v.shape == (3,)
        assert np.array_equal(v, expected)
    assert type(s.t_s) is float and s.t_s == 1.0 and s.flags == SampleFlags.NEW_DATA


def test_a_row_of_a_float64_block_shares_its_memory():
    block = np.random.default_rng(0).normal(size=(4, 3))
    s = make_sample(0.0, block[2], block[2], block[2])
    assert np.shares_memory(s.gyro_rad_s, block) and np.array_equal(s.gyro_rad_s, block[2])


@pytest.mark.parametrize("bad", [[1.0, 2.0], np.zeros(4), np.zeros((2, 3))])
def test_a_vector_of_another_size_is_refused(bad):
    with pytest.raises(ValueError):
        make_sample(0.0, bad, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
