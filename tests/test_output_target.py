"""An output that is a device or a FIFO is written through, never replaced by a renamed temporary file: `ahrsd
replay … --output /dev/null` run as root replaced /dev/null with a regular file (seen on the development machine
this session: tmux then failed with "server exited unexpectedly"). A FIFO stands in for the device (no root needed)."""

from __future__ import annotations

import os
import stat
import threading

from ahrsd.cli.main import main
from ahrsd.cli.output_target import renamed_into_place


def _drain(path, into: list) -> threading.Thread:
    def read():
        with open(path, "rb") as f:
            into.append(f.read())
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return reader


def test_a_replay_into_a_fifo_leaves_the_fifo_and_delivers_every_row(tmp_path):
    recording = tmp_path / "static.csv"
    assert main(["record", "--sim", "static", "--seconds", "1", "--rate-hz", "204.8", "--output", str(recording),
                 "--quiet"]) == 0
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    received: list = []
    reader = _drain(fifo, received)
    assert main(["replay", str(recording), "--output", str(fifo), "--quiet"]) == 0
    reader.join(30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode), "the FIFO was replaced by a regular file"
    rows = [line for line in received[0].decode().splitlines() if line and not line.startswith("#")]
    n_samples = sum(1 for line in recording.read_text().splitlines() if line and line[0].isdigit())
    assert len(rows) == n_samples + 1          # the header and one row a sample
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


def test_only_new_paths_and_regular_files_are_renamed_into_place(tmp_path):
    regular = tmp_path / "a.csv"
    regular.write_text("x")
    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    assert renamed_into_place(tmp_path / "new.csv") and renamed_into_place(regular)
    assert not renamed_into_place(fifo) and not renamed_into_place(os.devnull)
