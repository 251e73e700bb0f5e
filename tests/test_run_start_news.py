"""`ahrsd run` with the aided estimator says nothing before "ahrsd started" that the warm-up's throwaway estimator
said about its made-up fix: the daemon's own warm-up logged "ins: velocity and position set from the GNSS fix at
t=0.000 s" on every start (#30 item 13), a claim about no real fix."""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import time

from ahrsd.daemon.estimator_news import estimator_news_muted
from ahrsd.estimator.warm_up import warm_up


def test_the_warm_up_of_ins_says_nothing_below_warning(caplog):
    with caplog.at_level(logging.INFO):
        warm_up("ins")                                  # what the estimator says unmuted: the made-up fix
    assert any("GNSS fix at t=0.000 s" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.INFO), estimator_news_muted():
        warm_up("ins")
    assert [r.getMessage() for r in caplog.records if r.levelno < logging.WARNING] == []
    assert logging.getLogger("ahrsd.estimator").level == logging.NOTSET     # restored after the block


def test_run_with_ins_logs_no_made_up_fix(tmp_path):
    cmd = [sys.executable, "-m", "ahrsd.cli", "run", "--sim", "boat", "--gnss-sim", "--estimator", "ins",
           "--status-line", "off", "--state-dir", str(tmp_path), "--mavlink", "udpout:127.0.0.1:9"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    before_start = []
    try:
        deadline = time.monotonic() + 600
        for line in proc.stdout:
            before_start.append(line)
            if "ahrsd started" in line or time.monotonic() > deadline:
                break
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
    text = "".join(before_start)
    assert "ahrsd started" in text, text
    assert "GNSS fix at t=0.000 s" not in text, text
