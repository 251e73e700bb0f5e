"""ADIS16405 driver over any SpiBus: registers, burst read, flags, DIAG_STAT, self-test, configuration.

Output: `ImuSample` in SI units in the sensor frame (the daemon applies the mounting rotation).
Nothing untrustworthy leaves `read_sample()`: a frame that fails the checks is counted in `counters`
and raised as a `FrameError`; a sample that is usable but suspect carries `SampleFlags`.

Protocol facts: Linux `drivers/iio/imu/adis16400.c` / `adis.c`, the ADIS16405 datasheet (Analog Devices, Rev. B)
and ADI EngineerZone thread 81805 (see `registers.py`).
"""

from __future__ import annotations

import functools
import logging
import math
import struct
from operator import ge as _ge, gt as _gt, mul as _mul
from collections.abc import Callable, Iterable

import numpy as np

from . import registers as R
from .errors import BusError, ConfigError, DriverError, FrameError, ProductIdMismatch, SelfTestFailed, ShortRead
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.sample_block import sample_flags
from .sample_record import SampleRecord
from .spi import SpiBus

log = logging.getLogger(__name__)

_BURST_TX = R.BURST_COMMAND + bytes(R.BURST_DATA_BYTES)
_BURST_LEN = len(_BURST_TX)
_UNPACK_BURST = struct.Struct(">12H").unpack_from
_FLAG_BITS = R.ND | R.EA
# SampleFlags as plain ints on the hot path (one enum construction per sample)
_NEW_DATA, _STALE, _ALARM, _GAP_BEFORE = (int(SampleFlags.NEW_DATA), int(SampleFlags.STALE), int(SampleFlags.ALARM),
                                          int(SampleFlags.GAP_BEFORE))
_GYRO_INVALID, _ACCEL_INVALID, _MAG_INVALID = (int(SampleFlags.GYRO_INVALID), int(SampleFlags.ACCEL_INVALID),
                                               int(SampleFlags.MAG_INVALID))
_GYRO_SAT = int(SampleFlags.GYRO_SATURATED | SampleFlags.GYRO_INVALID)
_ACCEL_SAT = int(SampleFlags.ACCEL_SATURATED | SampleFlags.ACCEL_INVALID)
_MAG_SAT = int(SampleFlags.MAG_SATURATED | SampleFlags.MAG_INVALID)
_ANY_SAT = int(SampleFlags.GYRO_SATURATED | SampleFlags.ACCEL_SATURATED | SampleFlags.MAG_SATURATED)
_BURST_BUG_RECOVERED = int(SampleFlags.BURST_BUG_RECOVERED)

# Plausibility of a burst frame (beyond these the frame is garbage, not a measurement).
SUPPLY_PLAUSIBLE_V = (3.0, 6.0)      # the chip stops working outside this; 4.75..5.25 V is nominal
PLAUSIBLE_RANGE_FACTOR = 1.25        # |value| > 1.25 × full scale cannot come from a working sensor
BURST_BUG_JUMP_DPS = 100.0           # an X-gyro step bigger than this between samples triggers a check read
STUCK_WINDOW_S = 0.5                 # an axis frozen this long while its siblings move is "stuck"

_SUPPLY_MIN_LSB = int(SUPPLY_PLAUSIBLE_V[0] / R.SUPPLY_V_PER_LSB)
_SUPPLY_MAX_LSB = int(SUPPLY_PLAUSIBLE_V[1] / R.SUPPLY_V_PER_LSB)
# the supply does not move 0.24 V from one sample to the next: a register read after a burst whose SUPPLY_OUT
# does (with ND set) is a corrupt frame, not the next sample (Adis16405.take_newer_sample)
_SUPPLY_STEP_MAX_LSB = 100

COUNTER_NAMES = (
    "samples",               # samples returned (any flags)
    "new_samples",           # ... of which carried fresh data (ND)
    "stale",                 # ND clear: no new data since the last read (sample repeated, flagged STALE)
    "ea_flags",              # frames with EA set (DIAG_STAT read and decoded)
    "burst_bug_recovered",   # X-gyro bit-13 burst bug fixed from a register read
    "burst_bug_unverified",  # suspected burst bug the register read could not confirm (gyro flagged invalid)
    "nd_taken_by_check",     # ... the register read found a newer sample and took its ND (read at the next burst)
    "index_checks",          # register reads after a burst that may have straddled a data-ready (take_newer_sample)
    "nd_taken_by_index_check",  # ... that found a newer sample ready (the burst's was the one before)
    "garbage_frames",        # frames rejected: inconsistent ND/EA, implausible supply or values
    "short_reads",           # the bus returned fewer bytes than clocked
    "bus_errors",            # the bus raised (device gone, ioctl failure)
    "saturations",           # samples with at least one axis at full scale
    "stuck_axis",            # onsets of an axis frozen while its siblings move
    "self_test_failures",    # failed self-test attempts
)


class Adis16405:
    """The ADIS16405 on an `SpiBus`.

    Read alone, every fresh sample is one sample period after the previous one and t_s starts at 0; read
    through drivers.chip_source.ChipSource (the daemon, `record`, `calibrate --live`), the host-clock
    SampleTimer stamps and indexes them and counts the samples lost between reads.
    sleep: how to wait for the chip (reset, self-test). Default: the bus's `sleep` (the host's time on a real
        bus; the simulated chip's own, virtual time).
    samples_as_records: read_sample returns a drivers.sample_record.SampleRecord instead of an ImuSample (the
        same numbers): the reader process (drivers.process_source) only packs the samples for the pipe, and asks
        the driver it opens for records (drivers.source.open_source(samples_as_records=True)).
    """

    def __init__(self, bus: SpiBus, *, sleep: Callable[[float], None] | None = None,
                 stuck_window_s: float = STUCK_WINDOW_S, data_ready: bool = False, samples_as_records: bool = False):
        self.bus = bus
        self.data_ready = data_ready      # start() routes data-ready to DIO1 (reads paced by drivers.data_ready)
        self.samples_as_records = samples_as_records
        self._sleep = sleep or bus.sleep
        self._stuck_window_s = stuck_window_s
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)
        self.product_id: int | None = None
        self.last_diag_stat = 0
        # configuration as read back from the chip (defaults until start())
        self.smpl_prd = R.SMPL_PRD_DEFAULT
        self.sens_avg = R.SENS_AVG_DEFAULT
        self._apply_config(self.smpl_prd, self.sens_avg)
        self._reset_stream_state()
        # read_burst(): one burst transfer, the frame's bytes undecoded (drivers.chip_source's common read decodes
        # the clean fresh frame itself and hands any other to `decode_burst`); a partial, not a method: a Python
        # frame less a read after each wake's cold caches (docs/daemon.md "Performance")
        self.read_burst: Callable[[], bytes] = functools.partial(self._xfer, _BURST_TX, R.SPI_BURST_HZ, 0)

    # ---------------------------------------------------------------------------------- configuration
    @property
    def sample_rate_hz(self) -> float:
        return self._rate_hz

    @property
    def sample_period_s(self) -> float:
        return self._period_s

    @property
    def filter_n(self) -> int:
        return R.decode_sens_avg(self.sens_avg)[1]

    @property
    def gyro_range_dps(self) -> int:
        return R.decode_sens_avg(self.sens_avg)[0]

    @property
    def spi_speed_hz(self) -> int:
        """Clock used for register access (burst reads always use 1 MHz)."""
        return self._reg_speed_hz

    def _apply_config(self, smpl_prd: int, sens_avg: int) -> None:
        self.smpl_prd, self.sens_avg = smpl_prd, sens_avg
        self._rate_hz = R.sample_rate_hz(smpl_prd)
        self._period_s = 1.0 / self._rate_hz
        self._reg_speed_hz = R.spi_speed_hz(smpl_prd)
        range_dps, _ = R.decode_sens_avg(sens_avg)
        gyro_rad_per_lsb = math.radians(R.GYRO_DPS_PER_LSB[range_dps])
        self._scale9 = np.array([gyro_rad_per_lsb] * 3 + [R.ACCEL_M_S2_PER_LSB] * 3 + [R.MAG_UT_PER_LSB] * 3)
        self._scale9_list = self._scale9.tolist()
        self._gyro_range_lsb = R.gyro_range_lsb(range_dps)
        self._full_scale9 = (self._gyro_range_lsb,) * 3 + (R.ACCEL_RANGE_LSB,) * 3 + (R.MAG_RANGE_LSB,) * 3
        self._plausible9 = tuple(int(PLAUSIBLE_RANGE_FACTOR * fs) for fs in self._full_scale9)
        self._jump_lsb = int(BURST_BUG_JUMP_DPS / R.GYRO_DPS_PER_LSB[range_dps])
        self._stuck_window = max(8, int(round(self._stuck_window_s * self._rate_hz)))

    def _reset_stream_state(self) -> None:
        self._counter = -1                 # index of the last fresh sample
        self._last: ImuSample | SampleRecord | None = None
        self._prev_gx: int | None = None
        self._prev_raw9 = [None] * 9
        self._runs = [0] * 9
        self._stuck = [False] * 9
        self._any_stuck = False
        # the register reads after the last burst took the ND of a newer sample (`_check_burst_bug`,
        # `take_newer_sample`): the sample just returned was not the newest when the read ended, and the next burst
        # returns the newer one as new (read by drivers.chip_source at every fresh read: a plain attribute)
        self.newer_sample_taken = False
        self._burst_supply_lsb = -1        # the last burst's SUPPLY_OUT (a stale register read returns the same)

    # ---------------------------------------------------------------------------------- bus primitives
    def _xfer(self, tx: bytes, speed_hz: int, delay_us: int = R.STALL_US) -> bytes:
        try:
            rx = self.bus.transfer(tx, speed_hz, delay_us)
        except BusError:
            self.counters["bus_errors"] += 1
            raise
        except OSError as exc:   # spidev/ioctl or a device that went away
            self.counters["bus_errors"] += 1
            raise BusError(f"SPI transfer failed: {exc}") from exc
        if len(rx) != len(tx):
            self.counters["short_reads"] += 1
            raise ShortRead(f"SPI transfer returned {len(rx)} of {len(tx)} bytes", rx)
        return rx

    def read_registers(self, addrs: Iterable[int]) -> list[int]:
        """Pipelined 16-bit register reads: each frame carries the next address and the previous data."""
        addrs = list(addrs)
        speed = self._reg_speed_hz
        out = []
        self._xfer(R.read_frame(addrs[0]), speed)
        for nxt in addrs[1:] + [R.FLASH_CNT]:   # the last frame requests a harmless register
            rx = self._xfer(R.read_frame(nxt), speed)
            out.append((rx[0] << 8) | rx[1])
        return out

    def read_register(self, addr: int) -> int:
        return self.read_registers([addr])[0]

    def write_byte(self, byte_addr: int, value: int) -> None:
        self._xfer(bytes((R.WRITE_BIT | (byte_addr & 0x7F), value & 0xFF)), self._reg_speed_hz)

    def write_register(self, addr: int, value: int) -> None:
        """16-bit write as two byte writes (upper byte first, kernel adis.c adis_write_reg_16)."""
        for frame in R.write_frames(addr, value):
            self._xfer(frame, self._reg_speed_hz)

    def read_diag_stat(self) -> tuple[int, list[str]]:
        """Read (and so clear) DIAG_STAT; returns the raw value and the names of the set bits."""
        diag = self.read_register(R.DIAG_STAT)
        self.last_diag_stat = diag
        return diag, R.diag_faults(diag)

    # ---------------------------------------------------------------------------------- commands
    def check_product_id(self) -> int:
        pid = self.read_register(R.PRODUCT_ID)
        self.product_id = pid
        if pid != R.PRODUCT_ID_ADIS16405:
            raise ProductIdMismatch(pid, R.PRODUCT_ID_ADIS16405)
        return pid

    def software_reset(self) -> None:
        """GLOB_CMD bit 7; the chip reloads its flash settings (170 ms, kernel reset timeout)."""
        self.write_byte(R.GLOB_CMD, R.GlobCmd.SOFTWARE_RESET)
        self._sleep(R.RESET_TIME_S)
        self._read_config()

    def factory_restore(self) -> None:
        """GLOB_CMD bit 1: restore the factory calibration (clears the user offset registers)."""
        self.write_byte(R.GLOB_CMD, R.GlobCmd.FACTORY_CAL_RESTORE)
        self._sleep(R.FACTORY_RESTORE_TIME_S)

    def auto_null(self, precision: bool = False) -> None:
        """Gyro bias auto-null (GLOB_CMD bit 0) or precision auto-null (bit 4, ~30 s). Keep the unit still."""
        cmd = R.GlobCmd.PRECISION_AUTO_NULL if precision else R.GlobCmd.AUTO_NULL
        self.write_byte(R.GLOB_CMD, cmd)
        self._sleep(R.PRECISION_AUTO_NULL_TIME_S if precision else R.AUTO_NULL_TIME_S)

    def flash_update(self) -> None:
        """GLOB_CMD bit 3: store the current settings and offsets in flash (survives reset/power cycle)."""
        self.write_byte(R.GLOB_CMD, R.GlobCmd.FLASH_UPDATE)
        self._sleep(0.05)

    def enable_data_ready(self) -> None:
        """Data-ready on DIO1, active high: MSC_CTRL bit 2 DATA_RDY_EN, bit 1 DATA_RDY_POL_HIGH, bit 0 clear
        (DIO1, not DIO2) — kernel adis16400.c ADIS16400_MSC_CTRL_DATA_RDY_*; the other bits are kept (bit 10,
        the self-clearing self-test, is never written). All three are in the low byte: one byte write, then
        read back."""
        msc = self.read_register(R.MSC_CTRL)
        want = (msc | R.MscCtrl.DATA_RDY_EN | R.MscCtrl.DATA_RDY_POL_HIGH) & ~R.MscCtrl.DATA_RDY_DIO2
        self.write_byte(R.MSC_CTRL, int(want) & 0xFF)
        back = self.read_register(R.MSC_CTRL)
        if back & 0x07 != int(want) & 0x07:
            raise DriverError(f"MSC_CTRL data-ready write did not take: wrote {int(want) & 0xFF:#04x}, "
                              f"read {back:#06x}")

    def gyro_offsets_dps(self) -> np.ndarray:
        raw = self.read_registers([R.XGYRO_OFF, R.YGYRO_OFF, R.ZGYRO_OFF])
        return np.array([R.decode_signed12(w) * R.GYRO_OFF_DPS_PER_LSB for w in raw])

    def self_test(self, retry_after_reset: bool = True) -> None:
        """Internal self-test (MSC_CTRL bit 10, self-clearing), then DIAG_STAT must show no failure.

        Like the kernel (adis_self_test), a failure is retried once after a software reset.
        Raises SelfTestFailed with the named DIAG_STAT bits.
        """
        attempts = 2 if retry_after_reset else 1
        for attempt in range(attempts):
            self.read_diag_stat()                       # clear stale latched bits
            msc = self.read_register(R.MSC_CTRL)
            self.write_byte(R.MSC_CTRL + 1, ((msc | R.MscCtrl.INT_SELF_TEST) >> 8) & 0xFF)
            self._sleep(R.SELF_TEST_TIME_S)
            for _ in range(20):                         # poll until the bit clears (up to ~10× the 12 ms)
                if not self.read_register(R.MSC_CTRL) & R.MscCtrl.INT_SELF_TEST:
                    break
                self._sleep(R.SELF_TEST_TIME_S / 2)
            else:
                self.counters["self_test_failures"] += 1
                raise SelfTestFailed(0, [], "self-test did not complete: MSC_CTRL bit 10 never cleared")
            diag, faults = self.read_diag_stat()
            failed = diag & (R.DiagStat.SELF_TEST_FAILED | R.DIAG_GYRO_SELF_TEST | R.DIAG_ACCEL_SELF_TEST)
            if not failed:
                if diag:
                    log.warning("DIAG_STAT after self-test: %s", ", ".join(faults))
                return
            self.counters["self_test_failures"] += 1
            log.warning("self-test attempt %d failed: %s", attempt + 1, ", ".join(faults))
            if attempt + 1 < attempts:
                self.software_reset()
        raise SelfTestFailed(diag, faults)

    def configure(self, *, smpl_prd: int | None = None, sample_rate_hz: float | None = None,
                  filter_n: int | None = None, gyro_range_dps: int | None = None) -> None:
        """Write SMPL_PRD / SENS_AVG (only what is given), read both back and verify."""
        if smpl_prd is not None and sample_rate_hz is not None:
            raise ConfigError("give smpl_prd or sample_rate_hz, not both")
        if sample_rate_hz is not None:
            if not 0.0 < sample_rate_hz <= R.TIME_BASE_FAST_HZ:
                raise ConfigError(f"sample rate must be in (0, {R.TIME_BASE_FAST_HZ}] Hz, not {sample_rate_hz}")
            smpl_prd = R.smpl_prd_for_rate(sample_rate_hz)
        if smpl_prd is not None:
            if not 0 <= smpl_prd <= 0xFF:
                raise ConfigError(f"SMPL_PRD must be 0x00..0xFF, not {smpl_prd:#x}")
            self.write_byte(R.SMPL_PRD, smpl_prd)
            self._reg_speed_hz = R.SPI_SLOW_HZ    # until read back: the slow clock is always safe
        if filter_n is not None or gyro_range_dps is not None:
            cur_range, cur_n = R.decode_sens_avg(self.read_register(R.SENS_AVG))
            try:
                value = R.encode_sens_avg(gyro_range_dps if gyro_range_dps is not None else cur_range,
                                          filter_n if filter_n is not None else cur_n)
            except ValueError as exc:
                raise ConfigError(str(exc)) from exc
            self.write_register(R.SENS_AVG, value)
        want = (smpl_prd, None if filter_n is None and gyro_range_dps is None else value)
        self._read_config()
        if want[0] is not None and self.smpl_prd != want[0]:
            raise DriverError(f"SMPL_PRD write did not take: wrote {want[0]:#04x}, read {self.smpl_prd:#04x}")
        if want[1] is not None and (self.sens_avg & 0x0707) != want[1]:
            raise DriverError(f"SENS_AVG write did not take: wrote {want[1]:#06x}, read {self.sens_avg:#06x}")

    def _read_config(self) -> None:
        saved = self._reg_speed_hz
        self._reg_speed_hz = R.SPI_SLOW_HZ
        try:
            smpl_prd, sens_avg = self.read_registers([R.SMPL_PRD, R.SENS_AVG])
        finally:
            self._reg_speed_hz = saved
        self._apply_config(smpl_prd & 0xFF, sens_avg)

    def start(self, *, self_test: bool = True, reset: bool = False, smpl_prd: int | None = None,
              sample_rate_hz: float | None = None, filter_n: int | None = None,
              gyro_range_dps: int | None = None) -> None:
        """Probe PRODUCT_ID (slow clock), optionally reset and self-test, configure, start the sample clock."""
        self._reg_speed_hz = R.SPI_SLOW_HZ
        if reset:
            self.software_reset()
        self.check_product_id()
        if self_test:
            self.self_test()
        self._read_config()
        if any(v is not None for v in (smpl_prd, sample_rate_hz, filter_n, gyro_range_dps)):
            self.configure(smpl_prd=smpl_prd, sample_rate_hz=sample_rate_hz, filter_n=filter_n,
                           gyro_range_dps=gyro_range_dps)
        if self.data_ready:
            self.enable_data_ready()
        self.read_diag_stat()
        self._reset_stream_state()
        log.info("ADIS16405 started: %.3f SPS, SENS_AVG N=%d, ±%d °/s, SPI %d Hz",
                 self._rate_hz, self.filter_n, self.gyro_range_dps, self._reg_speed_hz)

    def close(self) -> None:
        self.bus.close()

    # ---------------------------------------------------------------------------------- sampling
    def _reject(self, reason: str, raw: bytes) -> FrameError:
        self.counters["garbage_frames"] += 1
        return FrameError(f"burst frame rejected: {reason}", raw)

    def read_sample(self, stamp: Callable[[int], tuple[float, int, int]] | None = None) -> ImuSample | SampleRecord:
        """One burst read -> ImuSample (SI, sensor frame; a SampleRecord with `samples_as_records`).

        stamp: `stamp(flags) -> (t_s, counter, extra_flags)`, called once the frame's flags are known, gives
            the sample its time stamp and index (drivers.chip_source: the host-clock SampleTimer). Without it
            the driver's own counter is used (see `_advance_counter`).
        Raises FrameError (counted) for frames that cannot be trusted, BusError when the bus fails.
        """
        return self.decode_burst(self._xfer(_BURST_TX, R.SPI_BURST_HZ, 0), stamp)

    def decode_burst(self, rx: bytes, stamp: Callable[[int], tuple[float, int, int]] | None = None
                     ) -> ImuSample | SampleRecord:
        """`read_sample` of the burst frame `rx` (read by `read_burst`): every check, the flags, the sample."""
        w0, w1, w2, w3, w4, w5, w6, w7, w8, w9, w10, _ = _UNPACK_BURST(rx, 2)
        # ND/EA must agree across SUPPLY_OUT and the nine sensor words (TEMP_OUT/AUX_ADC are not checked:
        # their flag bits are not relied on, so a hardware difference there cannot reject every frame)
        both = w0 & w1 & w2 & w3 & w4 & w5 & w6 & w7 & w8 & w9 & _FLAG_BITS
        if (w0 | w1 | w2 | w3 | w4 | w5 | w6 | w7 | w8 | w9) & _FLAG_BITS != both:
            raise self._reject("ND/EA bits differ between words", rx)
        supply = w0 & 0x3FFF
        if not _SUPPLY_MIN_LSB <= supply <= _SUPPLY_MAX_LSB:
            raise self._reject(f"implausible supply {supply * R.SUPPLY_V_PER_LSB:.2f} V", rx)
        self._burst_supply_lsb = supply
        raw9 = [((x & 0x3FFF) ^ 0x2000) - 0x2000 for x in (w1, w2, w3, w4, w5, w6, w7, w8, w9)]
        # ND clear but the previous read's XGYRO_OUT check took the ND of the sample that became ready after
        # its burst: these registers hold that sample, new to us
        new_data = bool(both & R.ND) or self.newer_sample_taken
        self.newer_sample_taken = False
        flags = 0
        # X-gyro burst bug (EZ 81805): a negative X rate comes back with bit 13 cleared, i.e. +8192 LSB
        gx, prev_gx = raw9[0], self._prev_gx
        if (not (w1 & 0x2000)) and (gx > self._gyro_range_lsb or
                                    (gx - prev_gx > self._jump_lsb if prev_gx is not None else gx > self._jump_lsb)):
            raw9[0], flags = self._burst_bug_fixed(w1, gx, new_data)
        # the nine magnitudes once, compared in C (map): per-axis Python only for a frame that fails a bound
        abs9 = list(map(abs, raw9))
        if any(map(_gt, abs9, self._plausible9)):
            i = next(i for i in range(9) if abs9[i] > self._plausible9[i])
            raise self._reject(f"axis {i} value {raw9[i]} LSB beyond any plausible reading", rx)
        diag = 0
        if both & R.EA:
            diag, flags = self._alarm_flags(flags)
        if any(map(_ge, abs9, self._full_scale9)):
            flags |= self._saturation_flags(raw9)
        flags |= self._fresh_flags(raw9, stamp is None) if new_data else self._stale_flags()
        if stamp is None:
            t_s, counter = self._counter * self._period_s, self._counter
        else:
            t_s, counter, extra = stamp(flags)
            flags |= extra
        return self._sample(t_s, counter, raw9, w10, supply, flags, diag)

    def _burst_bug_fixed(self, w1: int, gx: int, new_data: bool) -> tuple[int, int]:
        """The X-gyro value of a frame that looks hit by the burst bug, and its flags: a new sample is checked with
        a register read (`_check_burst_bug`); a repeat of the sample checked when it was new takes that value
        without a register read, which would only take the ND of a sample that became ready since (and lose it)."""
        if new_data or self._prev_gx is None:
            return self._check_burst_bug(w1, gx, 0)
        return self._prev_gx, 0

    def _alarm_flags(self, flags: int) -> tuple[int, int]:
        """EA set: read and decode DIAG_STAT (each fault counted); a failed self-test invalidates its sensor.
        Returns (DIAG_STAT, flags with ALARM and those)."""
        self.counters["ea_flags"] += 1
        flags |= _ALARM
        diag, faults = self.read_diag_stat()
        for name in faults:
            key = "diag_" + name.lower()
            self.counters[key] = self.counters.get(key, 0) + 1
        if diag & R.DIAG_GYRO_SELF_TEST:
            flags |= _GYRO_INVALID
        if diag & R.DIAG_ACCEL_SELF_TEST:
            flags |= _ACCEL_INVALID
        return diag, flags

    def _saturation_flags(self, raw9: list[int]) -> int:
        """A sensor with an axis at full scale is saturated (its values are invalid); counted per sample."""
        flags = 0
        full = self._full_scale9
        if (abs(raw9[0]) >= full[0] or abs(raw9[1]) >= full[1] or abs(raw9[2]) >= full[2]):
            flags |= _GYRO_SAT
        if (abs(raw9[3]) >= full[3] or abs(raw9[4]) >= full[4] or abs(raw9[5]) >= full[5]):
            flags |= _ACCEL_SAT
        if (abs(raw9[6]) >= full[6] or abs(raw9[7]) >= full[7] or abs(raw9[8]) >= full[8]):
            flags |= _MAG_SAT
        if flags:
            self.counters["saturations"] += 1
        return flags

    def _fresh_flags(self, raw9: list[int], own_counter: bool) -> int:
        """A new sample (ND): counted, indexed by the driver's own counter when no `stamp` does it, its X-gyro
        kept for the next burst-bug check, its axes checked for a stuck one."""
        flags = _NEW_DATA
        self.counters["new_samples"] += 1
        if own_counter:
            flags |= self._advance_counter()
        self._prev_gx = raw9[0]
        return flags | self._check_stuck(raw9)

    def _stale_flags(self) -> int:
        """No new data since the last read: the sample repeated, flagged STALE (and stuck as the last one was)."""
        self.counters["stale"] += 1
        if self._counter < 0:
            self._counter = 0
        return _STALE | self._stuck_flags()

    def _sample(self, t_s: float, counter: int, raw9: list[int], w_temp: int, supply: int, flags: int,
                diag: int) -> ImuSample | SampleRecord:
        """The ImuSample (or SampleRecord) of a checked frame, in SI units; counted and kept as the last one."""
        temp_c = R.TEMP_C_AT_ZERO + R.TEMP_C_PER_LSB * (((w_temp & 0x0FFF) ^ 0x0800) - 0x0800)
        if self.samples_as_records:
            # the same products as the array's below (an int times a float64, rounded once)
            sample = SampleRecord((t_s, *map(_mul, raw9, self._scale9_list), temp_c, supply * R.SUPPLY_V_PER_LSB,
                                   flags, diag, counter))
        else:
            values = np.array(raw9, dtype=np.float64)
            values *= self._scale9
            sample = ImuSample(t_s, values[0:3], values[3:6], values[6:9], temp_c, supply * R.SUPPLY_V_PER_LSB,
                               sample_flags(flags), diag, counter)
        self.counters["samples"] += 1
        self._last = sample
        return sample

    def take_newer_sample(self) -> bool:
        """Is a sample newer than the last burst's ready? One output register read (SUPPLY_OUT): its ND says so,
        and reading it clears ND, so the next burst returns that sample as new (`newer_sample_taken`). For the
        host-clock sample timer, when a burst may have straddled a data-ready (drivers.chip_source). Raises FrameError
        (counted, as for a burst) when the answer cannot be trusted: a short frame, ND clear with another supply
        word than the burst's (the same sample's registers), or ND set with a supply step no supply makes."""
        self.counters["index_checks"] += 1
        reg = self.read_register(R.SUPPLY_OUT)
        supply = reg & 0x3FFF
        if reg & R.ND:
            if abs(supply - self._burst_supply_lsb) > _SUPPLY_STEP_MAX_LSB:
                raise self._reject("register read after the burst: supply step beyond any supply's",
                                   reg.to_bytes(2, "big"))
            self.newer_sample_taken = True
            self.counters["nd_taken_by_index_check"] += 1
            return True
        if supply != self._burst_supply_lsb:
            raise self._reject("register read after the burst: another sample's supply without ND",
                               reg.to_bytes(2, "big"))
        return False

    def _advance_counter(self) -> int:
        """Index the fresh sample without a host clock: one period after the previous one (no gaps can be seen;
        drivers.chip_source times and indexes samples from the host clock)."""
        self._counter += 1
        return 0

    def _check_burst_bug(self, w1: int, gx: int, flags: int) -> tuple[int, int]:
        """Confirm a suspicious burst X-gyro value with a register read of XGYRO_OUT. Reading an output
        register clears ND: when the word comes back with ND set, a new sample became ready after the burst and
        this read took its ND, so the next burst is new data although its ND is clear (`newer_sample_taken`)."""
        reg = self.read_register(R.XGYRO_OUT)
        if reg & R.ND:
            self.newer_sample_taken = True
            self.counters["nd_taken_by_check"] += 1
        reg_lsb = R.decode_signed14(reg)
        if reg_lsb == gx:
            return gx, flags                                  # genuine
        if (reg & 0x3FFF) == ((w1 & 0x3FFF) | 0x2000):
            self.counters["burst_bug_recovered"] += 1
            return reg_lsb, flags | _BURST_BUG_RECOVERED
        # the register moved on (new sample) or disagrees otherwise: the burst value cannot be trusted
        self.counters["burst_bug_unverified"] += 1
        fixed = R.decode_signed14(w1 | 0x2000)
        return fixed, flags | _GYRO_INVALID

    def _check_stuck(self, raw9: list[int]) -> int:
        """Flag an axis frozen for the stuck window while another axis of the same sensor moves.

        A sensor whose three axes are all constant (an ideal simulation, a unit at rest with heavy averaging)
        is not called stuck: only the disagreement between sibling axes is evidence of a fault.
        """
        prev, runs = self._prev_raw9, self._runs
        for i in range(9):
            if raw9[i] == prev[i]:
                runs[i] += 1
            else:
                runs[i] = 0
                prev[i] = raw9[i]
        window = self._stuck_window
        if max(runs) < window:
            if self._any_stuck:
                self._stuck = [False] * 9
                self._any_stuck = False
            return 0
        stuck = self._stuck
        for s in (0, 3, 6):
            r0, r1, r2 = runs[s], runs[s + 1], runs[s + 2]
            if r0 < window and r1 < window and r2 < window:
                stuck[s] = stuck[s + 1] = stuck[s + 2] = False
                continue
            moving = r0 < window or r1 < window or r2 < window
            for i, r in ((s, r0), (s + 1, r1), (s + 2, r2)):
                frozen = moving and r >= window
                if frozen and not stuck[i]:
                    self.counters["stuck_axis"] += 1
                    log.warning("axis %d stuck at %d LSB for %d samples", i, raw9[i], r)
                stuck[i] = frozen
        self._any_stuck = any(stuck)
        return self._stuck_flags() if self._any_stuck else 0

    def _stuck_flags(self) -> int:
        st = self._stuck
        flags = 0
        if st[0] or st[1] or st[2]:
            flags |= _GYRO_INVALID
        if st[3] or st[4] or st[5]:
            flags |= _ACCEL_INVALID
        if st[6] or st[7] or st[8]:
            flags |= _MAG_INVALID
        return flags
