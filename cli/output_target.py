"""Whether a command's output may be written under a temporary name and renamed onto its path when complete."""

from __future__ import annotations

import os


def renamed_into_place(path: os.PathLike | str) -> bool:
    """True for a new path or a regular file. A device, FIFO or socket (`--output /dev/null`, a pipe's name) is
    written through instead: os.replace would put a regular file in its place — as root, /dev/null itself, after
    which every program that opens /dev/null (tmux, daemons, shells) reads a file."""
    return not os.path.exists(path) or os.path.isfile(path)
