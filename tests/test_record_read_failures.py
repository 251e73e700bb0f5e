"""`ahrsd record` reads the chip through drivers.source with drivers.source_recorder.SourceRecorder, which stops on
the daemon's sample-reading failure policy (drivers.read_failures): corrupt frames are skipped until
FRAME_ERRORS_FOR_FAILURE come in a row; a bus error is a failure at once. Faults are injected into the byte-level
simulated chip (drivers.faults), which counts what it injected independently of the reader."""

from __future__ import annotations

import errno

import pytest

from ahrsd.cli import record as record_cli
from ahrsd.cli.main import build_parser, main
from ahrsd.cli.record import problems_in_words
from ahrsd.drivers.errors import BusError, FrameError
from ahrsd.drivers.faults import FaultKind, FaultPlan
from ahrsd.drivers.read_failures import FRAME_ERRORS_FOR_FAILURE, RETRY_AFTER_FAILURE_S, ReadFailures
from ahrsd.drivers.recording import RecordingWriter, read_recording
from ahrsd.drivers.source import open_chip_bus, start_chip_source
from ahrsd.drivers.source_recorder import SourceRecorder

from support.chip_bus import SimulatedChipBus

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


def _record(tmp_path, bus, n_samples: int = round(SECONDS * RATE_HZ)):
    """`ahrsd record --sim static --seconds 1 --no-self-test`'s reading, on `bus`: (recorder, finished, rows)."""
    source = start_chip_source(bus, "ADIS16405", clock=bus.now, self_test=False)
    out = tmp_path / "rec.csv"
    with RecordingWriter(out, extra_columns=("temp_c", "supply_v", "flags", "counter")) as writer:
        recorder = SourceRecorder(source, writer, paced=False)
        finished = recorder.run(n_samples)
    return recorder, finished, len(read_recording(out)), source


def _faulted_chip(kind: FaultKind, n_samples: int):
    plan = FaultPlan(seed=1)
    plan.add(kind, start_sample=FAULT_START, stop_sample=FAULT_START + n_samples)
    return open_chip_bus("sim", scenario="static", clock=None, faults=plan), plan


def test_fewer_corrupt_frames_than_the_limit_are_skipped(tmp_path):
    bus, plan = _faulted_chip(FaultKind.GARBAGE, FRAME_ERRORS_FOR_FAILURE // 2)
    recorder, finished, rows, _ = _record(tmp_path, bus)
    assert finished and recorder.failure is None
    assert plan.injected[FaultKind.GARBAGE] > 0
    assert rows == recorder.written == round(SECONDS * RATE_HZ)


def test_the_count_of_corrupt_frames_starts_again_after_a_good_read(tmp_path):
    plan = FaultPlan(seed=1)
    burst = int(0.6 * FRAME_ERRORS_FOR_FAILURE)       # two bursts: more than the limit together, not in a row
    for start in (FAULT_START, FAULT_START + 2 * burst):
        plan.add(FaultKind.GARBAGE, start_sample=start, stop_sample=start + burst)
    recorder, finished, rows, _ = _record(tmp_path, open_chip_bus("sim", scenario="static", clock=None, faults=plan))
    assert plan.injected[FaultKind.GARBAGE] > FRAME_ERRORS_FOR_FAILURE
    assert finished and recorder.failure is None and rows == round(SECONDS * RATE_HZ)


def test_the_end_of_run_line_says_what_went_wrong_in_words(tmp_path, capsys):
    """The corrupt frames the byte-level chip was made to send, counted by the fault plan (not by the code
    under test), come back as phrases for the last line; no counter dict, no reads-before-data-ready."""
    rc = main(["record", "--sim", "static", "--seconds", str(SECONDS), "-o", str(tmp_path / "clean.csv"), "-q"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 0 and last.endswith(" s"), last                    # a clean run: nothing after the time
    bus, plan = _faulted_chip(FaultKind.GARBAGE, FRAME_ERRORS_FOR_FAILURE // 2)
    _, finished, _, source = _record(tmp_path, bus)
    n = plan.injected[FaultKind.GARBAGE]
    # each corrupt frame carried a sample: it is a gap in the recording too
    assert finished and problems_in_words(source.counters()) == [f"{n} samples lost (gaps in the recording)",
                                                                 f"{n} corrupt frames rejected"]


def test_a_gnss_receiver_that_cannot_be_opened_leaves_no_file(tmp_path, capsys):
    """`record --gnss-serial` on a device that does not exist: the reason, exit 1, and neither the IMU nor
    the GNSS recording created (a header-only file looks like a recording that caught nothing)."""
    out = tmp_path / "rec.csv"
    missing = tmp_path / "no-such-tty"
    rc = main(["record", "--sim", "static", "--realtime", "--seconds", "1", "-o", str(out), "-q",
               "--gnss-serial", str(missing)])
    err = capsys.readouterr().err
    assert rc == 1 and "ahrsd record: error: GNSS: cannot open GNSS receiver" in err and str(missing) in err, err
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


def test_the_limit_of_corrupt_frames_in_a_row_stops_the_recording(tmp_path):
    bus, _ = _faulted_chip(FaultKind.GARBAGE, 2 * FRAME_ERRORS_FOR_FAILURE)
    recorder, finished, rows, _ = _record(tmp_path, bus)
    assert not finished
    assert recorder.failure.startswith(f"sensor failure ({FRAME_ERRORS_FOR_FAILURE} corrupt frames in a row): ")
    assert rows == recorder.written == FAULT_START


class _BusFailingForAWhile(SimulatedChipBus):
    """The simulated chip behind a bus whose transfers fail (ENODEV) for `n_failures` calls after `start`
    transfers, then work again: counted in transfers, so a reader that kept going would come out of it."""

    def __init__(self, chip, start: int, n_failures: int):
        super().__init__(chip)
        self._start, self._stop = start, start + n_failures
        self.transfers = 0

    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        self.transfers += 1
        if self._start < self.transfers <= self._stop:
            raise OSError(errno.ENODEV, "No such device")
        return self.chip.transfer(tx, speed_hz, delay_us)


def test_a_bus_error_stops_the_recording(tmp_path):
    bus = _BusFailingForAWhile(open_chip_bus("sim", scenario="static", clock=None), 400, 10)
    recorder, finished, rows, _ = _record(tmp_path, bus)
    assert not finished and recorder.failure.startswith("sensor failure: "), recorder.failure
    assert 0 < rows == recorder.written < 400


def test_the_command_says_the_sensor_failed_and_exits_1(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    args = build_parser().parse_args(["record", "--sim", "static", "--seconds", str(SECONDS), "-o", str(out), "-q",
                                      "--no-self-test"])
    rc = record_cli.run(args, open_bus=lambda kind, **kw: _BusFailingForAWhile(open_chip_bus(kind, **kw), 400, 10))
    err = capsys.readouterr().err.strip().splitlines()
    rows = len(read_recording(out))
    assert rc == 1 and err[0].startswith("ahrsd record: error: sensor failure: "), err
    assert err[-1].startswith(f"ahrsd record: wrote {rows} samples ") and 0 < rows < 400, err
