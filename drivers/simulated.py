"""A byte-level simulation of the ADIS16405 behind the SpiBus protocol.

The driver cannot tell it from the real part: it answers 16-bit frames with the pipelined register
protocol (the data for a request arrives in the next frame), takes byte writes, answers `0x3E00` with a
burst, sets ND/EA, latches DIAG_STAT, runs the self-test (MSC_CTRL bit 10 self-clears after 12 ms of chip
time), changes rate with SMPL_PRD, filters with the SENS_AVG Bartlett window, quantises to 14 bits and
saturates at ±300 °/s (or the selected range), ±18 g, ±2.5 gauss. Values come from
`ahrsd.simulation.open_stream` (truth trajectory + sensor errors), pulled and encoded a block at a time with
numpy so the per-read cost stays small.

Time: with `clock=None` every burst read returns the next sample (free-running), and chip time is virtual:
each transfer advances it by its duration on the wire and `sleep(s)` advances it without waiting. With a
`clock` the chip produces samples at the configured rate on that clock; samples nobody reads are lost.

Faults: a `FaultPlan` (drivers.faults) injects alarms, self-test failure, stuck or saturated axes, garbage,
the X-gyro burst bug, a vanished device, short reads and data-ready stalls.
"""

from __future__ import annotations

import errno
import logging
import math
import struct
from collections.abc import Callable
from datetime import timedelta

import numpy as np

from . import registers as R
from .faults import FaultKind, FaultPlan
from .sim_block_stream import BlockStream, ChipBlock, InProcessStream, SimulationStream
from .sim_clock import ChipClock, chip_clock

log = logging.getLogger(__name__)

BLOCK_SAMPLES = 256                  # a block on a clock: computed ahead while the reader waits (sim_block_stream)
# A free-running chip (clock=None: `ahrsd record --seconds`, tests) on a named scenario pulls its blocks when it
# runs out: larger blocks share each block's fixed cost (the trajectory's attitude, the encoding) over more samples.
# The simulation's samples do not depend on the block length (its random processes and the Bartlett filter's
# history run on across blocks), so the chip's bytes are the same as with BLOCK_SAMPLES. A stream object or
# factory given by the caller keeps BLOCK_SAMPLES: its values may change, or its noise be drawn, per block.
FREE_RUNNING_BLOCK_SAMPLES = 2048
SUPPLY_V = 5.0
_PACK12 = struct.Struct(">12H").pack
_ZERO2 = b"\x00\x00"
_OUTPUT_INDEX = {addr: i for i, addr in enumerate(R.OUTPUT_REGISTERS)}
_READ_ONLY = set(R.OUTPUT_REGISTERS) | {R.DIAG_STAT, R.PRODUCT_ID, R.FLASH_CNT}
_OFFSET_REGS = (R.XGYRO_OFF, R.YGYRO_OFF, R.ZGYRO_OFF, R.XACCL_OFF, R.YACCL_OFF, R.ZACCL_OFF)
_FLASH_REGS = _OFFSET_REGS + (R.XMAGN_HIF, R.YMAGN_HIF, R.ZMAGN_HIF, R.XMAGN_SIF, R.YMAGN_SIF, R.ZMAGN_SIF,
                              R.GPIO_CTRL, R.MSC_CTRL, R.SMPL_PRD, R.SENS_AVG, R.ALM_MAG1, R.ALM_MAG2,
                              R.ALM_SMPL1, R.ALM_SMPL2, R.ALM_CTRL, R.AUX_DAC)
_MAX_FILTER_HISTORY = 2 * (1 << 7) - 2   # Bartlett N = 7: two 128-tap boxes
# MSC_CTRL's data-ready routing as plain ints: a data-ready line checks it at every edge wait, and IntFlag
# arithmetic builds new enum members on each call
_DIO1_ROUTED = int(R.MscCtrl.DATA_RDY_EN | R.MscCtrl.DATA_RDY_POL_HIGH)
_DIO1_ROUTE_BITS = _DIO1_ROUTED | int(R.MscCtrl.DATA_RDY_DIO2)


def _default_registers() -> list[int]:
    regs = [0] * 64
    regs[R.PRODUCT_ID >> 1] = R.PRODUCT_ID_ADIS16405
    regs[R.SMPL_PRD >> 1] = R.SMPL_PRD_DEFAULT
    regs[R.SENS_AVG >> 1] = R.SENS_AVG_DEFAULT
    regs[R.MSC_CTRL >> 1] = R.MSC_CTRL_DEFAULT
    for reg in (R.XMAGN_SIF, R.YMAGN_SIF, R.ZMAGN_SIF):
        regs[reg >> 1] = 0x0800       # unity soft-iron scale (stored, not applied by the simulation)
    return regs


class SimulatedAdis16405:
    """An ADIS16405 on a simulated SPI bus (implements `SpiBus`).

    scenario: a scenario name for `ahrsd.simulation.open_stream`, a ready stream object (a
        `drivers.sim_block_stream.SimulationStream`), or a factory `f(rate_hz, start_s) -> stream` (used again
        when SMPL_PRD changes the rate).
    clock: None (free-running, virtual time) or a monotonic clock in seconds: a `drivers.sim_clock.ChipClock`
        (a test's stepped clock, whose `sleep` `sleep()` uses) or a plain function (`time.monotonic`: real
        sleeps).
    faults: a FaultPlan to inject faults (an empty one is created otherwise: `chip.faults.add(...)`).
    product_id: what PRODUCT_ID reads (0x4015; 0x4010 simulates an ADIS16400).
    producer: where a named scenario's samples are computed on a clock: "thread" (a helper thread of this
        process) or "process" (drivers.sim_block_producer: out of the reader's GIL, as the real chip's work
        is in silicon).
    site, vehicle_iron: a named scenario's place (a simulation.Site; None: simulation.DEFAULT_SITE) and vehicle
        iron ("scenario": the scenario's own, None, or a simulation.VehicleIron), as `open_stream` takes them;
        the field, gravity and track are the place's. Only in this process: producer "thread".
    """

    def __init__(self, scenario="static", seed: int = 0, errors="adis16405",
                 clock: ChipClock | Callable[[], float] | None = None, faults: FaultPlan | None = None,
                 product_id: int = R.PRODUCT_ID_ADIS16405, producer: str = "thread", site=None,
                 vehicle_iron="scenario"):
        if producer not in ("thread", "process"):
            raise ValueError(f"producer must be 'thread' or 'process', not {producer!r}")
        if producer == "process" and (site is not None or not isinstance(vehicle_iron, str)):
            raise ValueError("a simulated chip at another place or with another iron is computed in this process "
                             "(producer 'thread')")
        self.faults = faults if faults is not None else FaultPlan(seed=seed)
        self.stats = {"transfers": 0, "bursts": 0, "samples_produced": 0, "samples_lost": 0,
                      "clock_violations": 0, "spi_failures": 0}
        self._clock = None if clock is None else chip_clock(clock)
        self._t_origin = self._clock() if clock is not None else 0.0
        self._vt = 0.0
        self._closed = False
        self._open_blocks = self._block_stream_opener(scenario, seed, errors, producer, site, vehicle_iron)
        self._block_samples = (FREE_RUNNING_BLOCK_SAMPLES if clock is None and isinstance(scenario, str)
                               else BLOCK_SAMPLES)
        self._product_id = product_id
        self._regs = _default_registers()
        self._regs[R.PRODUCT_ID >> 1] = product_id
        self._flash = {reg: self._regs[reg >> 1] for reg in _FLASH_REGS}
        self._diag = 0
        self._pending = _ZERO2
        self._busy_until = -math.inf
        self._reset_at = math.inf
        self._self_test_until = math.inf
        self._next_event = math.inf
        self._stuck_values: dict[int, int] = {}
        self._index = -1                  # index of the sample in the output registers
        self._nd = False
        self._out_override: list[int] | None = None
        self._out_row = -1
        self._blk = None
        self._apply_config(reopen=True, start_s=0.0, first_index=0)
        if self._clock is not None:
            # power-on: chip time 0 (sample 0's data-ready) is when the chip can make samples, i.e. once its
            # stream is open — a producer process may take seconds to import the simulator, samples that the
            # simulated chip could not have made are not lost samples
            self._t_origin, self._seg_t0 = self._clock(), 0.0

    def _block_stream_opener(self, scenario, seed: int, errors, producer: str, site, vehicle_iron
                             ) -> Callable[[float, float], BlockStream]:
        """How the chip opens its block stream at a rate and a start time (`scenario`: the constructor's)."""
        ahead = self._clock is not None
        if isinstance(scenario, str) and producer == "process" and self._clock is not None and isinstance(errors, str):
            def produced(rate_hz, start_s, _name=scenario):
                from ahrsd.drivers.sim_block_producer import ProducedStream

                return ProducedStream(_name, rate_hz, seed, errors, start_s, BLOCK_SAMPLES)
            return produced
        if isinstance(scenario, str):
            def reopen(rate_hz, start_s, _name=scenario):
                from ahrsd.simulation import open_stream   # imported here: simulation is heavy
                return open_stream(_name, rate_hz=rate_hz, seed=seed, errors=errors, start_s=start_s, site=site,
                                   vehicle_iron=vehicle_iron)
            return lambda rate_hz, start_s: InProcessStream(reopen(rate_hz, start_s), reopen, ahead)
        if isinstance(scenario, SimulationStream):
            return lambda rate_hz, start_s: InProcessStream(scenario, None, ahead)
        if callable(scenario):
            return lambda rate_hz, start_s: InProcessStream(scenario(rate_hz, start_s), scenario, ahead)
        raise TypeError("scenario must be a name, a stream with next_block(n), or a factory(rate_hz, start_s)")

    # --------------------------------------------------------------------------------- public helpers
    @property
    def sample_rate_hz(self) -> float:
        return self._rate

    @property
    def sample_index(self) -> int:
        """Index of the sample now in the output registers (-1 before the first)."""
        return self._index

    @property
    def output_lsb(self) -> list[int]:
        """The 12 output registers of the current sample as decoded integers (what a perfect read gives)."""
        w = self._out_words()
        return [R.decode_unsigned14(w[0])] + [R.decode_signed14(x) for x in w[1:10]] + \
               [R.decode_signed12(w[10]), R.decode_unsigned12(w[11])]

    @property
    def output_truth_q_wxyz(self) -> np.ndarray | None:
        """Truth attitude (body->NED, scalar first) of the sample in the output registers, if known."""
        if self._out_row < 0 or self._blk_truth_q is None:
            return self._last_truth_q
        return self._blk_truth_q[self._out_row]

    @property
    def output_truth_gyro_rad_s(self) -> np.ndarray | None:
        if self._out_row < 0 or self._blk_truth_gyro is None:
            return None
        return self._blk_truth_gyro[self._out_row]

    def ready_clock_time(self, index: int) -> float:
        """The value of the chip's `clock` at which sample `index` becomes ready (its data-ready pulse): the
        chip's own sample grid (clock mode only)."""
        return self._t_origin + self._seg_t0 + (index - self._seg_index0) / self._rate

    def first_index_after(self, clock_time: float) -> int:
        """The first sample index that becomes ready after `clock_time` (a value of the chip's clock)."""
        return self._seg_index0 + int(math.floor((clock_time - self._t_origin - self._seg_t0) * self._rate)) + 1

    def first_index_after_now(self) -> int:
        """The first sample index that becomes ready after now, on the grid of the chip's current rate (a rate
        written at start-up starts a new grid: drivers.ground_truth rebases its fault plan on it)."""
        return self.first_index_after(self._t_origin + self.now())

    @property
    def data_ready_on_dio1(self) -> bool:
        """MSC_CTRL routes data-ready to DIO1, active high (bit 2 enable, bit 1 polarity, bit 0 clear = DIO1)."""
        return (self._regs[R.MSC_CTRL >> 1] & _DIO1_ROUTE_BITS) == _DIO1_ROUTED

    def now(self) -> float:
        """Chip time in seconds."""
        return self._vt if self._clock is None else self._clock() - self._t_origin

    def sleep(self, seconds: float) -> None:
        """Wait `seconds` of chip time: instant on virtual time (clock=None), real sleep otherwise."""
        if self._clock is None:
            self._vt += max(0.0, seconds)
            if self._vt >= self._next_event:
                self._run_events(self._vt)
        else:
            self._clock.sleep(max(0.0, seconds))

    def helper_pids(self) -> list[int]:
        """The processes the chip's reads may wait on (its block producer, drivers.sim_block_producer): a
        real-time reader gives them its own priority (drivers.threaded_source)."""
        pid = self._stream.pid
        return [pid] if pid is not None else []

    def close(self) -> None:
        self._closed = True
        self._stream.close()

    def power_cycle(self) -> None:
        """Back to the flash settings with a clean DIAG_STAT (like a reset, but instant)."""
        self._reset_now()

    # --------------------------------------------------------------------------------- SpiBus
    def transfer(self, tx: bytes, speed_hz: int, delay_us: int = 0) -> bytes:
        if self._closed:
            raise OSError(errno.EBADF, "simulated SPI bus is closed")
        n = len(tx)
        self.stats["transfers"] += 1
        if self._clock is None:
            self._vt += n * 8.0 / speed_hz + delay_us * 1e-6
            now = self._vt
        else:
            now = self._clock() - self._t_origin
        if now >= self._next_event:
            self._run_events(now)
        plan = self.faults
        if plan.faults and plan:
            idx = self._index + 1 if self._clock is None else self._clock_index(now)
            if plan.active(FaultKind.BUS_ERROR, idx):
                raise OSError(errno.ENODEV, "No such device (simulated ADIS16405 gone)")
            rx = self._dispatch(tx, n, speed_hz, now)
            if plan.active(FaultKind.GARBAGE, idx):
                rx = plan.random_bytes(n)
            if plan.active(FaultKind.SHORT_READ, idx):
                rx = rx[: n // 2]
            return rx
        return self._dispatch(tx, n, speed_hz, now)

    def _dispatch(self, tx: bytes, n: int, speed_hz: int, now: float) -> bytes:
        if now < self._busy_until:
            return bytes(n)                        # resetting / executing a command: no answer
        if n >= 2 and tx[0] == R.GLOB_CMD and tx[1] == 0:
            return self._burst(n, speed_hz, now)
        if self._clock is not None:
            self._catch_up(now)
        if n % 2:
            self._latch(R.DiagStat.SPI_FAILURE)
            self.stats["spi_failures"] += 1
            return bytes(n)
        if n == 2:
            return self._frame(tx[0], tx[1], speed_hz)
        return b"".join(self._frame(tx[i], tx[i + 1], speed_hz) for i in range(0, n, 2))

    # --------------------------------------------------------------------------------- frames
    def _violation(self, speed_hz: int, limit_hz: int) -> bool:
        if speed_hz > limit_hz:
            self.stats["clock_violations"] += 1
            self._latch(R.DiagStat.SPI_FAILURE)
            return True
        return False

    def _frame(self, b0: int, b1: int, speed_hz: int) -> bytes:
        resp = self._pending
        if self._violation(speed_hz, R.spi_speed_hz(self._regs[R.SMPL_PRD >> 1])):
            resp = bytes(((resp[0] >> 1) | 0x80, ((resp[0] & 1) << 7) | (resp[1] >> 1)))  # bit slip
        if b0 & R.WRITE_BIT:
            self._pending = _ZERO2
            self._write_byte(b0 & 0x7F, b1)
        else:
            self._pending = self._read_register(b0 & 0x7E).to_bytes(2, "big")
        return resp

    def _read_register(self, addr: int) -> int:
        i = _OUTPUT_INDEX.get(addr)
        if i is not None:
            word = self._out_words()[i] | (R.ND if self._nd else 0) | (R.EA if self._diag else 0)
            self._nd = False
            return word
        if addr == R.DIAG_STAT:
            diag, self._diag = self._diag, 0        # latched bits clear on read
            return diag
        if addr == R.MSC_CTRL and self._self_test_until < math.inf:
            return self._regs[addr >> 1] | R.MscCtrl.INT_SELF_TEST
        return self._regs[addr >> 1] if addr < 128 else 0

    def _write_byte(self, byte_addr: int, value: int) -> None:
        reg, upper = byte_addr & 0x7E, byte_addr & 1
        if reg == R.GLOB_CMD:
            if not upper:
                self._command(value)
            return
        if reg in _READ_ONLY or reg >= 128:
            return
        old = self._regs[reg >> 1]
        new = (old & 0x00FF) | (value << 8) if upper else (old & 0xFF00) | value
        if reg == R.MSC_CTRL and new & R.MscCtrl.INT_SELF_TEST:
            new &= ~R.MscCtrl.INT_SELF_TEST
            self._self_test_until = self.now() + R.SELF_TEST_TIME_S
            self._next_event = min(self._next_event, self._self_test_until)
        if reg == R.SMPL_PRD:
            new &= 0x00FF
        self._regs[reg >> 1] = new
        if reg == R.SMPL_PRD and new != old:
            self._apply_config(reopen=True)
        elif reg == R.SENS_AVG or reg in _OFFSET_REGS:
            self._apply_config(reopen=False)

    def _command(self, bits: int) -> None:
        now = self.now()
        if bits & R.GlobCmd.SOFTWARE_RESET:
            self._busy_until = now + R.RESET_TIME_S
            self._reset_at = self._busy_until
            self._next_event = min(self._next_event, self._busy_until)
            return
        if bits & R.GlobCmd.FACTORY_CAL_RESTORE:
            for reg in _OFFSET_REGS + (R.XMAGN_HIF, R.YMAGN_HIF, R.ZMAGN_HIF):
                self._regs[reg >> 1] = 0
            self._busy_until = now + R.FACTORY_RESTORE_TIME_S
            self._apply_config(reopen=False)
        if bits & (R.GlobCmd.AUTO_NULL | R.GlobCmd.PRECISION_AUTO_NULL):
            self._auto_null()
            precise = bits & R.GlobCmd.PRECISION_AUTO_NULL
            self._busy_until = now + (R.PRECISION_AUTO_NULL_TIME_S if precise else R.AUTO_NULL_TIME_S)
        if bits & R.GlobCmd.FLASH_UPDATE:
            self._flash = {reg: self._regs[reg >> 1] for reg in _FLASH_REGS}
            self._regs[R.FLASH_CNT >> 1] += 1

    def _auto_null(self) -> None:
        """Set the gyro offsets so the present (unfiltered-bias) gyro output reads zero."""
        if self._blk is None or self._out_row < 0:
            return
        lo, hi = max(0, self._out_row - 63), self._out_row + 1
        mean_dps = self._blk_gyro_dps[lo:hi].mean(axis=0)   # before offsets
        for k, reg in enumerate((R.XGYRO_OFF, R.YGYRO_OFF, R.ZGYRO_OFF)):
            lsb = int(np.clip(np.rint(-mean_dps[k] / R.GYRO_OFF_DPS_PER_LSB), R.LSB12_MIN, R.LSB12_MAX))
            self._regs[reg >> 1] = lsb & 0xFFFF
        self._apply_config(reopen=False)

    def _run_events(self, now: float) -> None:
        if now >= self._self_test_until:
            self._self_test_until = math.inf
            fault = self.faults.active(FaultKind.SELF_TEST_FAIL, self._index + 1) if self.faults.faults else None
            if fault is not None:
                self._latch(fault.diag_bits | R.DiagStat.SELF_TEST_FAILED)
        if self._reset_at <= now:
            self._reset_at = math.inf
            self._reset_now()
        self._next_event = min(self._self_test_until, self._reset_at)

    def _reset_now(self) -> None:
        old_prd = self._regs[R.SMPL_PRD >> 1]
        self._regs = _default_registers()
        self._regs[R.PRODUCT_ID >> 1] = self._product_id
        for reg, value in self._flash.items():
            self._regs[reg >> 1] = value
        self._diag = 0
        self._nd = False
        self._pending = _ZERO2
        self._self_test_until = math.inf
        self._apply_config(reopen=self._regs[R.SMPL_PRD >> 1] != old_prd)

    def _latch(self, bits: int) -> None:
        self._diag |= int(bits)

    # --------------------------------------------------------------------------------- burst
    def _burst(self, n: int, speed_hz: int, now: float) -> bytes:
        self.stats["bursts"] += 1
        violated = self._violation(speed_hz, R.SPI_BURST_HZ)
        if self._clock is None:
            self._produce(self._index + 1)
            t = self._seg_t0 + (self._index - self._seg_index0) / self._rate
            if t > self._vt:
                self._vt = t
        else:
            self._catch_up(now)
        nd, ea = self._nd, self._diag != 0
        self._nd = False
        pending, self._pending = self._pending, _ZERO2
        plan = self.faults
        if (nd and not ea and not violated and self._out_override is None and pending == _ZERO2
                and n == R.BURST_FRAME_BYTES and not (plan.faults and plan)):
            row = self._out_row
            return self._blk_bytes_nd[row * 26:(row + 1) * 26]
        words = list(self._out_words())
        if plan.faults and plan and words[1] & 0x2000 and plan.active(FaultKind.BURST_BUG, self._index):
            words[1] &= ~0x2000 & 0xFFFF                     # EZ 81805: bit 13 lost on negative X-gyro
        flag = (R.ND if nd else 0) | (R.EA if ea else 0)
        data = _PACK12(*[w | flag for w in words])
        if violated:
            data = bytes(b ^ 0x5A for b in data)
        out = pending + data
        if n > len(out):
            out += bytes(n - len(out))
        return out[:n]

    def _clock_index(self, now: float) -> int:
        return self._seg_index0 + int(math.floor((now - self._seg_t0) * self._rate))

    def _catch_up(self, now: float) -> None:
        target = self._clock_index(now)
        if target > self._index:
            lost = target - self._index - 1
            if lost > 0 and self._index >= 0:
                self.stats["samples_lost"] += lost
            self._produce(target)

    # --------------------------------------------------------------------------------- samples
    def _produce(self, index: int) -> None:
        """Make sample `index` the output (samples before it that were never produced are dropped)."""
        while True:
            if self._blk is None:
                self._refill()
            row = index - self._blk_first
            if row < self._blk_n:
                break
            self._materialise_output()
            self._refill()
        if row < 0:
            return
        plan = self.faults
        if plan.faults and plan:
            if plan.active(FaultKind.STALL, index):
                self._index = index              # time moves on, the output registers do not
                return
            self._out_row = row
            self._out_override = None
            self._index = index
            self._nd = True
            self.stats["samples_produced"] += 1
            self._apply_sample_faults(index, row)
        else:
            self._out_row = row
            self._out_override = None
            self._index = index
            self._nd = True
            self.stats["samples_produced"] += 1
        if self._blk_sat[row]:
            self._latch(R.DiagStat.SENSOR_OVERRANGE)

    def _apply_sample_faults(self, index: int, row: int) -> None:
        plan = self.faults
        words = None
        fault = plan.active(FaultKind.ALARM, index)
        if fault is not None:
            self._latch(fault.diag_bits)
        for f in plan.faults:
            if f.kind is FaultKind.STUCK_AXIS and f.in_window(index):
                words = words or [int(w) for w in self._blk_words[row]]
                held = self._stuck_values.setdefault(id(f), words[1 + f.axis])
                words[1 + f.axis] = held
                plan.injected[f.kind.value] += 1
            elif f.kind is FaultKind.STUCK_AXIS:
                self._stuck_values.pop(id(f), None)
        fault = plan.active(FaultKind.SATURATION, index)
        if fault is not None:
            words = words or [int(w) for w in self._blk_words[row]]
            limit = self._full9[fault.axis]
            words[1 + fault.axis] = R.encode_signed14(int(limit if fault.sign >= 0 else -limit), nd=False)
            self._latch(R.DiagStat.SENSOR_OVERRANGE)
        if words is not None:
            self._out_override = words

    def _out_words(self) -> list[int]:
        if self._out_override is not None:
            return self._out_override
        if self._out_row < 0 or self._blk is None:
            return [0] * 12
        return [int(w) for w in self._blk_words[self._out_row]]

    def _materialise_output(self) -> None:
        if self._out_override is None and self._out_row >= 0:
            self._out_override = self._out_words()
            self._last_truth_q = None if self._blk_truth_q is None else self._blk_truth_q[self._out_row].copy()
        self._out_row = -1

    # --------------------------------------------------------------------------------- blocks
    def _apply_config(self, reopen: bool, start_s: float | None = None, first_index: int | None = None) -> None:
        """Take SMPL_PRD / SENS_AVG / offsets from the registers; reopen the stream if the rate changed."""
        regs = self._regs
        self._rate = R.sample_rate_hz(regs[R.SMPL_PRD >> 1])
        range_dps, filter_n = R.decode_sens_avg(regs[R.SENS_AVG >> 1])
        self._box = 1 << filter_n
        dps_per_lsb = R.GYRO_DPS_PER_LSB[range_dps]
        self._scale9 = np.array([dps_per_lsb] * 3 + [R.ACCEL_G_PER_LSB] * 3 + [R.MAG_GAUSS_PER_LSB] * 3)
        self._full9 = np.array([R.gyro_range_lsb(range_dps)] * 3 + [R.ACCEL_RANGE_LSB] * 3 + [R.MAG_RANGE_LSB] * 3)
        gyro_off = [R.decode_signed12(regs[r >> 1]) * R.GYRO_OFF_DPS_PER_LSB for r in _OFFSET_REGS[:3]]
        accel_off = [R.decode_signed12(regs[r >> 1]) * R.ACCEL_OFF_G_PER_LSB for r in _OFFSET_REGS[3:]]
        self._offset9 = np.array(gyro_off + accel_off + [0.0] * 3)
        if reopen:
            if first_index is None:
                first_index = self._index + 1
                start_s = self._seg_t0 + (first_index - self._seg_index0) / self._seg_rate
                self._materialise_output()
            if self._stream is None:
                self._stream = self._open_blocks(self._rate, start_s)
            else:        # a producer process restarts in place: not a new import of the simulator
                self._stream.restart(self._rate, start_s)
            # the new sample grid starts once its stream is open (a producer process has its first block)
            self._seg_t0 = self.now() if self._clock is not None else start_s
            self._seg_index0 = first_index
            self._seg_rate = self._rate
            self._blk = None
            self._tail = None
            self._blk_first = first_index
            self._blk_n = 0
            self._blk_truth_q = None
            self._last_truth_q = None
        elif self._blk is not None:
            self._encode()                       # re-encode the current block with the new settings

    def _refill(self) -> None:
        first = self._blk_first + self._blk_n
        if self._blk is not None:
            keep = _MAX_FILTER_HISTORY
            self._tail = np.concatenate([self._tail, self._blk_raw])[-keep:]
        blk = self._next_block()
        n = len(blk.t_s)
        raw = np.empty((n, 9))
        np.degrees(blk.gyro_rad_s, out=raw[:, 0:3])
        np.multiply(blk.accel_m_s2, 1.0 / R.STANDARD_GRAVITY_M_S2, out=raw[:, 3:6])
        np.multiply(blk.mag_ut, 1.0 / R.UT_PER_GAUSS, out=raw[:, 6:9])
        if self._tail is None:
            self._tail = np.repeat(raw[:1], _MAX_FILTER_HISTORY, axis=0)   # no start-up transient
        self._blk = blk
        self._blk_first = first
        self._blk_n = n
        self._blk_raw = raw
        self._blk_temp = np.asarray(blk.temp_c, dtype=np.float64)
        self._blk_truth_q = blk.truth_q_wxyz
        self._blk_truth_gyro = blk.truth_gyro_rad_s
        self._encode()

    def _next_block(self) -> ChipBlock:
        """The stream's next block (on a real-time clock it was computed ahead: drivers.sim_block_stream)."""
        blk = self._stream.next_block(self._block_samples)
        if self._stream.computed_elsewhere:
            # computed ahead in a producer process: a wait (its ring empty) is the producer short of CPU,
            # counted: the read waits with it and samples are lost that the real chip, computing in silicon,
            # would keep
            wait_us = int(self._stream.waited_s * 1e6)
            if wait_us > 1e6 / self._rate:
                self.stats["producer_waits"] = self.stats.get("producer_waits", 0) + 1
            self.stats["producer_wait_max_us"] = max(self.stats.get("producer_wait_max_us", 0), wait_us)
        return blk

    _stream: BlockStream | None = None

    def _encode(self) -> None:
        """Bartlett filter, offsets, quantisation, saturation and word encoding for the whole block."""
        raw, n, m = self._blk_raw, self._blk_n, self._box
        if m > 1:
            h = 2 * m - 2
            ext = np.concatenate([self._tail[-h:], raw])
            c = np.zeros((len(ext) + 1, 9))
            np.cumsum(ext, axis=0, out=c[1:])
            box1 = (c[m:] - c[:-m]) / m                       # first 2^N-tap average
            c2 = np.zeros((len(box1) + 1, 9))
            np.cumsum(box1, axis=0, out=c2[1:])
            filt = (c2[m:] - c2[:-m]) / m                     # second: together a Bartlett window
        else:
            filt = raw.copy()
        self._blk_gyro_dps = filt[:, 0:3].copy()
        filt += self._offset9
        lsb = np.rint(filt / self._scale9)
        np.clip(lsb, -self._full9, self._full9, out=lsb)
        self._blk_sat = (np.abs(lsb) >= self._full9).any(axis=1)
        words = np.empty((n, 12), dtype=np.int64)
        words[:, 0] = int(round(SUPPLY_V / R.SUPPLY_V_PER_LSB))
        words[:, 1:10] = lsb
        words[:, 0:10] &= R.DATA14_MASK
        temp_lsb = np.clip(np.rint((self._blk_temp - R.TEMP_C_AT_ZERO) / R.TEMP_C_PER_LSB), R.LSB12_MIN, R.LSB12_MAX)
        words[:, 10] = temp_lsb.astype(np.int64) & R.DATA12_MASK
        words[:, 11] = 0                                      # AUX_ADC: nothing connected
        self._blk_words = words.astype(np.uint16)
        framed = np.zeros((n, 13), dtype=">u2")               # 2 pipeline bytes + 24 data bytes per row
        framed[:, 1:] = self._blk_words | R.ND
        self._blk_bytes_nd = framed.tobytes()


class EdgeEvent:
    """What libgpiod's `gpiod.EdgeEvent` carries (event_type, timestamp_ns, line_offset, global_seqno,
    line_seqno)."""

    __slots__ = ("event_type", "timestamp_ns", "line_offset", "global_seqno", "line_seqno")
    RISING_EDGE = 1

    def __init__(self, timestamp_ns: int, line_offset: int, seqno: int):
        self.event_type = self.RISING_EDGE
        self.timestamp_ns = timestamp_ns
        self.line_offset = line_offset
        self.global_seqno = self.line_seqno = seqno


class SimulatedDataReadyLine:
    """The chip's DIO1 data-ready line on a GPIO, as libgpiod's `LineRequest` for one line with rising-edge
    detection presents it (`wait_edge_events(timeout)`, `read_edge_events(max_events)`, `release()`): one
    rising edge per sample on the chip's own sample clock, only while MSC_CTRL routes data-ready to DIO1
    active high. Time stamps are the host clock's (CLOCK_MONOTONIC, libgpiod's default event clock); like the
    kernel's buffer (16 events per line) it keeps the newest events, and the sequence numbers count every edge.

    chip: a SimulatedAdis16405 on a clock. to_host(t): the host time of chip-clock time t (identity unless the
    test's chip clock drifts); host_clock / sleep_until: the reader's clock and how to wait on it.
    """

    BUFFER_EVENTS = 16        # the kernel's default event buffer: 16 events per requested line

    def __init__(self, chip: "SimulatedAdis16405", *, offset: int = 25, host_clock=None, to_host=None,
                 sleep_until=None):
        if chip._clock is None:
            raise ValueError("a data-ready line needs the chip on a clock (free-running chips have no edges)")
        self.chip = chip
        self.offset = offset
        self._host = chip._clock if host_clock is None else chip_clock(host_clock)
        self._to_host = to_host or chip._clock.to_host
        self._sleep_until = sleep_until or self._host.sleep_until
        self._first: int | None = None          # the chip index of edge seqno 1
        self._next = None                       # the chip index of the next edge not yet read
        self.released = False

    def _edge_host_time(self, index: int) -> float:
        return self._to_host(self.chip.ready_clock_time(index))

    def _due(self) -> int:
        """How many edges are waiting (0 while data-ready is not routed to this line)."""
        chip = self.chip
        if not chip.data_ready_on_dio1:
            self._next = None
            return 0
        now_chip = chip._clock()
        if self._next is None:                  # edges start now (the request, or data-ready enabled)
            self._next = chip.first_index_after(now_chip)
            if self._first is None:
                self._first = self._next
        newest = chip.first_index_after(now_chip) - 1
        return max(0, newest - self._next + 1)

    def wait_edge_events(self, timeout=None) -> bool:
        if self.released:
            raise OSError(errno.EBADF, "line request released")
        if self._due():
            return True
        if isinstance(timeout, timedelta):                # libgpiod takes a timedelta or seconds
            timeout = timeout.total_seconds()
        limit = None if timeout is None else self._host() + float(timeout)
        if self._next is None:
            target = limit if limit is not None else self._host() + 0.1
        else:
            target = self._edge_host_time(self._next)
            if limit is not None:
                target = min(target, limit)
        self._sleep_until(target)
        return self._due() > 0

    def read_edge_events(self, max_events: int | None = None) -> list:
        n = self._due()
        if n == 0:
            self.wait_edge_events(None)         # libgpiod blocks until an event comes
            n = self._due()
        first, last = self._next, self._next + n - 1
        self._next = last + 1
        keep = min(n, self.BUFFER_EVENTS, max_events or self.BUFFER_EVENTS)
        return [EdgeEvent(int(round(self._edge_host_time(i) * 1e9)), self.offset, i - self._first + 1)
                for i in range(last - keep + 1, last + 1)]

    def release(self) -> None:
        self.released = True
