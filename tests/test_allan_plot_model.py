"""The Allan plot draws the fitted model only over the τ it was fitted on: on the simulated chip's correlated
samples the dashed "model" dived to 1e-5 below τ ≈ 5 ms (the white term N²(1/τ − D/τ²) turns negative there), a
curve no data supports."""

from __future__ import annotations

import numpy as np
import pytest

from ahrsd.calibration.allan.analysis import analyse_static
from ahrsd.cli.plots.allan import plot_allan

pytest.importorskip("matplotlib")

RATE_HZ = 819.2
TAPS = 5                                    # a 5-sample moving average, like the chip's Bartlett window


def _correlated_white(n: int, density: float, rng) -> np.ndarray:
    raw = rng.standard_normal((n + TAPS - 1, 3)) * density * np.sqrt(RATE_HZ) * np.sqrt(TAPS)
    kernel = np.ones(TAPS) / TAPS
    return np.column_stack([np.convolve(raw[:, k], kernel, mode="valid") for k in range(3)])


def test_model_line_stays_on_the_fitted_taus(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    n = int(120 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    result = analyse_static(t, gyro_rad_s=_correlated_white(n, 5.8e-4, rng),
                            accel_m_s2=_correlated_white(n, 3.3e-3, rng) + [0.0, 0.0, -9.81],
                            mag_ut=_correlated_white(n, 4.4e-3, rng) + [20.0, 0.0, 40.0])
    from matplotlib.figure import Figure

    from ahrsd.core.plotting import pyplot

    plt = pyplot()
    figures = []
    monkeypatch.setattr(plt, "close", lambda fig: figures.append(fig))
    # the lines drawn are read, not the picture: matplotlib's layout and rendering (most of this test's CPU) left
    # out; test_cal_cli and test_cal_allan_cli render the figure and read its PNG
    monkeypatch.setattr(Figure, "tight_layout", lambda self, *args, **kwargs: None)
    monkeypatch.setattr(Figure, "savefig", lambda self, *args, **kwargs: None)
    plot_allan(result, tmp_path / "allan.png")
    axes = [ax for ax in figures[0].axes if ax.get_title()]
    assert len(axes) == 9
    for ax in axes:
        model = [line for line in ax.get_lines() if str(line.get_label()).startswith("model")]
        adev = [line for line in ax.get_lines() if line.get_label() == "Allan deviation"][0]
        assert len(model) == 1
        x, y = np.asarray(model[0].get_xdata()), np.asarray(model[0].get_ydata())
        # not down into the correlated samples' τ: the fit starts at 2 of the window's correlation lengths (5
        # samples), beyond its span; the dive was below τ = D ≈ 3 ms, where N²(1/τ − D/τ²) turns negative
        assert x.min() >= 2 * TAPS / RATE_HZ
        assert np.all(np.isfinite(y)) and np.all(y > 0)
        # and where it is drawn and the data are dense (τ ≤ 10 s of a 120 s record) it follows them, which the
        # dive did not (1e-5 against 2e-3 at τ = 3 ms)
        ax_tau, ax_dev = np.asarray(adev.get_xdata()), np.asarray(adev.get_ydata())
        dense = x <= 10.0
        ratio = y[dense] / np.interp(x[dense], ax_tau, ax_dev)
        assert np.all((ratio > 0.7) & (ratio < 1.4)), ax.get_title()
