"""What a `--plot` drew, for tests: the matplotlib figures saved while a command runs, so a test reads the
panels' titles and the data of their lines (checked against truth it computes itself), not only that a PNG
file exists."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np


@contextmanager
def saved_figures(monkeypatch):
    """Yield a list that collects every Figure saved (savefig still writes the file)."""
    from matplotlib.figure import Figure

    saved = []
    original = Figure.savefig

    def savefig(self, *args, **kwargs):
        saved.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    yield saved


def line(ax, label: str) -> np.ndarray:
    """(n, 2) x/y data of the line labelled `label` in `ax` (exactly one)."""
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert len(found) == 1, (label, [ln.get_label() for ln in ax.get_lines()])
    return np.column_stack([np.asarray(found[0].get_xdata(), float), np.asarray(found[0].get_ydata(), float)])


def overlapping_adev(x: np.ndarray, rate_hz: float, m: int) -> float:
    """Overlapping Allan deviation of rate samples x at τ = m/rate (IEEE Std 952 / Riley's handbook, eq. 11)."""
    tau = m / rate_hz
    theta = np.concatenate(([0.0], np.cumsum(x) / rate_hz))
    d = theta[2 * m:] - 2 * theta[m:-m] + theta[: -2 * m]
    return float(np.sqrt(np.sum(d * d) / (2 * tau * tau * d.size)))
