"""The one lazy matplotlib import every figure uses (`ahrsd calibrate|replay ... --plot FILE.png`): matplotlib is
an optional dependency (the `plot` extra of the source tree), imported only when a plot is drawn, on the file-only
Agg backend."""

from __future__ import annotations

import shlex
import sys

# ahrsd is installed from its source tree, not from a package registry, so `pip install 'ahrsd[plot]'` finds
# nothing: the hint names the interpreter that runs ahrsd (its virtualenv) and the one package the figures need.
PLOT_INSTALL_HINT = f"{shlex.quote(sys.executable)} -m pip install matplotlib"


class PlotUnavailableError(ImportError):
    """A plot was asked for but matplotlib (the optional `plot` extra) is not installed."""


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend; PlotUnavailableError when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotUnavailableError(f"plotting needs matplotlib: {PLOT_INSTALL_HINT} ({exc})") from None
    return plt
