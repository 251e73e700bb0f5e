"""A record too short for the Allan fit gets a reason, not a crash or a wrong reading (calibration/allan/analysis.py
read_axis, calibration/allan/terms.py select_terms, calibration/allan/correlation.py samples_to_tell)."""

import numpy as np
import pytest

from ahrsd.calibration.allan.analysis import analyse_static, read_axis, summary
from ahrsd.calibration.allan.adev import StreamingAllan
from ahrsd.calibration.allan.correlation import SampleCorrelation
from ahrsd.calibration.allan.terms import octave_points

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
    # 1.2 s of samples correlated over 40 samples: only τ ≥ 2·40/819.2 = 0.098 s (the fit's start, 2 correlation
    # lengths) can be fitted, and a 1.2 s record has two cluster sizes there. A fit over the bent short τ would read
    # the filter as a Gauss–Markov term.
    n = 1000
    acc = StreamingAllan(RATE_HZ, n_axes=3)
    acc.add(_bartlett_filtered(n, 40, seed=3))
    curve = acc.curve()
    assert np.count_nonzero(octave_points(curve, 0).taus >= 2 * 40 / RATE_HZ) < 3    # the case this test is about
    p = read_axis(curve, 0, SIGMA, RATE_HZ, correlation_samples=40)
    assert p.white_noise is None and p.gauss_markov_sigma is None
    assert len(p.flags) == 1 and p.flags[0].startswith("recording too short") and "no noise terms read" in p.flags[0]


def _bartlett_length(length: int) -> int:
    """The window's own correlation length: the first lag where its autocorrelation is below 0.1."""
    w = np.bartlett(length + 2)[1:-1]
    acf = np.correlate(w, w, "full")[length - 1:]
    return int(np.flatnonzero(acf / acf[0] < 0.1)[0])


def test_a_record_too_short_to_tell_the_filter_length_reads_no_term_and_the_advised_length_reads_white_noise():
    # 2000 samples through a 40-tap window: 50 of its spans, too few to read its correlation length (the
    # analysis wants 400). A fit over every τ read the window as a Gauss–Markov term and said white noise was
    # "not seen … whatever the recording length".
    n = 2000
    result = analyse_static(np.arange(n) / RATE_HZ, gyro_rad_s=_bartlett_filtered(n, 40, seed=1))
    needs = []
    for axis, p in result.parameters["gyro"].items():
        assert p.white_noise is None and p.gauss_markov_sigma is None and not p.terms, (axis, p.flags)
        assert len(p.flags) == 1 and p.flags[0].startswith("recording too short"), (axis, p.flags)
        assert "no noise terms read" in p.flags[0]
        needs.append(p.too_short_need_s)
    assert min(needs) * RATE_HZ > n
    lead = summary(result)
    assert "x too short  y too short  z too short" in lead[0] and "not seen" not in lead[0]
    assert lead[1] == f"  recording too short for 3 axes: record ≥ {max(needs):.0f} s of the sensor at rest (details below)"
    # the length it advises reads the white noise the samples have, within its 1σ's scatter, on every axis
    longer = int(max(needs) * RATE_HZ)
    result = analyse_static(np.arange(longer) / RATE_HZ, gyro_rad_s=_bartlett_filtered(longer, 40, seed=2))
    for axis, p in result.parameters["gyro"].items():
        assert set(p.terms) == {"white"}, (axis, p.flags)
        assert abs(p.white_noise - DENSITY) < 4 * p.terms["white"].uncertainty, (axis, p.flags)
        assert p.terms["white"].uncertainty < 0.1 * DENSITY, axis


def test_the_samples_it_asks_for_tell_the_filter_length():
    true_length = _bartlett_length(40)
    asked = []
    for seed in range(8):
        c = SampleCorrelation()
        c.add(_bartlett_filtered(2000, 40, seed=100 + seed))
        asked.append(int(np.max(c.samples_to_tell())))
    assert min(asked) > 2000
    for seed in range(8):
        c = SampleCorrelation()
        c.add(_bartlett_filtered(max(asked), 40, seed=200 + seed))
        assert list(c.samples_to_tell()) == [0, 0, 0], seed
        assert np.all(np.abs(c.lengths() / true_length - 1) <= 0.2), (seed, c.lengths(), true_length)


def test_short_independent_samples_and_a_short_slow_process_are_not_called_too_short():
    rng = np.random.default_rng(7)
    n = 1500
    white = rng.normal(0.0, SIGMA, (n, 3))
    result = analyse_static(np.arange(n) / RATE_HZ, gyro_rad_s=white)
    for axis, p in result.parameters["gyro"].items():
        assert p.white_noise == pytest.approx(DENSITY, rel=0.2), (axis, p.flags)
    # a random walk is correlated far beyond any filter: the term fit models it from every τ, whatever the length
    walk = np.cumsum(rng.normal(size=(n, 3)), axis=0) + 0.1 * rng.normal(size=(n, 3))
    c = SampleCorrelation()
    c.add(walk)
    assert list(c.samples_to_tell()) == [0, 0, 0] and list(c.lengths()) == [1, 1, 1]


def test_the_command_gives_a_short_record_in_seconds_and_leads_with_how_long_to_record(tmp_path, capsys):
    from ahrsd.cli.main import main
    from ahrsd.drivers.recording import RECORDING_HEADER

    n = 2000
    rng = np.random.default_rng(5)
    table = np.column_stack([np.arange(n) / RATE_HZ, _bartlett_filtered(n, 40, seed=4),
                             rng.normal(0, 0.03, (n, 3)) + [0, 0, -9.81], rng.normal(0, 0.05, (n, 3)) + 30])
    rec = tmp_path / "short.csv"
    np.savetxt(rec, table, delimiter=",", fmt="%.9g", header=RECORDING_HEADER, comments="")
    assert main(["calibrate", "allan", str(rec), "--dry-run", "--state-dir", str(tmp_path / "s")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"Allan analysis of {rec}: {n / RATE_HZ:.1f} s at {RATE_HZ:.1f} Hz; noise parameters not saved (--dry-run)"
    assert lines[1].startswith("  gyro  ARW (°/√h): x too short  y too short  z too short;"), lines[1]
    assert any(line.startswith("  recording too short for ") for line in lines[:6]), lines[:6]
