"""`ahrsd calibrate gyro --plot FILE.png` draws the fit it made and says where the figure is: the bias line at
the injected bias, the still periods it came from shaded (not the part where the unit was handled), and for a
rate table the residual of each steady segment."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from ahrsd.cli.plots import gyro as gyro_plot  # noqa: E402
from ahrsd.cli import main as cli  # noqa: E402
from ahrsd.drivers.recording import RECORDING_HEADER  # noqa: E402
from support.kept_figures import kept_figures  # noqa: E402

RATE_HZ = 100.0
BIAS_RAD_S = np.array([0.004, -0.003, 0.0015])
NOISE_RAD_S = 0.01
HANDLED = (10.0, 16.0)      # s: the unit picked up and turned: not still, and no bias


@pytest.fixture
def figures(monkeypatch):
    """The figures the command saves (kept open for the test to read)."""
    with kept_figures(monkeypatch, gyro_plot, "save", lambda fig, path: (fig, path)) as kept:
        yield kept


def still_with_handling(path, seconds=40.0, seed=3):
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    gyro = BIAS_RAD_S + rng.normal(0.0, NOISE_RAD_S, (len(t), 3))
    accel = np.tile([0.0, 0.0, -9.80665], (len(t), 1)) + rng.normal(0.0, 0.02, (len(t), 3))
    handled = (t >= HANDLED[0]) & (t < HANDLED[1])
    gyro[handled] += [0.3, -0.2, 0.5]                     # turning: far from the bias
    phase = 2 * math.pi * 0.7 * t[handled]
    accel[handled] += np.column_stack([3 * np.sin(phase), 2 * np.cos(phase), np.zeros(handled.sum())])
    mag = np.tile([20.0, 1.0, 45.0], (len(t), 1))
    np.savetxt(path, np.column_stack([t, gyro, accel, mag]), delimiter=",", fmt="%.8g", header=RECORDING_HEADER,
               comments="")
    return t


def test_bias_only_plot_draws_the_fitted_bias_and_the_still_periods(tmp_path, figures, capsys):
    rec, png = tmp_path / "still.csv", tmp_path / "gyro.png"
    t = still_with_handling(rec)
    code = cli.main(["calibrate", "gyro", "--bias-only", str(rec), "--plot", str(png), "--dry-run",
                     "--state-dir", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert png.stat().st_size > 0 and f"figure written to {png}" in err
    (fig,) = figures
    axes = fig.axes
    assert len(axes) == 3
    n_still = len(t) - (HANDLED[1] - HANDLED[0]) * RATE_HZ
    sigma_deg = math.degrees(NOISE_RAD_S / math.sqrt(n_still * 0.5))    # generous: trimmed still periods
    for k, ax in enumerate(axes):
        bias_lines = [ln for ln in ax.get_lines() if ln.get_label().startswith("bias")]
        assert len(bias_lines) == 1, [ln.get_label() for ln in ax.get_lines()]
        drawn_deg = float(np.mean(bias_lines[0].get_ydata()))
        assert abs(drawn_deg - math.degrees(BIAS_RAD_S[k])) < 4 * sigma_deg
        # its label in the axis's own unit first (walk29: "bias -808.9 °/h" over an axis in °/s)
        assert bias_lines[0].get_label().startswith(f"bias {drawn_deg:+.3f} °/s ("), bias_lines[0].get_label()
        # the shaded still periods: never over the handled interval, and most of the rest of the recording
        spans = [x_extent(p) for p in ax.patches if p.get_gid() == "still"]
        assert spans
        assert all(b <= HANDLED[0] or a >= HANDLED[1] for a, b in spans), spans
        assert sum(b - a for a, b in spans) > 0.6 * (t[-1] - (HANDLED[1] - HANDLED[0]))


def x_extent(patch) -> tuple[float, float]:
    if hasattr(patch, "get_x"):                      # a Rectangle (matplotlib ≥ 3.9)
        return patch.get_x(), patch.get_x() + patch.get_width()
    xy = np.asarray(patch.get_xy())                  # a Polygon (earlier)
    return float(xy[:, 0].min()), float(xy[:, 0].max())


def test_a_refused_bias_fit_still_draws_the_rates_without_a_bias(tmp_path, figures, capsys):
    rec, png = tmp_path / "turning.csv", tmp_path / "gyro.png"
    t = np.arange(2000) / RATE_HZ
    table = np.column_stack([t, np.full(len(t), 0.2), np.zeros((len(t), 2)), np.tile([0, 0, -9.81], (len(t), 1)),
                             np.tile([20.0, 1.0, 45.0], (len(t), 1))])
    np.savetxt(rec, table, delimiter=",", fmt="%.8g", header=RECORDING_HEADER, comments="")
    code = cli.main(["calibrate", "gyro", "--bias-only", str(rec), "--plot", str(png), "--dry-run",
                     "--state-dir", str(tmp_path / "s")])
    assert code == 1 and png.exists()
    (fig,) = figures
    assert "REFUSED" in fig.texts[0].get_text()
    for ax in fig.axes:
        assert not [ln for ln in ax.get_lines() if ln.get_label().startswith("bias")]
        raw = [ln for ln in ax.get_lines() if ln.get_label() == "raw rate"]
        assert len(raw) == 1
    assert np.allclose(fig.axes[0].get_lines()[0].get_ydata(), math.degrees(0.2))


def test_rate_table_panel_shows_each_segments_residual():
    reference = np.radians([[0.0, 0.0, 0.0], [0.0, 0.0, 90.0], [0.0, 0.0, -90.0], [90.0, 0.0, 0.0]])
    measured = reference + np.radians([[0.01, -0.02, 0.0], [0.0, 0.0, 0.3], [0.0, 0.0, -0.1], [0.05, 0.0, 0.0]])
    fig = gyro_plot.rate_table_figure(reference, measured, "t", "raw")
    try:
        top, bottom = fig.axes
        z = [ln for ln in bottom.get_lines() if ln.get_label() == "z"][0]
        assert np.allclose(z.get_ydata(), [0.0, 0.3, -0.1, 0.0])
        assert bottom.get_ylabel().startswith("raw − reference")
        x_ref = [ln for ln in top.get_lines() if ln.get_label() == "x reference"][0]
        assert np.allclose(x_ref.get_ydata(), [0, 0, 0, 90])
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def points_under_legend(fig) -> list[tuple[str, float, float]]:
    """The plotted points (lines' data, in display coordinates after drawing) that fall inside a legend's box."""
    fig.canvas.draw()
    hidden = []
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box = legend.get_window_extent()
        for ln in ax.get_lines():
            xy = ax.transData.transform(np.column_stack([ln.get_xdata(), ln.get_ydata()]).astype(float))
            inside = ((xy[:, 0] >= box.x0) & (xy[:, 0] <= box.x1) & (xy[:, 1] >= box.y0) & (xy[:, 1] <= box.y1))
            hidden += [(ln.get_label(), *p) for p in xy[inside]]
    return hidden


def test_the_rate_table_legend_hides_no_segment():
    """Session 23's walk: on the six-axis table of `ahrsd record --sim rate-table` the legend ("best") covered
    the y axis's +90 °/s segments 24 and 27. The segments here: each axis ±90 °/s, holds between, 30 of them."""
    rates = [0.0, 90.0, 0.0, -90.0, 0.0]
    reference = np.radians([[r if k == axis else 0.0 for k in range(3)] for axis in (2, 2, 0, 0, 1, 1) for r in rates])
    measured = reference + np.radians(0.02) * np.sin(np.arange(reference.size)).reshape(reference.shape)
    fig = gyro_plot.rate_table_figure(reference, measured, "t")
    try:
        assert points_under_legend(fig) == []
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_the_bias_figure_legend_hides_no_sample():
    """The bias-only figure's legends sat over the rates they label ("upper right" inside each panel)."""
    t = np.arange(0.0, 20.0, 0.01)
    gyro = np.radians(0.2) * np.column_stack([np.sin(t * k) for k in (1.0, 2.0, 3.0)])
    fig = gyro_plot.bias_figure(t, gyro, [(0, 500)], np.zeros(3), np.full(3, 1e-3), "t")
    try:
        assert points_under_legend(fig) == []
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
