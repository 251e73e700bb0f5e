"""Keep the matplotlib figures a command draws open for the test to read (their panels, lines, titles), while
still writing each to the file the command names."""

from __future__ import annotations

from contextlib import contextmanager


@contextmanager
def kept_figures(monkeypatch, module, attr: str, figure_and_path):
    """Replace `module.attr` (a function that writes a figure) by one that keeps the figure:
    `figure_and_path(*args, **kwargs) -> (figure, path)` says which figure and file a call is about."""
    import matplotlib.pyplot as plt

    kept = []

    def keep(*args, **kwargs):
        fig, path = figure_and_path(*args, **kwargs)
        kept.append(fig)
        fig.savefig(path, dpi=40)

    monkeypatch.setattr(module, attr, keep)
    try:
        yield kept
    finally:
        for fig in kept:
            plt.close(fig)
