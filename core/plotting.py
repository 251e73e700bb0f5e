"""The one lazy matplotlib import every figure uses (`ahrsd calibrate|replay ... --plot FILE.png`): matplotlib is
the optional `ahrsd[plot]` extra, imported only when a plot is drawn, on the file-only Agg backend."""

from __future__ import annotations

PLOT_INSTALL_HINT = "pip install 'ahrsd[plot]'"


class PlotUnavailableError(ImportError):
    """A plot was asked for but matplotlib (the optional `ahrsd[plot]` extra) is not installed."""


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend; PlotUnavailableError when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotUnavailableError(f"plotting needs matplotlib: {PLOT_INSTALL_HINT} ({exc})") from None
    return plt
