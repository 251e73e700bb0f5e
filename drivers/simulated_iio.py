"""A simulated IIO device: what the kernel's adis16400 driver shows user space, built in a temporary directory
around the byte-level simulated chip, so `drivers.iio_source` is tested through the same code path as on
hardware (sysfs files written and read, whole scan records read from a character-device stand-in).

* `<root>/sys/bus/iio/devices/iio:device0/`: name, sampling_frequency, the scale/offset files, scan_elements/
  (`*_en`, `*_index`, `*_type` as the driver's channel table gives them), buffer/{enable,length},
  current_timestamp_clock, trigger/current_trigger — the values the driver's `adis16400_read_raw` formats
  (IIO_VAL_INT_PLUS_MICRO "%d.%06u"), listed in SYSFS below with their derivation.
* `<root>/dev/iio:device0`: a FIFO, its pipe sized to `buffer/length` records (F_SETPIPE_SZ).

The kernel runs where the kernel would: in a process of its own (spawned), never in the reader's process or
under its GIL. While `buffer/enable` reads 1 it plays `adis16400_trigger_handler`: for each of the chip's
samples it burst-reads the chip over its SPI bytes (0x3E00 + 24 bytes at 1 MHz) and writes one scan record —
the enabled channels' raw big-endian words in scan-index order, each aligned to its size, the s64 time stamp
(little-endian, ns, of `current_timestamp_clock`: CLOCK_REALTIME unless "monotonic" was written) and the
padding of `iio_compute_scan_bytes`. The kernel's handler is a SCHED_FIFO interrupt thread that reads each
sample within microseconds of its data-ready edge and stamps it in the hard interrupt
(`iio_pollfunc_store_time`); a simulator process is scheduled like any other and can wake late. So the
simulated handler reads sample k on the chip's clock at its edge + HANDLER_LATENCY_S, whenever the process
gets to it (a late wake writes the records it owes in one go), and stamps it with the edge time: the records
and their times are the kernel's, only their delivery into the pipe can come later. A record is lost only as the
kernel loses one: the buffer full (a non-blocking write that does not fit is dropped, as kfifo refuses a scan
when full: `overflow_dropped`), or an interrupt outage injected with `stall(seconds)`.

`sampling_frequency` is the driver's attribute, not a file with a value: a FIFO that a thread of the kernel
process serves, so that a write is applied before the next read of the file returns, as a sysfs store()
returns only once the driver is done. A write is parsed as the IIO core and `adis16400_write_raw` parse it and
handed to `adis16400_set_freq` (drivers.iio_source.driver_smpl_prd): SMPL_PRD written to the chip over its SPI
bytes, one byte-write frame at the SPI clock the driver sets for the new rate (2 MHz below divisor 0x0A on the
fast base, else 300 kHz); a read is `adis16400_get_freq` — SMPL_PRD read over SPI, "%d.%06u" of its milli-SPS —
or, with `rate_reads_empty`, the empty line of kernels since 5.5 (drivers.iio_source's module doc). The thread
looks for a reader or a writer every ATTRIBUTE_POLL_S: a writer whose open lands in the few microseconds
between the thread's last read of an idle FIFO and its close would be lost (the thread holds the read end that
long once a period). `smpl_prd` is the chip's SMPL_PRD as the driver last wrote or read it.

`remove()` unbinds the device as the kernel does when the chip or its driver goes away (the stream ends — the
reader's next read sees the end — and the sysfs directory and the node disappear); `recreate()` brings it back
with the buffer and channels disabled, like a fresh probe. The chip keeps running meanwhile (it stays powered):
its samples of the outage are never read. A re-probe resets the chip (`adis_initial_startup`): SMPL_PRD back at
its flash setting, 819.2 SPS.

    device = SimulatedIioDevice(tmpdir, scenario="static")    # then IioSource(str(device.sysfs))
"""

from __future__ import annotations

import errno
import fcntl
import logging
import multiprocessing
import os
import select
import shutil
import stat
import struct
import threading
import time
from pathlib import Path

from ahrsd.drivers import registers as R
from ahrsd.drivers.iio_source import driver_milli_sps, driver_smpl_prd, sysfs_rate_text, written_milli_sps

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
HANDLER_LATENCY_S = 20e-6        # edge → burst read of the kernel's threaded handler (SCHED_FIFO 50)
F_SETPIPE_SZ = 1031              # fcntl.F_SETPIPE_SZ (Python ≥ 3.10 names it; Linux's value)
RATE_ATTRIBUTE = "sampling_frequency"
ATTRIBUTE_POLL_S = 0.01          # the attribute thread looks for a reader or a writer this often
# the shared counters of the kernel process (an int64 array): their slots
_STATS = ("records", "stale_records", "overflow_dropped", "sessions", "first_index", "last_index")
_STALL_US, _UNPLUGGED, _UNPLUG_ACK, _READY = len(_STATS), len(_STATS) + 1, len(_STATS) + 2, len(_STATS) + 3
_SMPL_PRD, _ATTRIBUTE_STOP, _PROBED = len(_STATS) + 4, len(_STATS) + 5, len(_STATS) + 6
_ORIGIN_NS = len(_STATS) + 7     # CLOCK_MONOTONIC ns of the chip's time 0 (sample 0's data-ready), once up
_SLOTS = len(_STATS) + 8


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
    """The sysfs tree and the FIFO in `root`, fed by a simulated kernel in its own process (module doc)."""

    def __init__(self, root, scenario="static", seed: int = 0, errors: str = "adis16405",
                 rate_reads_empty: bool = False):
        self.root = Path(root)
        self.sysfs = self.root / "sys/bus/iio/devices/iio:device0"
        self.node = self.root / "dev/iio:device0"
        self._build_tree()
        ctx = multiprocessing.get_context("spawn")          # a clean interpreter: the kernel shares nothing
        self._shared = ctx.Array("q", _SLOTS, lock=False)
        self._shared[_STATS.index("first_index")] = self._shared[_STATS.index("last_index")] = -1
        self._shared[_SMPL_PRD] = R.SMPL_PRD_DEFAULT
        self._stop = ctx.Event()
        self._proc = ctx.Process(target=_kernel, name="sim-iio-kernel", daemon=True,
                                 args=(str(self.sysfs), str(self.node), scenario, seed, errors, self._shared,
                                       self._stop, rate_reads_empty))
        self._proc.start()

    @property
    def stats(self) -> dict:
        """records written, stale_records (ND clear), overflow_dropped (buffer full), sessions (buffer enables)."""
        return {k: int(self._shared[i]) for i, k in enumerate(_STATS[:4])}

    @property
    def smpl_prd(self) -> int:
        """The chip's SMPL_PRD as the simulated driver last wrote (set_freq) or read it over SPI (get_freq)."""
        return int(self._shared[_SMPL_PRD])

    @property
    def first_index_written(self) -> int | None:
        v = int(self._shared[_STATS.index("first_index")])
        return None if v < 0 else v

    @property
    def last_index_written(self) -> int | None:
        v = int(self._shared[_STATS.index("last_index")])
        return None if v < 0 else v

    @property
    def kernel_pid(self) -> int | None:
        """The simulated kernel's process: its CPU is the kernel's work on hardware, not the reader's."""
        return self._proc.pid

    def chip_time_s(self) -> float:
        """The chip's own time now (its `now()`, in the kernel process): time.monotonic() − its time 0, which
        the kernel publishes once the chip is up (wait_ready). The scenario's time of the records' samples, as
        long as no new rate restarts its sample grid: the clock a simulated receiver of the same vehicle runs on
        (drivers.gnss.scenario `chip_clock`), as the sim path's receiver runs on the chip's `now`."""
        if not self._shared[_READY]:
            raise RuntimeError("the simulated chip is not up yet (wait_ready)")
        return time.monotonic() - self._shared[_ORIGIN_NS] * 1e-9

    def wait_ready(self, timeout_s: float = 120.0) -> None:
        """Until the kernel process has its chip up (the spawn imports the simulator)."""
        end = time.monotonic() + timeout_s
        while not self._shared[_READY]:
            if time.monotonic() > end or not self._proc.is_alive():
                raise RuntimeError("the simulated IIO kernel process did not start")
            time.sleep(0.01)

    def _build_tree(self) -> None:
        d = self.sysfs
        (d / "scan_elements").mkdir(parents=True, exist_ok=True)
        (d / "buffer").mkdir(exist_ok=True)
        (d / "trigger").mkdir(exist_ok=True)
        for name, value in SYSFS.items():
            (d / name).write_text(value + "\n")
        if not (d / RATE_ATTRIBUTE).exists():
            os.mkfifo(d / RATE_ATTRIBUTE)                    # served by the kernel process (module doc)
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

    def lost_truth(self) -> int:
        """Chip samples between the first and the last record written that no record carries."""
        if self.first_index_written is None:
            return 0
        st = self.stats
        fresh = st["records"] - st["stale_records"]
        return self.last_index_written - self.first_index_written + 1 - fresh

    def stall(self, seconds: float) -> None:
        """The "kernel" reads nothing for `seconds` (a lost interrupt, a stalled SPI controller): the chip's
        samples of that time are never read, the next record's time stamp jumps."""
        self._shared[_STALL_US] = int(seconds * 1e6)

    def remove(self, timeout_s: float = 10.0) -> None:
        """The device goes away (unbind): the stream ends, the sysfs directory and the node disappear."""
        self._shared[_UNPLUG_ACK] = 0
        self._shared[_UNPLUGGED] = 1
        end = time.monotonic() + timeout_s
        while not self._shared[_UNPLUG_ACK] and time.monotonic() < end and self._proc.is_alive():
            time.sleep(0.005)
        shutil.rmtree(self.sysfs, ignore_errors=True)
        try:
            self.node.unlink()
        except FileNotFoundError:
            pass

    def recreate(self, timeout_s: float = 10.0) -> None:
        """The device is back (a fresh probe): buffer and channels disabled until a reader enables them. Its
        files appear once the probe has reset the chip (devm_iio_device_register ends the probe), so that a
        reader's rate written at once is not undone by the reset."""
        self._shared[_PROBED] = 0
        self._shared[_UNPLUGGED] = 0
        end = time.monotonic() + timeout_s
        while not self._shared[_PROBED] and time.monotonic() < end and self._proc.is_alive():
            time.sleep(0.005)
        self._build_tree()

    def close(self) -> None:
        self._freeze_rate_attribute()
        self._stop.set()
        self._proc.join(5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1.0)

    def _freeze_rate_attribute(self) -> None:
        """The attribute's thread stops and the FIFO becomes a file with the last rate: a read after the
        "kernel" is gone (a reader's re-open) must not wait for an answer forever."""
        self._shared[_ATTRIBUTE_STOP] = 1
        time.sleep(2 * ATTRIBUTE_POLL_S)
        path = self.sysfs / RATE_ATTRIBUTE
        if path.parent.is_dir():
            tmp = path.with_name(RATE_ATTRIBUTE + ".frozen")
            tmp.write_text(sysfs_rate_text(driver_milli_sps(self.smpl_prd)) + "\n")
            os.replace(tmp, path)


class _HandlerClock:
    """The chip's clock as the kernel's handler sees it: the time of the read it is doing (set per sample)."""

    def __init__(self):
        self.t = time.monotonic()

    def __call__(self) -> float:
        return self.t


def _kernel(sysfs: str, node: str, scenario, seed: int, errors: str, shared, stop, rate_reads_empty: bool) -> None:
    """The simulated kernel (a spawned process): buffer sessions while the device is present and enabled."""
    import signal

    from ahrsd.drivers.simulated import SimulatedAdis16405
    from ahrsd.drivers.threaded_source import request_realtime_priority

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # the test or bench ends it (Ctrl-C reaches the group)
    clock = _HandlerClock()
    chip = SimulatedAdis16405(scenario, seed=seed, errors=errors, clock=clock)
    kernel = _Kernel(Path(sysfs), node, chip, clock, shared, stop)
    attribute = threading.Thread(target=_RateAttribute(kernel, rate_reads_empty).serve, name="sim-iio-attribute",
                                 daemon=True)
    attribute.start()                                      # a sysfs store runs in the writer's context, not RT
    request_realtime_priority()                            # as the kernel's threaded IRQ handlers run
    shared[_ORIGIN_NS] = round(chip.ready_clock_time(0) * 1e9)    # the chip's time 0 on CLOCK_MONOTONIC
    shared[_READY] = 1
    unplugged = False
    try:
        while not stop.is_set():
            if shared[_UNPLUGGED]:
                shared[_UNPLUG_ACK] = 1
                unplugged = True
                time.sleep(0.01)
                continue
            if unplugged:                                  # a re-probe: adis_initial_startup resets the chip
                unplugged = False
                kernel.probe()
                shared[_PROBED] = 1
            if kernel.read("buffer/enable") != "1":
                time.sleep(0.01)
                continue
            kernel.session()
    finally:
        chip.close()


class _Kernel:
    def __init__(self, sysfs: Path, node: str, chip, clock: _HandlerClock, shared, stop):
        self.sysfs, self.node, self.chip, self.clock, self.shared, self.stop = sysfs, node, chip, clock, shared, stop
        self._clock_name, self._clock_read_at = "realtime", -1.0
        self.bus = threading.Lock()         # the SPI bus and the chip: the handler's bursts, the attribute's
        self.in_session = False
        self.spi_hz = R.SPI_FAST_HZ         # adis16400_initial_setup: fast while the divisor is below 0x0A

    def probe(self) -> None:
        """The driver's probe (adis16400_initial_setup): the chip reset (its flash settings), SMPL_PRD read at
        the slow clock, the fast clock kept if its divisor is below 0x0A."""
        with self.bus:
            self.clock.t = max(self.clock.t, time.monotonic())
            self.chip.power_cycle()
            self.chip.transfer(R.read_frame(R.SMPL_PRD), R.SPI_SLOW_HZ, R.STALL_US)
            smpl_prd = int.from_bytes(self.chip.transfer(bytes(2), R.SPI_SLOW_HZ, R.STALL_US), "big")
            fast = (smpl_prd & R.SMPL_PRD_DIVISOR_MASK) < R.SPI_FAST_MAX_DIVISOR
            self.spi_hz = R.SPI_FAST_HZ if fast else R.SPI_SLOW_HZ
        self.shared[_SMPL_PRD] = smpl_prd

    def _register_access_clock(self) -> None:
        # outside a buffer session the chip's clock is now; inside, the handler's (never set back)
        if not self.in_session:
            self.clock.t = max(self.clock.t, time.monotonic())

    def set_freq(self, text: str) -> None:
        """adis16400_write_raw(IIO_CHAN_INFO_SAMP_FREQ) -> adis16400_set_freq: the SPI clock for the new
        rate, then SMPL_PRD in one byte-write frame. A value the driver refuses (mSPS <= 0: EINVAL) is ignored."""
        try:
            milli_sps = written_milli_sps(text)
        except ValueError:
            return
        if milli_sps <= 0:
            return
        value = driver_smpl_prd(milli_sps)
        with self.bus:
            self._register_access_clock()
            self.spi_hz = R.spi_speed_hz(value)
            self.chip.transfer(bytes((R.WRITE_BIT | R.SMPL_PRD, value)), self.spi_hz, R.STALL_US)
        self.shared[_SMPL_PRD] = value

    def get_freq(self) -> int:
        """adis16400_get_freq: SMPL_PRD read over SPI (its value comes in the next frame), in milli-SPS."""
        with self.bus:
            self._register_access_clock()
            self.chip.transfer(R.read_frame(R.SMPL_PRD), self.spi_hz, R.STALL_US)
            smpl_prd = int.from_bytes(self.chip.transfer(bytes(2), self.spi_hz, R.STALL_US), "big")
        self.shared[_SMPL_PRD] = smpl_prd
        return driver_milli_sps(smpl_prd)

    def read(self, rel: str) -> str:
        try:
            return (self.sysfs / rel).read_text().strip()
        except OSError:
            return ""                                     # the device is being removed

    def _gone(self) -> bool:
        return bool(self.stop.is_set() or self.shared[_UNPLUGGED])

    def _stamp_offset_ns(self) -> int:
        # sysfs reads cost the kernel nothing; here a file read: cached for 0.1 s
        now = time.monotonic()
        if now - self._clock_read_at > 0.1:
            self._clock_read_at = now
            self._clock_name = self.read("current_timestamp_clock") or self._clock_name
        return 0 if self._clock_name == "monotonic" else time.time_ns() - time.monotonic_ns()

    def _open_writer(self) -> int | None:
        """The write end once a reader has the node open (ENXIO until then)."""
        while not self._gone() and self.read("buffer/enable") == "1":
            try:
                return os.open(self.node, os.O_WRONLY | os.O_NONBLOCK)
            except OSError as exc:
                if exc.errno not in (errno.ENXIO, errno.ENOENT):
                    raise
            time.sleep(0.005)
        return None

    def session(self) -> None:
        """One buffer session: the driver's start-up, then a record per chip sample until disabled or gone."""
        enabled = [(n, i, t) for n, i, t in SCAN_ELEMENTS if self.read(f"scan_elements/{n}_en") == "1"]
        length = int(self.read("buffer/length") or 128)
        _, size = layout(enabled)
        fd = self._open_writer()
        if fd is None:
            return
        shared, chip = self.shared, self.chip
        shared[_STATS.index("sessions")] += 1
        self.in_session = True
        try:
            k = self._start_up(fd, length * size)
            checked = time.monotonic()
            while not self._gone():
                now = time.monotonic()
                if now - checked > 0.1:
                    checked = now
                    if self.read("buffer/enable") != "1":
                        return
                stall_us = shared[_STALL_US]
                if stall_us:                                  # an injected interrupt outage from now on
                    shared[_STALL_US] = 0
                    k = max(k, chip.first_index_after(now + stall_us * 1e-6))
                k = self._handle_interrupts(fd, k, chip.first_index_after(now) - 1, enabled)
                if k is None:
                    return                                  # the reader closed the node
                time.sleep(max(0.0, chip.ready_clock_time(k) + HANDLER_LATENCY_S - time.monotonic()))
        finally:
            self.in_session = False
            os.close(fd)

    def _start_up(self, fd: int, buffer_bytes: int) -> int:
        """The driver's buffer enable: the pipe sized as the kfifo (the chip keeps its settings: SMPL_PRD as
        written); the index of the first data-ready edge after it."""
        try:
            fcntl.fcntl(fd, F_SETPIPE_SZ, max(4096, buffer_bytes))     # the kfifo's length
        except OSError:
            pass
        with self.bus:
            self.clock.t = max(self.clock.t, time.monotonic())
            return self.chip.first_index_after(self.clock.t)

    def _handle_interrupts(self, fd: int, k: int, newest: int, enabled) -> int | None:
        """adis16400_trigger_handler for each edge k..newest: burst-read the chip at the edge's handler time and
        write the scan record stamped with the edge (dropped when the buffer is full, counted). The next edge to
        handle; None when the reader closed the node."""
        offset_ns = self._stamp_offset_ns() if k <= newest else 0
        with self.bus:                                # the attribute's register accesses wait
            return self._handle_locked(fd, k, newest, enabled, offset_ns)

    def _handle_locked(self, fd: int, k: int, newest: int, enabled, offset_ns: int) -> int | None:
        shared, chip, clock = self.shared, self.chip, self.clock
        records, stale, dropped = (_STATS.index(n) for n in ("records", "stale_records", "overflow_dropped"))
        first, last = _STATS.index("first_index"), _STATS.index("last_index")
        while k <= newest:
            edge = chip.ready_clock_time(k)
            clock.t = edge + HANDLER_LATENCY_S
            rx = chip.transfer(_BURST_TX, R.SPI_BURST_HZ, 0)           # adis16400_trigger_handler
            words = struct.unpack(">12H", rx[2:26])
            rec = scan_record(list(words), int(round(edge * 1e9)) + offset_ns, enabled)
            try:
                os.write(fd, rec)
                shared[records] += 1
                if not words[1] & R.ND:
                    shared[stale] += 1              # the chip had no new sample
                if shared[first] < 0:
                    shared[first] = chip.sample_index
                shared[last] = chip.sample_index
            except BlockingIOError:
                shared[dropped] += 1                # the buffer is full: kfifo refuses the scan
            except BrokenPipeError:
                return None
            k += 1
        return k


class _RateAttribute:
    """sampling_frequency served on its FIFO (module doc): a reader gets the driver's answer, a writer's value
    goes to set_freq; one at a time, so a read after a write sees it applied."""

    def __init__(self, kernel: _Kernel, reads_empty: bool):
        self.kernel, self.reads_empty = kernel, reads_empty
        self.path = kernel.sysfs / RATE_ATTRIBUTE

    def serve(self) -> None:
        shared = self.kernel.shared
        while not (shared[_ATTRIBUTE_STOP] or self.kernel.stop.is_set()):
            if not (self._answer_a_reader() or self._take_a_write()):
                time.sleep(ATTRIBUTE_POLL_S)

    def _open(self, flags: int) -> int | None:
        """The FIFO opened non-blocking; None if it is not there (removed, or frozen into a file) or, for
        writing, has no reader."""
        try:
            fd = os.open(self.path, flags | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno in (errno.ENXIO, errno.ENOENT):
                return None
            raise
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            os.close(fd)
            return None
        return fd

    def _answer_a_reader(self) -> bool:
        """A reader waits (the FIFO opens for writing only then): the driver's read. The FIFO is replaced by a
        fresh one before the answer, so that the next reader (or the same again) is answered on its own FIFO."""
        fd = self._open(os.O_WRONLY)
        if fd is None:
            return False
        try:
            fresh = self.path.with_name(f".{RATE_ATTRIBUTE}.next")
            if fresh.exists():
                fresh.unlink()                      # left by an answer the device's removal cut short
            os.mkfifo(fresh)
            os.replace(fresh, self.path)
            milli_sps = self.kernel.get_freq()
            text = "" if self.reads_empty else sysfs_rate_text(milli_sps)
            os.write(fd, (text + "\n").encode())
        except (BrokenPipeError, FileNotFoundError):
            pass                                    # the reader went, or the device was removed meanwhile
        finally:
            os.close(fd)
        return True

    def _take_a_write(self) -> bool:
        """A writer waits in its open (or none: the read end sees no writer and ends at once): its value to
        set_freq."""
        fd = self._open(os.O_RDONLY)
        if fd is None:
            return False
        data = b""
        try:
            while True:
                try:
                    chunk = os.read(fd, 256)
                except BlockingIOError:             # a writer has it open and has not written yet
                    select.select([fd], [], [], 0.1)
                    continue
                if not chunk:
                    break
                data += chunk
        finally:
            os.close(fd)
        if not data:
            return False
        self.kernel.set_freq(data.decode(errors="replace"))
        return True
