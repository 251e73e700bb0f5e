"""The kernel's ADIS16400/5 IIO driver as a sensor source (`[sensor] source = "iio"`, `ahrsd run --iio DEVICE`).

Linux `drivers/iio/imu/adis16400.c` ("support Analog Devices ADIS16400/5") reads the chip in the kernel on its
data-ready interrupt (one burst per sample), time-stamps each read in the interrupt and queues the scan in a
buffer; user space enables channels and the buffer through sysfs and reads whole scan records from
`/dev/iio:deviceN`. The kernel buffers (`buffer/length` scans), so a reader that is late by less than that
loses nothing: this source needs no thread of its own — `poll()` takes every complete record waiting.

The record, for the ADIS16405 ("adis16405" binds the ADIS16400 variant), from the driver's channel table
`adis16400_channels[]` and `industrialio-buffer.c`:
* scan order = ascending scan_index (`enum { ADIS16400_SCAN_SUPPLY, _GYRO_X.. }`): supply 0, gyro x/y/z 1-3,
  accel x/y/z 4-6, magn x/y/z 7-9, temp 11 (ADIS16350_SCAN_TEMP_X; 10 is the ADIS16448's barometer, absent),
  aux ADC 16, timestamp 17. sysfs names: in_voltage0_supply, in_anglvel_{x,y,z}, in_accel_{x,y,z},
  in_magn_{x,y,z}, in_temp0, in_voltage1, in_timestamp.
* each data channel: 16 storage bits, big-endian (IIO_BE), shift 0; realbits 14 signed for gyro/accel/magn
  (`be:s14/16>>0`), 14 unsigned for the supply (`be:u14/16>>0`), 12 signed for temp (`be:s12/16>>0`), 12
  unsigned for aux (`be:u12/16>>0`). The two storage bits above realbits are the chip's raw flag bits (bit 15
  ND new data, bit 14 EA alarm: the kernel pushes the burst words as read, `adis16400_trigger_handler`), masked
  off by realbits and read here as flags.
* the timestamp: IIO_CHAN_SOFT_TIMESTAMP, `le:s64/64>>0` on a little-endian CPU (IIO_CPU), nanoseconds of
  the device's `current_timestamp_clock` (default "realtime": this source writes "monotonic").
* layout (`iio_compute_scan_bytes`): each enabled element aligned to its own storage size, the record padded
  to its largest element: 12 × 2 bytes, the timestamp at byte 24, 32 bytes per record.
Scales (`adis16400_read_raw`, IIO_VAL_INT_PLUS_MICRO, read from sysfs, not assumed): in_anglvel_scale rad/s per
LSB (IIO_DEGREE_TO_RAD(50000) µrad/s: 0.000873), in_accel_scale m/s² (IIO_G_TO_M_S_2(3333) µm/s²: 0.032685),
in_magn_scale gauss (0.000500; × 100 → µT), in_temp0_scale m°C with in_temp0_offset LSB
(value = (raw + offset) × scale), in_voltage0_supply_scale mV. ABI: Documentation/ABI/testing/sysfs-bus-iio.

Lost samples: the kernel time-stamps every scan in the data-ready interrupt, so a scan dropped anywhere (the
kernel buffer full: kfifo refuses new scans; a missed interrupt) shows as a time-stamp step of more than one
period; the next sample carries GAP_BEFORE and its index jumps by the samples missing, exactly as on the
spidev path (drivers.sample_timer), and `lost_samples_host` counts them. The count is exact while the kernel's
threaded handler reads the chip within a period of its interrupt: a handler later than that reads the next
sample under the earlier stamp (then a scan with ND clear, counted `stale`, or one step too many follows).

Read off the event loop: in the daemon's process drivers.threaded_source's reader thread reads the kernel's buffer
when the daemon's next output falls due (and at the latest every 25 ms), decodes the records into one block of
columns (`decode_block`: core.sample_block, no ImuSample per record) and wakes the daemon; the kernel holds the
records meanwhile. `wait(timeout_s)` blocks (in select, without the GIL) until records are waiting: paced to
READ_EVERY_S in a reader process's thread (`reader = "process"`, whose own hand-over decides), at once for the
first record after a deadline. The kernel buffer (`buffer/length` scans) is what a stalled reader has before a
scan is lost, the thread's hand-over buffer what a stalled event loop has.

The sampling rate (`[sensor] rate_hz`, `IioSource(rate_hz=...)`): the driver's `sampling_frequency` attribute
(IIO_CHAN_INFO_SAMP_FREQ, shared by all channels). A write is parsed as micro-units (`iio_write_channel_info`:
"204.8" is 204 + 800000 µ) and handed to `adis16400_write_raw`, which takes milli-SPS (val × 1000 + val2 / 1000)
and calls `adis16400_set_freq`: t = 1638404 / mSPS (integer division); t < 128 writes SMPL_PRD = t − 1 on the
fast time base, else the slow base bit with t = 52851 / mSPS (at most 127, and not decremented), one byte write
(`__adis_write_reg_8`). A read is `adis16400_get_freq`: (52851 if bit 7 else 1638404) / (divisor + 1) mSPS,
formatted "%d.%06u" (IIO_VAL_INT_PLUS_MICRO). The driver takes the write whether or not the buffer runs (no
`iio_device_claim_direct_mode`); this source writes with the buffer disabled, before enabling it, since its
gap detection needs the period from the start. It writes the kernel's own value of the SMPL_PRD setting that
`registers.smpl_prd_for_rate` picks (the spidev path's rule: "204.800000" for 204.8, SMPL_PRD 7), reads it back
and runs at what it reads. The driver's integer rule cannot reach SMPL_PRD 0x7F (12.8 SPS): 12.8 becomes the
slow base's 0x84, 10.570 SPS (driver_smpl_prd). Kernels since 5.5 read the attribute as an empty line:
`adis16400_read_raw` returns get_freq's positive value where the IIO core expects a format code
(`if (ret) return ret;`, from "iio: imu: adis16400: check ret val for non-zero vs less-than-zero", 2019),
and `iio_format_value` prints nothing for an unknown code. On such a kernel the rate is what the driver's
set_freq/get_freq make of the value written (without `rate_hz` the chip's default, 819.2, is written so that
the rate is known), with a warning.

A vanished device (the chip or its driver unbound: reads fail with ENODEV, or the stream ends) is closed,
counted (`device_lost`) and logged once; `poll()` then raises BusError (the daemon reports the sensor failed)
and re-opens it with backoff (0.2 s doubling to 5 s): found again by the same spec (a name may come back as
another iio:deviceN), reconfigured from scratch as after a fresh probe, counted (`reopens`) and logged. The
last time stamp is kept, so the samples of the outage are counted lost (GAP_BEFORE), as on the spidev path.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import re
import select
import time
from dataclasses import dataclass
from typing import NamedTuple
from pathlib import Path

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import SampleBlock
from ahrsd.drivers import registers as R
from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ
from ahrsd.drivers.errors import BusError
from ahrsd.drivers.source_interface import LiveSource

log = logging.getLogger(__name__)

IIO_DEVICES = "/sys/bus/iio/devices"
BUFFER_LENGTH = 8192                 # scans the kernel holds (10 s at 819.2 SPS): the longest reader stall
MAX_RECORDS_PER_POLL = 4096
UT_PER_GAUSS = 100.0
BACKOFF_FIRST_S = 0.2                # re-open attempts after the device vanished (as drivers.reconnecting)
BACKOFF_MAX_S = 5.0
NO_WRITER_POLL_S = 0.01              # the FIFO stand-in before its writer opened: select() would not block
# a record is in the kernel's buffer this long after its data-ready edge (its time stamp): the driver's threaded
# handler wakes and burst-reads the chip, 0x3E00 and 12 words = 26 bytes at ADIS16400_SPI_BURST (1 MHz), 208 µs
READ_AFTER_EDGE_S = 0.0003
READ_EVERY_S = 0.004                 # a paced wait (a reader process's thread) reads at most this often: a
                                     # wake per scan would cost a decode per scan

# adis16400_get_freq / adis16400_set_freq: the two time bases in milli-SPS, integer arithmetic
DRIVER_FAST_BASE_MSPS = 1638404
DRIVER_SLOW_BASE_MSPS = 52851
RATE_WRITE_FIX = ("the daemon's group needs write access to it: systemd/99-ahrsd-iio.rules gives the group iio "
                  "the device's files (sampling_frequency among them) and systemd/ahrsd-iio.conf adds the group "
                  "and lifts ProtectKernelTunables (docs/drivers.md, \"Under systemd\"); without it, leave "
                  "[sensor] rate_hz at its default: the driver's rate is then only read (where the kernel reads it)")

# the channels this source enables, in the roles of an ImuSample (sysfs scan element name → role)
CHANNELS = ("in_voltage0_supply", "in_anglvel_x", "in_anglvel_y", "in_anglvel_z", "in_accel_x", "in_accel_y",
            "in_accel_z", "in_magn_x", "in_magn_y", "in_magn_z", "in_temp0", "in_voltage1", "in_timestamp")
_TYPE = re.compile(r"^(be|le):([su])(\d+)/(\d+)(?:X(\d+))?>>(\d+)$")
_GAP_BEFORE, _ALARM, _NEW_DATA = int(SampleFlags.GAP_BEFORE), int(SampleFlags.ALARM), int(SampleFlags.NEW_DATA)
# a saturated sensor's flags (saturated, hence invalid), gyro / accel / mag: disjoint bits, so a sum is their OR
_SATURATED_BITS = np.array([int(SampleFlags.GYRO_SATURATED | SampleFlags.GYRO_INVALID),
                            int(SampleFlags.ACCEL_SATURATED | SampleFlags.ACCEL_INVALID),
                            int(SampleFlags.MAG_SATURATED | SampleFlags.MAG_INVALID)], dtype=np.int64)
_SATURATED_ANY = int(_SATURATED_BITS.sum())


class _Block(NamedTuple):
    """A block of records decoded at once (IioSource._convert): rows are records."""
    si: np.ndarray           # the 12 data channels in SI, (n, 12): supply V, gyro rad/s, accel m/s², mag µT, temp °C
    new_data: list           # the chip's ND bit set on every sensor word, (n,) bools
    garbage: list            # a sensor word beyond 1.25 × its range: not a frame the chip sent, (n,) bools
    status: list             # ALARM (the chip's EA bit on any sensor word) and each saturated sensor's flags, (n,) ints


@dataclass(frozen=True)
class ScanType:
    """One scan element's `*_type`, e.g. "be:s14/16>>0"
    (sysfs-bus-iio: [be|le]:[s|u]bits/storagebits[Xrepeat]>>shift)."""

    big_endian: bool
    signed: bool
    realbits: int
    storagebits: int
    shift: int
    repeat: int = 1

    @classmethod
    def parse(cls, text: str) -> "ScanType":
        m = _TYPE.match(text.strip())
        if m is None:
            raise ValueError(f"not an IIO scan element type: {text.strip()!r}")
        end, sign, real, storage, repeat, shift = m.groups()
        st = cls(end == "be", sign == "s", int(real), int(storage), int(shift), int(repeat or 1))
        if st.storagebits not in (8, 16, 32, 64) or not 0 < st.realbits <= st.storagebits:
            raise ValueError(f"unsupported IIO scan element type {text.strip()!r}")
        return st

    @property
    def nbytes(self) -> int:
        return self.storagebits // 8 * self.repeat

    def dtype(self) -> np.dtype:
        return np.dtype(f"{'>' if self.big_endian else '<'}u{self.storagebits // 8}")

    def values(self, raw: np.ndarray) -> np.ndarray:
        """Storage words -> signed/unsigned integers: shift, mask to realbits, sign-extend."""
        v = raw.astype(np.uint64)
        if self.shift:
            v >>= np.uint64(self.shift)
        if self.realbits < 64:
            v &= np.uint64((1 << self.realbits) - 1)
        if not self.signed:
            return v.astype(np.int64)
        if self.realbits == 64:
            return v.view(np.int64)
        half = 1 << (self.realbits - 1)
        return (v.astype(np.int64) ^ half) - half


@dataclass(frozen=True)
class Element:
    name: str
    index: int
    type: ScanType
    offset: int           # byte offset in the record


def record_layout(elements: list[tuple[str, int, ScanType]]) -> tuple[list[Element], int]:
    """Byte offsets and record size of the enabled elements (kernel `iio_compute_scan_bytes`): ascending
    scan index, each aligned to its own storage size, the record aligned to its largest element."""
    out, nbytes, largest = [], 0, 1
    for name, index, st in sorted(elements, key=lambda e: e[1]):
        length = st.nbytes
        align = st.storagebits // 8
        nbytes = (nbytes + align - 1) // align * align
        out.append(Element(name, index, st, nbytes))
        nbytes += length
        largest = max(largest, length)
    nbytes = (nbytes + largest - 1) // largest * largest
    return out, nbytes


def driver_smpl_prd(milli_sps: int) -> int:
    """The SMPL_PRD `adis16400_set_freq` writes for a sampling_frequency of `milli_sps` (> 0), its integer
    arithmetic as it is: the slow time base's divisor is not decremented."""
    t = DRIVER_FAST_BASE_MSPS // milli_sps
    if t >= 128:
        return R.SMPL_PRD_TIME_BASE | min(127, DRIVER_SLOW_BASE_MSPS // milli_sps)
    return t - 1 if t else 0


def driver_milli_sps(smpl_prd: int) -> int:
    """`adis16400_get_freq`: the rate of a SMPL_PRD value in milli-SPS, as the driver reports it."""
    base = DRIVER_SLOW_BASE_MSPS if smpl_prd & R.SMPL_PRD_TIME_BASE else DRIVER_FAST_BASE_MSPS
    return base // ((smpl_prd & R.SMPL_PRD_DIVISOR_MASK) + 1)


def sysfs_rate_text(milli_sps: int) -> str:
    """A rate as the driver's read formats it (IIO_VAL_INT_PLUS_MICRO, "%d.%06u"): 204800 -> "204.800000"."""
    return f"{milli_sps // 1000}.{milli_sps % 1000 * 1000:06d}"


def written_milli_sps(text: str) -> int:
    """What `adis16400_write_raw` receives for a written string: iio_write_channel_info parses micro-units
    (digits past the sixth dropped), the driver takes val × 1000 + val2 / 1000."""
    whole, _, frac = text.strip().partition(".")
    micro = int((frac + "000000")[:6]) if frac else 0
    return int(whole) * 1000 + micro // 1000


def driver_rate_hz(rate_hz: float) -> float:
    """The rate the kernel's driver runs at when this source asks for `rate_hz`: the kernel's value of the
    nearest SMPL_PRD setting written, then set_freq's and get_freq's integer rules (12.8 -> 10.570)."""
    return driver_milli_sps(driver_smpl_prd(driver_milli_sps(R.smpl_prd_for_rate(rate_hz)))) / 1000.0


def next_edge_s(t: float, last_s: float, period_s: float) -> float:
    """The chip's first data-ready edge at or after `t`, from the edge `last_s` and the period (the kernel stamps
    each scan with its edge). It looks at most HANDOVER_MAX_S (25 ms, 31 periods) ahead: a chip clock off the rate
    read back moves the edge by that share of it, and a read that finds the record not yet there waits for it
    (drivers.threaded_source). A `t` within 1 µs past an edge is that edge."""
    return last_s + max(0, math.ceil((t - last_s - 1e-6) / period_s)) * period_s


def resolve_device(spec: str) -> tuple[Path, Path]:
    """(sysfs directory, character device) of `spec`: a sysfs directory path (…/sys/bus/iio/devices/iio:deviceN,
    the device node then being …/dev/iio:deviceN under the same root — how the simulated device lives in a
    temporary directory), "iio:deviceN", or the device's name ("adis16405")."""
    p = Path(spec)
    if p.is_absolute() and p.name.startswith("iio:device"):
        parts = str(p).split("/sys/bus/iio/devices/")
        root = parts[0] if len(parts) == 2 else ""
        return p, Path(f"{root}/dev/{p.name}")
    base = Path(IIO_DEVICES)
    if spec.startswith("iio:device"):
        return base / spec, Path("/dev") / spec
    for d in sorted(base.glob("iio:device*")):
        try:
            if (d / "name").read_text().strip() == spec:
                return d, Path("/dev") / d.name
        except OSError:
            continue
    raise BusError(f"no IIO device named {spec!r} under {IIO_DEVICES}: is the adis16400 driver bound "
                   "(device-tree overlay, `dmesg | grep adis`)?")


def _read(path: Path) -> str:
    return path.read_text().strip()


def _write(path: Path, value: str) -> None:
    path.write_text(value + "\n")


class IioSource(LiveSource):
    """The ADIS16405 through the kernel's IIO buffer: whole scan records in blocks (`poll()`), converted with the
    kernel's scale/offset to SI, time-stamped by the kernel (CLOCK_MONOTONIC), gaps counted from the stamps."""

    description: str
    sample_rate_hz: float
    per_sample = False
    monotonic_offset_s = 0.0            # the kernel's stamps are CLOCK_MONOTONIC (current_timestamp_clock)

    def __init__(self, spec: str, *, buffer_length: int = BUFFER_LENGTH, clock=time.monotonic,
                 rate_hz: float | None = None):
        """rate_hz: written to the driver's sampling_frequency at every (re)start (None: the driver's rate is
        left as it is and read)."""
        self.spec = spec
        self.rate_hz = rate_hz
        self.sysfs, self.node = resolve_device(spec)
        self.buffer_length = buffer_length
        self._clock = clock
        self._streaming = False         # records came since the buffer was opened
        self._lost_reason = ""          # the device vanished: why (empty while it is up)
        self._next_attempt = 0.0
        self._backoff_s = BACKOFF_FIRST_S
        self._read_at = -1.0
        self.name = ""
        self.description = ""
        self.sample_rate_hz = 0.0
        self._fd: int | None = None
        self._rest = b""
        self._k = -1
        self._last_ns: int | None = None
        self.stats = {"records": 0, "samples": 0, "lost_samples_host": 0, "gaps": 0, "stale": 0,
                      "ea_flags": 0, "saturations": 0, "garbage_frames": 0, "timestamp_backwards": 0,
                      "device_lost": 0, "reopens": 0, "reopen_failures": 0}

    # -- set-up -------------------------------------------------------------------------------------------------

    def start(self) -> None:
        """Enable the channels and check the device (BusError with a hint). The buffer is enabled and the
        character device opened at the first `poll()`: scans the kernel queued while the daemon was still
        starting would be stale, and a failure there is reported and retried by the daemon's reader."""
        d = self.sysfs
        try:
            self.name = _read(d / "name")
            if (d / "buffer" / "enable").exists() and _read(d / "buffer" / "enable") == "1":
                _write(d / "buffer" / "enable", "0")       # a previous run left it on: reconfigure
            self.sample_rate_hz = self._set_rate()
            scan = d / "scan_elements"
            for name in os.listdir(scan):
                if name.endswith("_en"):
                    _write(scan / name, "1" if name[:-3] in CHANNELS else "0")
            elements = []
            for name in CHANNELS:
                if not (scan / f"{name}_en").exists():
                    raise BusError(f"{d}: no scan element {name} (is this an ADIS16400/5? name {self.name!r})")
                elements.append((name, int(_read(scan / f"{name}_index")),
                                 ScanType.parse(_read(scan / f"{name}_type"))))
            self.elements, self.record_bytes = record_layout(elements)
            self._scale = self._scales()
            clock = d / "current_timestamp_clock"
            if clock.exists():
                _write(clock, "monotonic")                   # the clock of every other time stamp here
            trigger = d / "trigger" / "current_trigger"
            if trigger.exists() and not _read(trigger):
                _write(trigger, f"{self.name}-dev{d.name.removeprefix('iio:device')}")
            _write(d / "buffer" / "length", str(self.buffer_length))
        except BusError:
            raise
        except (OSError, ValueError) as exc:
            raise BusError(f"IIO device {d}: {exc}") from exc
        self._dtype = np.dtype({"names": [e.name for e in self.elements],
                                "formats": [e.type.dtype() if e.type.repeat == 1 else (e.type.dtype(), e.type.repeat)
                                            for e in self.elements],
                                "offsets": [e.offset for e in self.elements], "itemsize": self.record_bytes})
        self._period_ns = 1e9 / self.sample_rate_hz
        self._stamp_type = {e.name: e.type for e in self.elements}["in_timestamp"]
        self._prepare_words()
        self.description = f"{self.name} through the kernel's IIO driver ({d.name}, {self.record_bytes}-byte scans)"
        log.info("IIO %s: %s at %.3f SPS, %d-byte records, buffer %d scans", d.name, self.name,
                 self.sample_rate_hz, self.record_bytes, self.buffer_length)

    def _set_rate(self) -> float:
        """Write `rate_hz` (if asked) to sampling_frequency with the buffer disabled, read it back and return
        the rate read; on a kernel whose read is empty (module doc) the driver's rule for the value written."""
        path = self.sysfs / "sampling_frequency"
        if not path.exists():
            path = self.sysfs / "in_sampling_frequency"
        written = None
        if self.rate_hz is not None:
            written = self._write_rate(path, self.rate_hz)
        got = _read(path)
        if not got:
            asked = ADIS16405_RATE_HZ if self.rate_hz is None else self.rate_hz
            if written is None:
                written = self._write_rate(path, asked)
            rate_hz = driver_rate_hz(asked)
            log.warning("IIO %s: %s reads empty (adis16400_read_raw on Linux >= 5.5, docs/drivers.md); wrote %s, "
                        "so the driver runs at %.3f SPS by its set_freq rule", self.sysfs.name, path.name,
                        written, rate_hz)
            return rate_hz
        if written is not None:
            log.info("IIO %s: sampling_frequency asked %g SPS (wrote %s), the driver reads back %s",
                     self.sysfs.name, self.rate_hz, written, got)
        return float(got)

    @staticmethod
    def _write_rate(path: Path, rate_hz: float) -> str:
        """The kernel's own value of the nearest SMPL_PRD setting (module doc), written; BusError naming the file
        and the fix if the kernel or the file's permissions refuse it."""
        text = sysfs_rate_text(driver_milli_sps(R.smpl_prd_for_rate(rate_hz)))
        try:
            _write(path, text)
        except OSError as exc:
            why = os.strerror(exc.errno) if exc.errno else str(exc)
            raise BusError(f"cannot set the sampling rate: writing {text} to {path} failed ({why}); "
                           f"{RATE_WRITE_FIX}") from exc
        return text

    def _scales(self) -> dict[str, tuple[float, float]]:
        """(offset LSB, SI per LSB) per channel from sysfs: shared-by-type (in_anglvel_scale) or separate."""
        d = self.sysfs

        def value(*names: str, default: float | None = None) -> float:
            for n in names:
                if (d / n).exists():
                    return float(_read(d / n))
            if default is None:
                raise BusError(f"{d}: none of {', '.join(names)}")
            return default

        out = {}
        for axis in "xyz":
            out[f"in_anglvel_{axis}"] = (0.0, value(f"in_anglvel_{axis}_scale", "in_anglvel_scale"))
            out[f"in_accel_{axis}"] = (0.0, value(f"in_accel_{axis}_scale", "in_accel_scale"))
            out[f"in_magn_{axis}"] = (0.0, value(f"in_magn_{axis}_scale", "in_magn_scale") * UT_PER_GAUSS)
        out["in_temp0"] = (value("in_temp0_offset", "in_temp_offset", default=0.0),
                           value("in_temp0_scale", "in_temp_scale") / 1000.0)            # m°C -> °C
        out["in_voltage0_supply"] = (0.0, value("in_voltage0_supply_scale") / 1000.0)     # mV -> V
        return out

    # -- reading ------------------------------------------------------------------------------------------------

    def _read_available(self) -> bytes:
        chunks = [self._rest]
        want = MAX_RECORDS_PER_POLL * self.record_bytes
        while want > 0:
            try:
                data = os.read(self._fd, want)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EAGAIN or len(chunks) > 1:   # records read before a failure go first
                    break
                raise BusError(f"reading {self.node} failed: {exc}") from exc
            if not data:
                # end of stream: a character device never ends while its device exists; the FIFO stand-in
                # ends when its writer (the simulated kernel) goes, and has none yet before it first wrote.
                # Records read before the end are handed over first; the next call reports it.
                if self._streaming and len(chunks) == 1:
                    raise BusError(f"{self.node}: the device ended the stream")
                break
            self._streaming = True
            chunks.append(data)
            want -= len(data)
        buf = b"".join(chunks)
        whole = len(buf) - len(buf) % self.record_bytes
        self._rest = buf[whole:]
        return buf[:whole]

    def _prepare_words(self) -> None:
        """The 12 data channels decoded as one (n, 12) array: per-column shift, realbits mask, sign and the
        kernel's offset and scale (a block costs a few numpy calls, not a dozen per channel)."""
        types = {e.name: e.type for e in self.elements}
        offsets = {e.name: e.offset for e in self.elements}
        words = CHANNELS[:12]
        first = types[words[0]]
        self._word_view = None          # (byte offset, dtype): the words lie side by side in the record
        if all(types[w].dtype() == first.dtype() and types[w].repeat == 1 and
               offsets[w] == offsets[words[0]] + i * first.storagebits // 8 for i, w in enumerate(words)):
            self._word_view = (offsets[words[0]], first.dtype())
        self._shift = np.array([types[w].shift for w in words], dtype=np.int64)
        self._mask = np.array([(1 << types[w].realbits) - 1 for w in words], dtype=np.int64)
        self._half = np.array([1 << (types[w].realbits - 1) if types[w].signed else 0 for w in words], dtype=np.int64)
        sc = self._scale
        self._lsb_offset = np.array([sc[w][0] if w in sc else 0.0 for w in words])
        self._si_per_lsb = np.array([sc[w][1] if w in sc else 0.0 for w in words])   # aux ADC: not used
        self._full9 = np.array([R.gyro_range_lsb()] * 3 + [R.ACCEL_RANGE_LSB] * 3 + [R.MAG_RANGE_LSB] * 3)

    def decode(self, data: bytes) -> list[ImuSample]:
        """Whole scan records -> ImuSamples (gaps, flags and counts as the module doc says)."""
        return list(self.decode_block(data))

    def decode_block(self, data: bytes) -> SampleBlock:
        """Whole scan records -> the block of their samples, as columns (core.sample_block: no ImuSample built;
        the daemon calibrates the block's arrays at once). A record is a sample when it is not garbage (beyond any
        range the chip reports) and the chip's new-data bit is set (else the interrupt came without a new sample:
        `stale`), placed in the sequence by its stamp (`_sequence_flags`). The loop over the records touches only
        Python lists: a numpy scalar or call per record costs more than the record's own work."""
        rec = np.frombuffer(data, dtype=self._dtype)
        n = len(rec)
        if n == 0:
            return SampleBlock((), np.empty((0, 9)), (), (), (), (), ())
        ts_ns = self._stamp_type.values(rec["in_timestamp"]).tolist()
        block = self._convert(self._storage_words(data, rec))
        stats = self.stats
        stats["records"] += n
        garbage, new_data, status = block.garbage, block.new_data, block.status
        rows, t_s, flags, counter = [], [], [], []
        sequence_flags = self._sequence_flags
        for i in range(n):
            if garbage[i]:
                stats["garbage_frames"] += 1
                continue
            if not new_data[i]:
                stats["stale"] += 1       # the interrupt came but the chip had no new sample: not a sample
                continue
            f = sequence_flags(ts_ns[i])
            if f is None:
                continue
            st = status[i]
            if st & _ALARM:
                stats["ea_flags"] += 1
            if st & _SATURATED_ANY:
                stats["saturations"] += 1
            rows.append(i)
            t_s.append(self._last_ns * 1e-9)
            flags.append(f | st)
            counter.append(self._k)
        stats["samples"] += len(rows)
        si = block.si if len(rows) == n else block.si[rows]
        return SampleBlock(t_s, si[:, 1:10].copy(), si[:, 10].tolist(), si[:, 0].tolist(), flags, [0] * len(rows),
                           counter)

    def _storage_words(self, data: bytes, rec: np.ndarray) -> np.ndarray:
        """The 12 data channels' storage words of each record, (n, 12) int64: a strided view when they lie side by
        side (_prepare_words), else gathered by name."""
        if self._word_view is not None:
            off, dt = self._word_view
            storage = np.ndarray((len(rec), 12), dtype=dt, buffer=data, offset=off,
                                 strides=(self.record_bytes, dt.itemsize))
            return storage.astype(np.int64)
        return np.stack([rec[name].astype(np.int64) for name in CHANNELS[:12]], axis=1)

    def _convert(self, storage: np.ndarray) -> _Block:
        """Storage words -> SI values, the chip's flag bits and the range checks, for a whole block at once."""
        lsb = (storage >> self._shift) & self._mask
        lsb = (lsb ^ self._half) - self._half               # sign-extend the signed channels
        si = (lsb + self._lsb_offset) * self._si_per_lsb
        absraw = np.abs(lsb[:, 1:10])
        # each sensor (3 words) at or beyond its range: saturated, hence invalid
        saturated = (absraw >= self._full9).reshape(len(storage), 3, 3).any(axis=2)
        alarm = ((storage[:, 1:10] >> 14) & 1).any(axis=1)                # the chip's flag bits above realbits
        return _Block(si=si, new_data=((storage[:, 1:10] >> 15) & 1).all(axis=1).tolist(),
                      garbage=(absraw > 1.25 * self._full9).any(axis=1).tolist(),
                      status=(saturated @ _SATURATED_BITS + alarm * _ALARM).tolist())

    def _sequence_flags(self, t_ns: int) -> int | None:
        """The sample stamped t_ns placed in the sequence: NEW_DATA, GAP_BEFORE after lost samples (the index
        advanced by the periods elapsed); None for a stamp not after the last one."""
        stats = self.stats
        last = self._last_ns
        if last is not None and t_ns <= last:
            stats["timestamp_backwards"] += 1
            return None
        step = 1 if last is None else max(1, int(round((t_ns - last) / self._period_ns)))
        self._last_ns = t_ns
        flags = _NEW_DATA
        if step > 1 and self._k >= 0:
            flags |= _GAP_BEFORE
            stats["gaps"] += 1
            stats["lost_samples_host"] += step - 1
        self._k += step
        return flags

    def _open_buffer(self) -> None:
        try:
            _write(self.sysfs / "buffer" / "enable", "1")
            self._fd = os.open(self.node, os.O_RDONLY | os.O_NONBLOCK)
        except OSError as exc:
            raise BusError(f"cannot start the IIO buffer of {self.sysfs} ({self.node}): {exc}") from exc
        self._streaming = False
        self._rest = b""

    def poll(self) -> SampleBlock:
        """Every whole record waiting, decoded into a block of samples (decode_block: a sequence of ImuSamples, built
        when asked for). BusError while the device is gone (re-opened with backoff)."""
        if self._fd is None:
            if self._lost_reason:
                self._reopen()
            else:
                self._open_buffer()
        self._read_at = self._clock()
        try:
            data = self._read_available()
        except BusError as exc:
            self._vanished(exc)
            raise
        return self.decode_block(data)

    def readable_after(self, t: float) -> float:
        """When the chip's first sample at or after `t` (CLOCK_MONOTONIC s) is in the kernel's buffer: its data-ready
        edge, from the last time stamp and the period (`next_edge_s`), plus READ_AFTER_EDGE_S; `t` itself before
        the first record."""
        last_ns = self._last_ns
        if last_ns is None:
            return t
        return next_edge_s(t, last_ns * 1e-9, self._period_ns * 1e-9) + READ_AFTER_EDGE_S

    def wait(self, timeout_s: float, paced: bool = True) -> bool:
        """Block until records are waiting (True) or `timeout_s` passed (False); True also when `poll()` has
        something else to do (open the buffer, or a re-open attempt is due). paced: not before READ_EVERY_S after
        the last read (a reader that reads whenever records wait: a reader process's thread); False: at once (the
        daemon's reader thread waiting for the first record after an output's deadline, drivers.threaded_source)."""
        if self._fd is None:
            dt = self._next_attempt - self._clock() if self._lost_reason else 0.0
            if dt > 0:
                time.sleep(min(timeout_s, dt))
            return dt <= timeout_s
        if not self._streaming:
            time.sleep(min(timeout_s, NO_WRITER_POLL_S))
            return True
        early = self._read_at + READ_EVERY_S - self._clock() if paced else 0.0
        if early > 0:
            time.sleep(early)                 # the kernel buffers meanwhile: read a block, not a scan
        return bool(select.select([self._fd], [], [], timeout_s)[0])

    def _vanished(self, exc: Exception) -> None:
        self._close_fd()
        self.stats["device_lost"] += 1
        self._lost_reason = str(exc)
        self._backoff_s = BACKOFF_FIRST_S
        self._next_attempt = self._clock() + self._backoff_s
        log.warning("IIO device %s lost (%s); re-opening every %.1f-%.0f s", self.spec, exc, BACKOFF_FIRST_S,
                    BACKOFF_MAX_S)

    def _reopen(self) -> None:
        now = self._clock()
        if now < self._next_attempt:
            raise BusError(f"IIO device {self.spec} lost ({self._lost_reason}); re-opening")
        try:
            self.sysfs, self.node = resolve_device(self.spec)
            if not self.sysfs.is_dir():
                raise BusError(f"{self.sysfs} is not there")
            self.start()
            self._open_buffer()
        except BusError as exc:
            self.stats["reopen_failures"] += 1
            self._backoff_s = min(BACKOFF_MAX_S, 2.0 * self._backoff_s)
            self._next_attempt = now + self._backoff_s
            raise BusError(f"IIO device {self.spec} lost ({self._lost_reason}); re-opening") from exc
        self.stats["reopens"] += 1
        log.warning("IIO device %s back (%s) after %s", self.spec, self.sysfs.name, self._lost_reason)
        self._lost_reason = ""

    def counters(self) -> dict:
        return dict(self.stats)

    def _close_fd(self) -> None:
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None

    def close(self) -> None:
        if self._fd is not None:
            self._close_fd()
            try:
                _write(self.sysfs / "buffer" / "enable", "0")
            except OSError as exc:
                log.debug("disabling the IIO buffer failed: %s", exc)
