"""`ahrsd calibrate gyro --plot FILE.png` draws the fit it made and says where the figure is: the bias line at
the injected bias, the still periods it came from shaded (not the part where the unit was handled), and for a
rate table the residual of each steady segment."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from ahrsd.cli import gyro_plot  # noqa: E402
from ahrsd.cli import main as cli  # noqa: E402
from ahrsd.drivers.recording import RECORDING_HEADER  # noqa: E402

RATE_HZ = 100.0
BIAS_RAD_S = np.array([0.004, -0.003, 0.0015])
NOISE_RAD_S = 0.01
HANDLED = (10.0, 16.0)      # s: the unit picked up and turned: not still, and no bias


@pytest.fixture
def figures(monkeypatch):
    """The figures the command saves (kept open for the test to read)."""
    kept = []
    real_save = gyro_plot.save

    def keep(fig, path):
        kept.append(fig)
        fig.savefig(path, dpi=50)

    monkeypatch.setattr(gyro_plot, "save", keep)
    yield kept
    import matplotlib.pyplot as plt

    for fig in kept:
        plt.close(fig)
    assert real_save is not None


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
