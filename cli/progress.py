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
    """A bar on this run: stderr is a terminal, and no --json/--quiet (args None: no bar)."""
    if args is None or getattr(args, "json", False) or getattr(args, "quiet", False):
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

    return _EstimatedTotalBar(tqdm(total=total, desc=desc, unit=unit, unit_scale=unit_scale, file=sys.stderr,
                                   dynamic_ncols=True, mininterval=0.2, leave=True))


class _EstimatedTotalBar:
    """A tqdm bar whose total is an estimate (a file's size over its rows' length): grown when passed, so the
    bar keeps its time left, and set to what was done at the end, so it closes at 100 %."""

    def __init__(self, bar):
        self._bar = bar

    def update(self, n: int = 1) -> None:
        bar = self._bar
        if bar.total is not None and bar.n + n > bar.total:
            bar.total = int((bar.n + n) * 1.02) + 1
        bar.update(n)

    def close(self) -> None:
        bar = self._bar
        if bar.total is not None and bar.n != bar.total:
            bar.total = bar.n
            bar.refresh()
        bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def expected_rows(path: str) -> int | None:
    """About how many rows a CSV recording holds (for the bar's time left): its size over the mean length of
    its first rows; None when that cannot be told cheaply (compressed, unreadable)."""
    import os

    if str(path).endswith(".gz"):
        return None
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(1 << 16).split(b"\n")[1:-1]
    except OSError:
        return None
    rows = [r for r in head if r and not r.startswith(b"#")]
    return int(size / (sum(len(r) + 1 for r in rows) / len(rows))) if rows else None
