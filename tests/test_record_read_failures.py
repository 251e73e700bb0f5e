"""`ahrsd record` reads the chip through drivers.source and stops on the daemon's sample-reading failure
policy (drivers.read_failures): corrupt frames are skipped until FRAME_ERRORS_FOR_FAILURE come in a row; a bus
error is a failure at once. Faults are injected into the byte-level simulated chip (drivers.faults)."""

from __future__ import annotations

import errno

import pytest

from ahrsd.cli.main import main
from ahrsd.drivers import source as drivers_source
from ahrsd.drivers.errors import BusError, FrameError
from ahrsd.drivers.faults import FaultKind, FaultPlan
from ahrsd.drivers.read_failures import FRAME_ERRORS_FOR_FAILURE, RETRY_AFTER_FAILURE_S, ReadFailures
from ahrsd.drivers.recording import read_recording

SECONDS = 1.0
RATE_HZ = 819.2
FAULT_START = 200


def test_the_policy_counts_corrupt_frames_in_a_row_and_fails_a_bus_at_once():
    failures = ReadFailures()
    for _ in range(FRAME_ERRORS_FOR_FAILURE - 1):
        verdict = failures.read_failed(FrameError("garbage"))
        assert not verdict.failed and verdict.retry_after_s is None
    assert failures.read_failed(FrameError("garbage")).failed
    failures.read_ok()
    assert not failures.read_failed(FrameError("garbage")).failed       # a good read starts the count again
    verdict = ReadFailures().read_failed(BusError("device gone"))
    assert verdict.failed and verdict.retry_after_s == RETRY_AFTER_FAILURE_S
    with pytest.raises(ValueError):
        ReadFailures(0)


def _record_with_fault(monkeypatch, tmp_path, capsys, kind: FaultKind, n_samples: int):
    plan = FaultPlan(seed=1)
    plan.add(kind, start_sample=FAULT_START, stop_sample=FAULT_START + n_samples)
    real_open_chip_bus = drivers_source.open_chip_bus

    def open_chip_bus_with_faults(kind_, **kw):
        return real_open_chip_bus(kind_, **{**kw, "faults": plan})

    monkeypatch.setattr(drivers_source, "open_chip_bus", open_chip_bus_with_faults)
    out = tmp_path / "rec.csv"
    rc = main(["record", "--sim", "static", "--seconds", str(SECONDS), "-o", str(out), "-q", "--no-self-test"])
    return rc, out, capsys.readouterr().err, plan


def test_fewer_corrupt_frames_than_the_limit_are_skipped(monkeypatch, tmp_path, capsys):
    rc, out, err, plan = _record_with_fault(monkeypatch, tmp_path, capsys, FaultKind.GARBAGE,
                                            FRAME_ERRORS_FOR_FAILURE // 2)
    assert rc == 0, err
    assert plan.injected[FaultKind.GARBAGE] > 0
    assert len(read_recording(out)) == round(SECONDS * RATE_HZ)


def test_the_end_of_run_line_says_what_went_wrong_in_words(monkeypatch, tmp_path, capsys):
    """The corrupt frames the byte-level chip was made to send, counted by the fault plan (not by the code
    under test), come back as a phrase on the last line; no counter dict, no reads-before-data-ready."""
    rc = main(["record", "--sim", "static", "--seconds", str(SECONDS), "-o", str(tmp_path / "clean.csv"), "-q"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 0 and last.endswith(" s"), last                    # a clean run: nothing after the time
    rc, out, err, plan = _record_with_fault(monkeypatch, tmp_path, capsys, FaultKind.GARBAGE,
                                            FRAME_ERRORS_FOR_FAILURE // 2)
    last = err.strip().splitlines()[-1]
    assert rc == 0 and last.startswith("ahrsd record: wrote "), err
    n = plan.injected[FaultKind.GARBAGE]
    # each corrupt frame carried a sample: it is a gap in the recording too
    assert f"; {n} samples lost (gaps in the recording), {n} corrupt frames rejected" in last, last
    assert "{" not in last and "stale" not in last and "_" not in last.split(" to ")[0], last


def test_a_gnss_receiver_that_cannot_be_opened_leaves_no_file(tmp_path, capsys):
    """`record --gnss-serial` on a device that does not exist: the reason, exit 1, and neither the IMU nor
    the GNSS recording created (a header-only file looks like a recording that caught nothing)."""
    out = tmp_path / "rec.csv"
    missing = tmp_path / "no-such-tty"
    rc = main(["record", "--sim", "static", "--realtime", "--seconds", "1", "-o", str(out), "-q",
               "--gnss-serial", str(missing)])
    err = capsys.readouterr().err
    assert rc == 1 and "ahrsd record: GNSS: cannot open GNSS receiver" in err and str(missing) in err, err
    assert not out.exists() and not (tmp_path / "rec.gnss.csv").exists()
    # refused before it starts (a simulated chip not on the host clock): the same
    rc = main(["record", "--sim", "static", "--seconds", "1", "-o", str(out), "-q", "--gnss-serial", str(missing)])
    err = capsys.readouterr().err
    assert rc == 1 and "needs the IMU on the host clock" in err and not out.exists(), err
    # the IMU recording cannot be written (its name is a directory) after the simulated boat's receiver
    # started: the GNSS file it began is removed too
    taken = tmp_path / "taken"
    taken.mkdir()
    rc = main(["record", "--sim", "boat", "--seconds", "1", "-o", str(taken), "-q"])
    err = capsys.readouterr().err
    assert rc == 1 and f"cannot write {taken}" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_the_limit_of_corrupt_frames_in_a_row_stops_the_recording(monkeypatch, tmp_path, capsys):
    rc, out, err, plan = _record_with_fault(monkeypatch, tmp_path, capsys, FaultKind.GARBAGE,
                                            2 * FRAME_ERRORS_FOR_FAILURE)
    assert rc == 1
    assert f"sensor failure ({FRAME_ERRORS_FOR_FAILURE} corrupt frames in a row)" in err
    assert len(read_recording(out)) < round(SECONDS * RATE_HZ)


class _BusFailingForAWhile:
    """The simulated chip behind a bus whose transfers fail (ENODEV) for `n_failures` calls after `start`
    transfers, then work again: counted in transfers, so a reader that kept going would come out of it."""

    def __init__(self, chip, start: int, n_failures: int):
        self._chip, self._start, self._stop = chip, start, start + n_failures
        self.transfers = 0

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        self.transfers += 1
        if self._start < self.transfers <= self._stop:
            raise OSError(errno.ENODEV, "No such device")
        return self._chip.transfer(tx, speed_hz, delay_us)

    def __getattr__(self, name):
        return getattr(self._chip, name)


def test_a_bus_error_stops_the_recording(monkeypatch, tmp_path, capsys):
    real_open_chip_bus = drivers_source.open_chip_bus
    monkeypatch.setattr(drivers_source, "open_chip_bus",
                        lambda kind, **kw: _BusFailingForAWhile(real_open_chip_bus(kind, **kw), 400, 10))
    out = tmp_path / "rec.csv"
    rc = main(["record", "--sim", "static", "--seconds", str(SECONDS), "-o", str(out), "-q", "--no-self-test"])
    err = capsys.readouterr().err
    assert rc == 1 and "sensor failure: " in err, err
    assert 0 < len(read_recording(out)) < 400
