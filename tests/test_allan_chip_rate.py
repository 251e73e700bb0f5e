"""Allan analysis of the project's own simulated ADIS16405 at its real rate (819.2 SPS, through the SPI byte
level and the chip's SENS_AVG Bartlett filter): the white noise of every axis is found within 5 % of the
simulator's configured density, not read as a millisecond Gauss–Markov bump; the samples' correlation length
is read from the data."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.calibration.allan.analysis import analyse_static
from ahrsd.calibration.allan.correlation import SampleCorrelation, shortest_fit_tau_s
from ahrsd.simulation.errors import SensorErrors

SECONDS = 120          # white noise read to ~1.5 % (1σ) per axis: the 5 % bound is over 3σ
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def chip_record():
    """What `ahrsd record --sim static --seconds SECONDS` records (its chip: seed 0, the data sheet's errors,
    free-running, self-tested, read through the one timing path), read here without the CSV file between: the
    recording's round trip is test_recording's, and writing and parsing 98 304 rows cost more than reading the
    chip (the values are the same: the CSV keeps the chip's quantised values exactly)."""
    from pathlib import Path

    from ahrsd.drivers.recording import BASE_COLUMNS, Recording
    from ahrsd.drivers.source import open_chip_bus, start_chip_source

    bus = open_chip_bus("sim", scenario="static", seed=0, errors="adis16405", clock=None)
    source = start_chip_source(bus, "ADIS16405", clock=bus.now, self_test=True)
    rows = []
    try:
        n = int(round(SECONDS * source.driver.sample_rate_hz))
        while len(rows) < n:
            s = source.read_one(source.clock())
            if s is not None:
                rows.append((s.t_s, *s.gyro_rad_s, *s.accel_m_s2, *s.mag_ut))
    finally:
        source.driver.close()
    a = np.array(rows)
    return Recording(Path("<simulated chip>"), BASE_COLUMNS, a[:, 0], a[:, 1:4], a[:, 4:7], a[:, 7:10])


def test_white_noise_at_the_chip_rate_is_the_configured_density(chip_record):
    rec = chip_record
    assert rec.sample_rate_hz == pytest.approx(819.2, rel=1e-3)
    # the terms read only: without the not-seen terms' profile bounds (the terms are the same: the entry
    # allan-terms-without-bounds, tests/test_allan_chip_filters.py), which cost four times the fit here
    res = analyse_static(rec.t_s, rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, not_seen_bounds=False)
    errors = SensorErrors.adis16405(0)      # the densities do not depend on the seed
    configured = {"gyro": errors.gyro_noise_density_rad_s_rthz, "accel": errors.accel_noise_density_m_s2_rthz,
                  "mag": errors.mag_noise_density_ut_rthz}
    for sensor, axes in res.parameters.items():
        print(f"{sensor} white noise vs configured: " + ", ".join(
            f"{axis} {(p.white_noise / configured[sensor] - 1) * 100:+.1f} %" for axis, p in axes.items()
            if p.white_noise is not None))
        for axis, p in axes.items():
            assert p.white_noise is not None, (sensor, axis, p.flags)
            assert p.white_noise == pytest.approx(configured[sensor], rel=0.05), (sensor, axis)
            assert p.gauss_markov_sigma is None, (sensor, axis, p.gauss_markov_tau_s)
            assert any("correlated over" in f for f in p.flags)


def test_the_correlation_length_comes_from_the_data():
    rng = np.random.default_rng(3)
    white = rng.normal(size=(20_000, 3))
    c = SampleCorrelation()
    c.add(white)
    assert list(c.lengths()) == [1, 1, 1]
    assert shortest_fit_tau_s(1, 819.2) == 0.0          # independent samples: every τ is fitted
    # the chip's default SENS_AVG: two 4-tap averages (a 7-tap Bartlett window)
    box = np.ones(4) / 4
    kernel = np.convolve(box, box)
    filtered = np.column_stack([np.convolve(white[:, k], kernel, mode="valid") for k in range(3)])
    c = SampleCorrelation()
    for start in range(0, len(filtered), 1000):          # streamed in chunks, as a recording is read
        c.add(filtered[start:start + 1000])
    lengths = c.lengths()
    # autocorrelation of the 7-tap triangle: lag 4 = 10/44 ≈ 0.23, lag 5 = 4/44 ≈ 0.09 < 0.1, within the
    # estimate's scatter (√((1 + 2Σρ²)/n) ≈ 0.015) of the threshold
    assert np.all(np.abs(lengths - 5) <= 1), lengths
    # the fit starts at 2 correlation lengths: beyond the window's span (7 taps, 1.4 lengths) filtered white noise
    # is N²·(1/τ − D/τ²) exactly (calibration/allan/correlation.py), so nothing nearer the filter is left out
    assert shortest_fit_tau_s(5, 819.2) == pytest.approx(2 * 5 / 819.2)


def test_a_slow_process_is_not_taken_for_a_filter():
    rng = np.random.default_rng(4)
    walk = np.cumsum(rng.normal(size=(20_000, 3)), axis=0) + 0.1 * rng.normal(size=(20_000, 3))
    c = SampleCorrelation()
    c.add(walk)
    assert list(c.lengths()) == [1, 1, 1]      # correlated far beyond any filter: the fit models it, every τ kept


def test_the_allan_report_leads_with_the_data_sheet_figures(tmp_path, capsys):
    import math

    from ahrsd.cli import main as cli
    from ahrsd.drivers.recording import RECORDING_HEADER

    rng = np.random.default_rng(9)
    rate, n = 100.0, 60_000
    arw_deg_rt_h = 2.0
    density = math.radians(arw_deg_rt_h) / 60.0                  # rad/s/√Hz
    t = np.arange(n) / rate
    gyro = rng.normal(0.0, density * math.sqrt(rate), (n, 3))
    table = np.column_stack([t, gyro, rng.normal(0, 0.03, (n, 3)) + [0, 0, -9.81], rng.normal(0, 0.05, (n, 3)) + 30])
    rec = tmp_path / "white.csv"
    np.savetxt(rec, table, delimiter=",", fmt="%.9g", header=RECORDING_HEADER, comments="")
    assert cli.main(["calibrate", "allan", str(rec), "--dry-run", "--state-dir", str(tmp_path / "s")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"Allan analysis of {rec}") and lines[0].endswith("not saved (--dry-run)")
    assert lines[1].startswith("  gyro  ARW (°/√h): x ")
    values = [float(part.split()[1]) for part in lines[1].split(":", 1)[1].split(";")[0].split("  ") if part.strip()]
    assert values == pytest.approx([arw_deg_rt_h] * 3, rel=0.06)
    assert lines.index("  details:") <= 6
