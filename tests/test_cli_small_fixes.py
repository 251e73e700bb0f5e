"""Small things a new user met (issue 30 item 13): `ahrsd --version`, the previous-file note, a progress bar
stopped part-way never shows 100 %, the warm-up's throwaway estimator keeps its news out of the log."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from ahrsd.cli import main as cli
from ahrsd.cli import warm_up as cli_warm_up
from ahrsd.cli.progress import _EstimatedTotalBar
from ahrsd.drivers.recording import RECORDING_HEADER


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    from importlib.metadata import version

    assert capsys.readouterr().out.strip() == f"ahrsd {version('ahrsd')}"


def test_the_previous_file_is_named_only_when_there_is_one(tmp_path, capsys):
    rec = tmp_path / "still.csv"
    t = np.arange(2000) / 100.0
    table = np.column_stack([t, np.full((len(t), 3), 1e-3), np.tile([0, 0, -9.81], (len(t), 1)),
                             np.tile([20.0, 1.0, 45.0], (len(t), 1))])
    np.savetxt(rec, table, delimiter=",", fmt="%.6f", header=RECORDING_HEADER, comments="")
    args = ["calibrate", "gyro", "--bias-only", str(rec), "--state-dir", str(tmp_path / "s")]
    assert cli.main(args) == 0
    first = capsys.readouterr().out
    assert "there was no previous file" in first and "calibration.prev.json" not in first
    assert cli.main(args) == 0
    assert "the previous file is kept as calibration.prev.json" in capsys.readouterr().out
    assert (tmp_path / "s" / "calibration.prev.json").exists()


class _FakeTqdm:
    def __init__(self, total):
        self.total, self.n, self.postfix, self.closed = total, 0, "", False

    def update(self, n):
        self.n += n

    def refresh(self):
        pass

    def set_postfix_str(self, text, refresh=True):
        self.postfix = text

    def close(self):
        self.closed = True


def test_a_bar_stopped_part_way_does_not_jump_to_100_percent():
    fake = _FakeTqdm(total=1000)
    with pytest.raises(KeyboardInterrupt):
        with _EstimatedTotalBar(fake) as bar:
            bar.update(300)
            raise KeyboardInterrupt
    assert fake.closed and fake.total == 1000 and fake.n == 300 and fake.postfix == "stopped"
    fake = _FakeTqdm(total=1000)
    with _EstimatedTotalBar(fake) as bar:
        bar.update(980)                    # the estimate was a little high: a finished run closes at 100 %
    assert fake.total == fake.n == 980 and fake.postfix == ""


def test_the_warm_up_estimators_news_stays_out_of_the_log(caplog):
    def chatty(name):
        logging.getLogger("ahrsd.estimator.ins").info("ins: velocity and position set from the GNSS fix at t=0.000 s")
        logging.getLogger("ahrsd.estimator.ins").warning("a real problem")

    caplog.set_level(logging.INFO)
    cli_warm_up.compile_estimator("ins", announce_after_s=600.0, warm_up=chatty)
    assert "a real problem" in caplog.text and "set from the GNSS fix" not in caplog.text
    logging.getLogger("ahrsd.estimator.ins").info("after the warm-up")
    assert "after the warm-up" in caplog.text            # the level is restored


def test_an_endpoint_that_cannot_bind_is_named():
    import asyncio

    from ahrsd.daemon.mavlink_io import Endpoint

    loop = asyncio.new_event_loop()
    try:
        ep = Endpoint("udpin:192.0.2.1:14550", 1, 200, lambda e, m: None)   # TEST-NET-1: not this machine's
        with pytest.raises(OSError, match=r"MAVLink endpoint udpin:192\.0\.2\.1:14550: "):
            ep.open(loop)
    finally:
        loop.close()
