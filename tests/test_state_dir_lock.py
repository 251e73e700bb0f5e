"""One daemon per state directory (daemon.state_lock): a second `ahrsd run` on the directory of a running one is
refused in one line naming the directory, the other's PID and the fix; the first keeps running; after the first is
killed with SIGKILL a new one starts (no stale lock); a daemon on another directory starts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ahrsd.daemon.state_lock import LOCK_FILE_NAME, StateDirBusy, StateDirLock
from service_rig import stop_process

START_TIMEOUT_S = 120.0     # an import under load 10 on 2 cores; the lock is taken before the estimator's compile


def test_the_lock_refuses_a_second_holder_and_is_free_after_release(tmp_path):
    """flock locks an open file, not a process: a second open in this very process is refused too."""
    first = StateDirLock.acquire(tmp_path / "st")
    assert (tmp_path / "st" / LOCK_FILE_NAME).read_text() == f"{os.getpid()}\n"
    with pytest.raises(StateDirBusy) as refused:
        StateDirLock.acquire(tmp_path / "st")
    assert refused.value.pid == os.getpid() and refused.value.directory == tmp_path / "st"
    first.release()
    assert (tmp_path / "st" / LOCK_FILE_NAME).read_text() == ""      # no PID left naming a process gone
    StateDirLock.acquire(tmp_path / "st").release()


def _run(state_dir, **popen):
    return subprocess.Popen([sys.executable, "-m", "ahrsd.cli", "run", "--sim", "static", "--state-dir", str(state_dir),
                             "--no-log", "--status-line", "off", "--mavlink", "udpout:127.0.0.1:9"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **popen)


def _wait_for_lock(proc, state_dir) -> None:
    """Until `proc` has written its PID into the lock file (it holds the lock), failing if it exits first."""
    path = state_dir / LOCK_FILE_NAME
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"exited {proc.returncode}: {proc.stderr.read()}"
        if path.exists() and path.read_text().strip() == str(proc.pid):
            return
        time.sleep(0.1)
    raise AssertionError(f"no lock taken by PID {proc.pid} within {START_TIMEOUT_S} s")


def _stop(proc) -> None:
    stop_process(proc, timeout_s=30.0)
    proc.stderr.close()


def test_a_second_daemon_on_one_directory_is_refused_and_one_on_another_starts(tmp_path):
    """Seen failing with the flock call dropped (acquire takes no lock): the second daemon ran (no exit in 60 s)."""
    shared = tmp_path / "st"
    first = _run(shared)
    procs = [first]
    try:
        _wait_for_lock(first, shared)
        second = subprocess.run([sys.executable, "-m", "ahrsd.cli", "run", "--sim", "static", "--state-dir",
                                 str(shared), "--no-log", "--status-line", "off", "--mavlink", "udpout:127.0.0.1:9"],
                                capture_output=True, text=True, timeout=60)
        assert second.returncode == 1
        assert second.stderr.strip().splitlines() == [
            f"ahrsd run: error: the state directory {shared} is in use by another ahrsd (PID {first.pid}): two "
            "daemons on one directory would overwrite each other's calibration, learned iron, position memory and "
            "logs. Stop the other one (under systemd: systemctl stop ahrsd), or give this one its own directory "
            "with --state-dir DIR"]
        assert first.poll() is None                                     # the first keeps running
        assert (shared / LOCK_FILE_NAME).read_text() == f"{first.pid}\n"   # and its PID is still the one named
        other = _run(tmp_path / "other")
        procs.append(other)
        _wait_for_lock(other, tmp_path / "other")                       # another directory: starts beside it
    finally:
        for proc in procs:
            _stop(proc)


def test_after_a_sigkill_a_new_daemon_starts_on_the_directory(tmp_path):
    """The kernel drops a flock with its process: no stale lock after a SIGKILL (a PID file would be left)."""
    shared = tmp_path / "st"
    first = _run(shared)
    try:
        _wait_for_lock(first, shared)
        first.send_signal(signal.SIGKILL)
        assert first.wait(30) == -signal.SIGKILL
    finally:
        _stop(first)
    assert (shared / LOCK_FILE_NAME).read_text() == f"{first.pid}\n"    # the dead one's PID is left in the file
    again = _run(shared)
    try:
        _wait_for_lock(again, shared)
    finally:
        _stop(again)
