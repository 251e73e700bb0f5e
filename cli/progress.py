"""Progress bars for long offline work (`replay`, `calibrate allan|mag`, `log cut`): tqdm on stderr with the
rate and the time left, only when stderr is a terminal and the command was not asked for --json or --quiet
(a pipe, a log file or a script gets no bar and no control characters)."""

from __future__ import annotations

import sys


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def wanted(args) -> bool:
    """A bar on this run: stderr is a terminal, and no --json/--quiet."""
    if getattr(args, "json", False) or getattr(args, "quiet", False):
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress_bar(args, total: float | None, desc: str, unit: str = "sample", unit_scale: bool = True):
    """A tqdm bar (or a silent stand-in when not `wanted`): `.update(n)`, `.close()`, a context manager."""
    if not wanted(args):
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, unit_scale=unit_scale, file=sys.stderr, dynamic_ncols=True,
                mininterval=0.2, leave=False)
