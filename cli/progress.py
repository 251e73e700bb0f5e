"""Progress bars for long offline work (`replay`, `calibrate allan|mag`, `log cut`): tqdm on stderr with the
rate and the time left, only when stderr is a terminal and the command was not asked for quiet output (its
--quiet; calibrate's --json, whose stdout a script reads): a pipe, a log file or a script gets no bar and no
control characters. The caller says which of its options means quiet (`quiet`): the commands have different ones.

Two kinds: `progress_bar` counts rows (reading, replaying, cutting: rate and time left); `activity` is for one
step whose progress cannot be counted from outside (a fit, the Allan analysis after the reading): a line that
shows how long it has run, refreshed twice a second, ending in "done"."""

from __future__ import annotations

import sys
import threading


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def wanted(quiet: bool) -> bool:
    """A bar on this run: stderr is a terminal, and the command was not asked for quiet output."""
    if quiet:
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress_bar(quiet: bool, total: float | None, desc: str, unit: str = "sample", unit_scale: bool = True):
    """A tqdm bar (or a silent stand-in when not `wanted`): `.update(n)`, `.close()`, a context manager."""
    if not wanted(quiet):
        return _NoBar()
    from tqdm import tqdm

    return _EstimatedTotalBar(tqdm(total=total, desc=desc, unit=unit, unit_scale=unit_scale, file=sys.stderr,
                                   dynamic_ncols=True, mininterval=0.2, leave=True))


def activity(quiet: bool, desc: str):
    """A context manager showing `desc: <elapsed>` while its block runs (or nothing when not `wanted`)."""
    if not wanted(quiet):
        return _NoBar()
    from tqdm import tqdm

    return _ActivityLine(tqdm(total=None, desc=desc, bar_format="{desc}: {elapsed}{postfix}", file=sys.stderr,
                              dynamic_ncols=True, leave=True))


class _ActivityLine:
    """tqdm redraws only on update(): a thread refreshes the line so the elapsed time moves during the step."""

    REFRESH_S = 0.5

    def __init__(self, bar):
        self._bar = bar
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._refresh, name="progress-activity", daemon=True)
        self._thread.start()

    def _refresh(self) -> None:
        while not self._done.wait(self.REFRESH_S):
            self._bar.refresh()

    def update(self, n: int = 1) -> None:
        pass

    def close(self, ok: bool = True) -> None:
        if self._done.is_set():
            return
        self._done.set()
        self._thread.join()
        self._bar.set_postfix_str("done" if ok else "stopped", refresh=True)
        self._bar.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(ok=exc_type is None)


class _EstimatedTotalBar:
    """A tqdm bar whose total is an estimate (a file's size over its rows' length): grown when passed, so the
    bar keeps its time left, and set to what was done at the end of a finished run, so it closes at 100 %; a run
    stopped part-way (Ctrl-C, an error) keeps the estimate and says "stopped", so it never shows 100 %."""

    def __init__(self, bar):
        self._bar = bar

    def update(self, n: int = 1) -> None:
        bar = self._bar
        if bar.total is not None and bar.n + n > bar.total:
            bar.total = int((bar.n + n) * 1.02) + 1
        bar.update(n)

    def close(self, finished: bool = True) -> None:
        bar = self._bar
        if not finished:
            bar.set_postfix_str("stopped", refresh=True)
        elif bar.total is not None and bar.n != bar.total:
            bar.total = bar.n
            bar.refresh()
        bar.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(finished=exc_type is None)


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
