"""A simulated IIO device: what the kernel's adis16400 driver shows user space, built in a temporary directory
around the byte-level simulated chip, so `drivers.iio_source` is tested through the same code path as on
hardware (sysfs files written and read, whole scan records read from a character-device stand-in).

* `<root>/sys/bus/iio/devices/iio:device0/`: name, sampling_frequency, the scale/offset files, scan_elements/
  (`*_en`, `*_index`, `*_type` as the driver's channel table gives them), buffer/{enable,length},
  current_timestamp_clock, trigger/current_trigger — the values the driver's `adis16400_read_raw` formats
  (IIO_VAL_INT_PLUS_MICRO "%d.%06u"), listed in SYSFS below with their derivation.
* `<root>/dev/iio:device0`: a FIFO. While `buffer/enable` reads 1, a thread plays the kernel: on each of the
  simulated chip's data-ready edges (drivers.simulated.SimulatedDataReadyLine) it burst-reads the chip over its
  SPI bytes (0x3E00 + 24 bytes at 1 MHz, as `adis16400_trigger_handler` does), and writes one scan record:
  the enabled channels' raw big-endian words in scan-index order, each aligned to its size, the s64 time stamp
  (little-endian, ns, of `current_timestamp_clock`: CLOCK_REALTIME unless "monotonic" was written) and the
  padding of `iio_compute_scan_bytes`. A full FIFO drops the record, as the kernel's kfifo refuses a scan
  when full (`overflow_dropped`).

    device = SimulatedIioDevice(tmpdir, scenario="static")    # then IioSource(str(device.sysfs))
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import struct
import threading
import time
from pathlib import Path

from ahrsd.drivers import registers as R
from ahrsd.drivers.simulated import SimulatedAdis16405, SimulatedDataReadyLine
from ahrsd.drivers.threaded_source import set_realtime_priority

log = logging.getLogger(__name__)

# adis16400_channels[] (the ADIS16400 variant, which "adis16405" binds): (sysfs name, scan_index, type)
SCAN_ELEMENTS = (
    ("in_voltage0_supply", 0, "be:u14/16>>0"),     # ADIS16400_SUPPLY_CHAN(SUPPLY_OUT, 14)
    ("in_anglvel_x", 1, "be:s14/16>>0"),           # ADIS16400_GYRO_CHAN(X, XGYRO_OUT, 14)
    ("in_anglvel_y", 2, "be:s14/16>>0"),
    ("in_anglvel_z", 3, "be:s14/16>>0"),
    ("in_accel_x", 4, "be:s14/16>>0"),             # ADIS16400_ACCEL_CHAN(X, XACCL_OUT, 14)
    ("in_accel_y", 5, "be:s14/16>>0"),
    ("in_accel_z", 6, "be:s14/16>>0"),
    ("in_magn_x", 7, "be:s14/16>>0"),              # ADIS16400_MAGN_CHAN(X, XMAGN_OUT, 14)
    ("in_magn_y", 8, "be:s14/16>>0"),
    ("in_magn_z", 9, "be:s14/16>>0"),
    ("in_temp0", 11, "be:s12/16>>0"),              # ADIS16400_TEMP_CHAN(TEMP_OUT, 12): ADIS16350_SCAN_TEMP_X
    ("in_voltage1", 16, "be:u12/16>>0"),           # ADIS16400_AUX_ADC_CHAN(AUX_ADC, 12): ADIS16400_SCAN_ADC
    ("in_timestamp", 17, "le:s64/64>>0"),          # IIO_CHAN_SOFT_TIMESTAMP(ADIS16400_SCAN_TIMESTAMP), IIO_CPU
)
BURST_WORD = {name: i for i, (name, _, _) in enumerate(SCAN_ELEMENTS[:12])}   # the burst's word order

SYSFS = {
    "name": "adis16405",
    "sampling_frequency": "819.202000",       # adis16400_get_freq: 1638404 / (SMPL_PRD 0x01 + 1) milli-SPS
    "in_anglvel_scale": "0.000873",           # IIO_DEGREE_TO_RAD(50000) = 873 µrad/s per LSB (0.05 °/s)
    "in_accel_scale": "0.032685",             # IIO_G_TO_M_S_2(3333) = 32685 µm/s² per LSB (3.333 mg)
    "in_magn_scale": "0.000500",              # 500 µgauss per LSB (0.5 mgauss)
    "in_temp0_scale": "140.000000",           # temp_scale_nano 140000000 → 140 m°C per LSB
    "in_temp0_offset": "178",                 # temp_offset 25000000 / 140000 (integer division): 25 °C = 0 LSB
    "in_voltage0_supply_scale": "2.418000",   # 2.418 mV per LSB
    "in_voltage1_scale": "0.805800",          # 805.8 µV per LSB
    "current_timestamp_clock": "realtime",    # the IIO core's default
}
_BURST_TX = R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES)


def layout(enabled: list[tuple[str, int, str]]) -> tuple[list[tuple[str, int, int]], int]:
    """(name, byte offset, size) of each enabled element and the record size (iio_compute_scan_bytes)."""
    out, nbytes, largest = [], 0, 1
    for name, _index, typ in sorted(enabled, key=lambda e: e[1]):
        size = int(typ.split("/")[1].split(">>")[0]) // 8
        nbytes = (nbytes + size - 1) // size * size
        out.append((name, nbytes, size))
        nbytes += size
        largest = max(largest, size)
    return out, (nbytes + largest - 1) // largest * largest


def scan_record(words: list[int], timestamp_ns: int, enabled: list[tuple[str, int, str]]) -> bytes:
    """One scan record of the enabled elements from the 12 burst words (as read, flag bits included)."""
    elems, size = layout(enabled)
    rec = bytearray(size)
    for name, off, nbytes in elems:
        if name == "in_timestamp":
            struct.pack_into("<q", rec, off, timestamp_ns)
        else:
            struct.pack_into(">H", rec, off, words[BURST_WORD[name]])
    return bytes(rec)


class SimulatedIioDevice:
    """The sysfs tree and the FIFO in `root`, fed from a SimulatedAdis16405 on the real-time clock."""

    def __init__(self, root, scenario="static", seed: int = 0, errors: str = "adis16405",
                 clock=time.monotonic, chip: SimulatedAdis16405 | None = None):
        self.root = Path(root)
        self.sysfs = self.root / "sys/bus/iio/devices/iio:device0"
        self.node = self.root / "dev/iio:device0"
        self._clock = clock
        self.chip = chip or SimulatedAdis16405(scenario, seed=seed, errors=errors, clock=clock)
        self.stats = {"records": 0, "stale_records": 0, "overflow_dropped": 0}
        self._build_tree()
        self._stop = threading.Event()
        self._stall_s = 0.0
        self.first_index_written: int | None = None   # chip sample indices of the first and last record written:
        self.last_index_written: int | None = None    # the truth of the samples a reader should count as lost
        self._thread = threading.Thread(target=self._run, name="sim-iio-kernel", daemon=True)
        self._thread.start()

    def _build_tree(self) -> None:
        d = self.sysfs
        (d / "scan_elements").mkdir(parents=True, exist_ok=True)
        (d / "buffer").mkdir(exist_ok=True)
        (d / "trigger").mkdir(exist_ok=True)
        for name, value in SYSFS.items():
            (d / name).write_text(value + "\n")
        for name, index, typ in SCAN_ELEMENTS:
            (d / "scan_elements" / f"{name}_en").write_text("0\n")
            (d / "scan_elements" / f"{name}_index").write_text(f"{index}\n")
            (d / "scan_elements" / f"{name}_type").write_text(typ + "\n")
        (d / "buffer" / "enable").write_text("0\n")
        (d / "buffer" / "length").write_text("128\n")
        (d / "trigger" / "current_trigger").write_text("adis16405-dev0\n")
        self.node.parent.mkdir(parents=True, exist_ok=True)
        if not self.node.exists():
            os.mkfifo(self.node)

    def _read(self, rel: str) -> str:
        return (self.sysfs / rel).read_text().strip()

    def _enabled(self) -> list[tuple[str, int, str]]:
        return [(n, i, t) for n, i, t in SCAN_ELEMENTS if self._read(f"scan_elements/{n}_en") == "1"]

    def _run(self) -> None:
        # the kernel's threaded IRQ handlers run SCHED_FIFO 50: so does this one, where the system allows it
        set_realtime_priority()
        while not self._stop.is_set():
            if self._read("buffer/enable") != "1":
                time.sleep(0.01)
                continue
            try:
                self._stream()
            except Exception:  # noqa: BLE001 - a simulator failure ends the stream, loudly
                log.exception("simulated IIO device failed")
                return

    def _stream(self) -> None:
        """One buffer session: the driver's start-up, then a record per data-ready edge until disabled."""
        enabled = self._enabled()
        length = int(self._read("buffer/length"))
        elems, size = layout(enabled)
        fd = os.open(self.node, os.O_WRONLY)                 # blocks until the reader opens the node
        try:
            try:
                fcntl.fcntl(fd, 1031, max(4096, length * size))      # F_SETPIPE_SZ: the kfifo's length
            except OSError:
                pass
            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
            chip = self.chip
            chip.power_cycle()
            line = SimulatedDataReadyLine(chip, host_clock=self._clock)
            checks = 0
            while not self._stop.is_set():
                if not line.wait_edge_events(0.05):
                    if self._read("buffer/enable") != "1":
                        return
                    continue
                line.read_edge_events()
                if self._stall_s:                                          # an injected interrupt outage
                    stall, self._stall_s = self._stall_s, 0.0
                    time.sleep(stall)
                    continue
                rx = chip.transfer(_BURST_TX, R.SPI_BURST_HZ, 0)           # adis16400_trigger_handler
                words = list(struct.unpack(">12H", rx[2:26]))
                # the stamp of the sample read (a handler that reads within a period of its interrupt):
                # when this thread runs late, the chip already holds a newer sample than the last edge's
                stamp_ns = int(round(line._to_host(chip.ready_clock_time(chip.sample_index)) * 1e9))
                if self._read_clock() != "monotonic":
                    stamp_ns += time.time_ns() - time.monotonic_ns()
                rec = scan_record(words, stamp_ns, enabled)
                try:
                    os.write(fd, rec)
                    self.stats["records"] += 1
                    if not words[1] & R.ND:
                        self.stats["stale_records"] += 1      # the chip had no new sample (read late before)
                    if self.first_index_written is None:
                        self.first_index_written = chip.sample_index
                    self.last_index_written = chip.sample_index
                except BlockingIOError:
                    self.stats["overflow_dropped"] += 1
                except OSError as exc:
                    if exc.errno == errno.EPIPE:                  # the reader closed the node
                        return
                    raise
                checks += 1
                if checks % 256 == 0 and self._read("buffer/enable") != "1":
                    return
        finally:
            os.close(fd)

    def lost_truth(self) -> int:
        """Chip samples between the first and the last record written that no record carries."""
        if self.first_index_written is None:
            return 0
        fresh = self.stats["records"] - self.stats["stale_records"]
        return self.last_index_written - self.first_index_written + 1 - fresh

    def stall(self, seconds: float) -> None:
        """The "kernel" reads nothing for `seconds` (a lost interrupt, a stalled SPI controller): the chip's
        samples of that time are never read, the next record's time stamp jumps."""
        self._stall_s = seconds

    def _read_clock(self) -> str:
        # sysfs reads are cheap for the kernel; here a file read per record: cache for 0.1 s
        now = time.monotonic()
        if now - getattr(self, "_clock_read_at", -1.0) > 0.1:
            self._clock_read_at = now
            self._clock_name = self._read("current_timestamp_clock")
        return self._clock_name

    def close(self) -> None:
        self._stop.set()
        try:                                  # a writer still waiting in open() for its reader
            os.close(os.open(self.node, os.O_RDONLY | os.O_NONBLOCK))
        except OSError:
            pass
        self._thread.join(2.0)
        self.chip.close()
