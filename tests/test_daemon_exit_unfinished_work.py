"""The fast exit after a stopped daemon (cli/main.py console_main: os._exit past the interpreter's teardown) is
taken only with nothing else left running: a thread still at work when the daemon has stopped (here one a plug-in
or an embedding script started) must finish, as it would at a normal exit, which waits for non-daemon threads
(Python's threading docs: "the entire Python program exits when no alive non-daemon threads are left").

The thread waits for the daemon's stop (its stats file, written while stopping), then works WORK_S longer and
writes a file; the file must be there when the process has ended. Truth: what a normal interpreter exit does,
not the code under test."""

from __future__ import annotations

import subprocess
import sys

from ahrsd.cli.main import ENDING_WAIT_S
from ahrsd.drivers.recording import RECORDING_HEADER

ROW = "{t:.6f},0.001,-0.002,0.0005,0.05,-0.03,-9.80665,20.0,1.5,45.0\n"
RATE_HZ = 819.2
# longer than the daemon takes from writing its stats to returning from main(), plus the exit's wait for what is
# ending (cli/main.py): the thread is still at work when that wait is over
WORK_S = 3.0 + ENDING_WAIT_S

CONSOLE = """
import os, sys, threading, time
stats, done = sys.argv[1], sys.argv[2]
def work():
    while not os.path.exists(stats):
        time.sleep(0.05)
    time.sleep({work_s})
    with open(done, "w") as f:
        f.write("finished")
threading.Thread(target=work).start()
sys.argv = ["ahrsd"] + sys.argv[3:]
from ahrsd.cli.main import console_main
console_main()
"""


def test_a_thread_still_at_work_when_the_daemon_stops_finishes_before_the_process_ends(tmp_path):
    recording = tmp_path / "rec.csv"
    recording.write_text(RECORDING_HEADER + "\n" + "".join(ROW.format(t=k / RATE_HZ) for k in range(2000)))
    stats, done = tmp_path / "stats.json", tmp_path / "done.txt"
    r = subprocess.run(
        [sys.executable, "-c", CONSOLE.format(work_s=WORK_S), stats, done,
         "run", "--replay", recording, "--replay-speed", "50", "--status-line", "off",
         "--state-dir", tmp_path / "state", "--log-dir", tmp_path / "logs", "--mavlink", "udpout:127.0.0.1:9",
         "--stats-file", stats],
        capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert stats.exists()
    assert done.exists() and done.read_text() == "finished", "the process ended with the thread's work unfinished"


ENDING = """
import multiprocessing, sys, threading, time
from ahrsd.cli.main import ENDING_WAIT_S, _nothing_left_running
fork = multiprocessing.get_context("fork")
fork.Process(target=time.sleep, args=(0.5,)).start()
threading.Thread(target=time.sleep, args=(0.5,)).start()
ended = _nothing_left_running(ENDING_WAIT_S)
working = fork.Process(target=time.sleep, args=(60.0,))
working.start()
left = _nothing_left_running(0.2)
working.kill()
working.join()
print(ended, left)
"""


def test_a_process_and_a_thread_that_end_within_the_exits_wait_are_not_work_left():
    """What the daemon's stop told to end without waiting (the field calibration's fit worker, daemon/magcal.py:
    its process and its pool's manager thread) is waited for, so that the fast exit is still taken; a process
    still alive after the wait is work left. In a process of its own: pytest's may have threads of its own."""
    r = subprocess.run([sys.executable, "-c", ENDING], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["True", "False"], r.stdout
