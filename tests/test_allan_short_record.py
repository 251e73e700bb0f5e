"""A record too short for the Allan fit gets a reason, not a crash (calibration/allan.py read_axis,
calibration/allan_terms.py select_terms)."""

import numpy as np
import pytest

from ahrsd.calibration.allan import analyse_static, read_axis
from ahrsd.calibration.allan_adev import StreamingAllan
from ahrsd.calibration.allan_terms import octave_points

RATE_HZ = 819.2
SIGMA = 1e-3                                   # rad/s per sample before the window
DENSITY = SIGMA / np.sqrt(RATE_HZ)             # a unit-gain window keeps the white-noise density at 0 Hz


def _bartlett_filtered(n: int, length: int, seed: int) -> np.ndarray:
    """Independent white noise through a Bartlett window of `length` taps, like the chip's SENS_AVG."""
    rng = np.random.default_rng(seed)
    w = np.bartlett(length + 2)[1:-1]
    w /= w.sum()
    return np.stack([np.convolve(rng.normal(0.0, SIGMA, n + length), w, "valid")[:n] for _ in range(3)], axis=1)


@pytest.mark.parametrize("n, length", [(3000, 4), (5000, 16), (8000, 16)])
def test_a_short_filtered_record_is_analysed_without_error(n, length):
    # These records left a lone Gauss–Markov term no τ range to fit in, and the term selection raised a bare
    # "need at least one array to concatenate".
    gyro = _bartlett_filtered(n, length, seed=n + length)
    result = analyse_static(np.arange(n) / RATE_HZ, gyro_rad_s=gyro)
    for axis, p in result.parameters["gyro"].items():
        if p.white_noise is not None:       # where white noise is read, it is the density the noise has
            assert p.white_noise == pytest.approx(DENSITY, rel=0.2), axis
        else:
            assert any("white" in flag or "too short" in flag for flag in p.flags), (axis, p.flags)


def test_too_few_cluster_sizes_beyond_the_filter_reads_no_term_and_says_how_long_to_record():
    # 2 s of samples correlated over 40 samples: only τ ≥ 8·40/819.2 = 0.39 s can be fitted, and a 2 s record has
    # fewer than three cluster sizes there. A fit over the bent short τ would read the filter as a Gauss–Markov term.
    n = 1640
    acc = StreamingAllan(RATE_HZ, n_axes=3)
    acc.add(_bartlett_filtered(n, 40, seed=3))
    curve = acc.curve()
    assert np.count_nonzero(octave_points(curve, 0).taus >= 8 * 40 / RATE_HZ) < 3    # the case this test is about
    p = read_axis(curve, 0, SIGMA, RATE_HZ, correlation_samples=40)
    assert p.white_noise is None and p.gauss_markov_sigma is None
    assert len(p.flags) == 1 and p.flags[0].startswith("recording too short") and "no noise terms read" in p.flags[0]
