"""The sensor-source interface and the one factory that builds the configured source.

A `SensorSource` hands the daemon IMU samples (ahrsd.core.ImuSample, sensor frame, SI units) with a time
stamp in CLOCK_MONOTONIC seconds (minus `monotonic_offset_s`), a sample index, and GAP_BEFORE on the first
sample after lost ones: gaps are found once, here. Two ways to be read:
* `per_sample = True` (a chip): `read_one(now)` once per sample at `next_read_time()`; returns the new sample
  or None (not ready yet). drivers.chip_source.ChipSource, drivers.reconnecting.ReconnectingSource.
* `per_sample = False` (a recording, or a reader off the event loop): `poll()` on a fixed tick returns every
  sample that is due. drivers.replay_source.ReplaySource, drivers.threaded_source.ThreadedSource (a chip read,
  or the IIO buffer drained, in its own thread), drivers.process_source.ProcessSource (a chip read in a child
  process), drivers.iio_source.IioSource (which can also `wait(timeout_s)` for records: a reader thread's).
Both raise DriverError subclasses on failure (FrameError: one corrupt frame; BusError: the bus failed).
What the daemon reads of a source is declared in drivers.source_interface (SensorSource, PerSampleSource).
A GNSS receiver is a sibling source with its own sample type (ahrsd.core.GnssFix), not an IMU source.
"""

from __future__ import annotations

import functools
import time

from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ, ChipSource
from ahrsd.drivers.reconnecting import ReconnectingSource
from ahrsd.drivers.replay_source import ReplaySource
from ahrsd.drivers.source_interface import PerSampleSource, SensorSource
from ahrsd.drivers.source_settings import SensorSettings

__all__ = ["SensorSource", "PerSampleSource", "SensorSettings", "open_source", "open_chip_bus", "open_chip_driver", "start_chip_source",
           "reader_kind"]


def open_chip_bus(kind: str, *, spi_device: str = "", scenario: str = "static", seed: int = 0,
                  errors: str = "adis16405", clock=time.monotonic, faults=None, producer: str = "thread",
                  site=None, vehicle_iron="scenario"):
    """The SPI bus the chip answers on (the one place a chip is built): kind "spi", the spidev node `spi_device`;
    kind "sim", the byte-level simulated ADIS16405 flying `scenario` (clock None: it runs free, one sample
    period per read, as fast as it is read; faults: a drivers.faults.FaultPlan; producer: where its samples
    are computed; site, vehicle_iron: where it flies and the vehicle's iron, drivers.simulated)."""
    if kind == "spi":
        if faults is not None:
            raise ValueError("faults are injected into the simulated chip only")
        from ahrsd.drivers.spi import SpidevBus

        return SpidevBus(spi_device)
    if kind == "sim":
        from ahrsd.drivers.simulated import SimulatedAdis16405

        return SimulatedAdis16405(scenario=scenario, seed=seed, errors=errors, clock=clock, faults=faults,
                                  producer=producer, site=site, vehicle_iron=vehicle_iron)
    raise ValueError(f"no chip bus {kind!r}: choose sim or spi")


def open_chip_driver(bus, *, data_ready: bool = False, samples_as_records: bool = False) -> Adis16405:
    """The IMU driver on a bus (the one place the chip model is named); data_ready: data-ready routed to DIO1
    at every (re)start; samples_as_records: it hands over SampleRecords (the reader process's, Adis16405)."""
    return Adis16405(bus, data_ready=data_ready, samples_as_records=samples_as_records)


def _chip_drivers(*, data_ready: bool, samples_as_records: bool):
    """The driver factory a reconnecting source builds its chip's driver with (drivers.reconnecting)."""
    return functools.partial(open_chip_driver, data_ready=data_ready, samples_as_records=samples_as_records)


def start_chip_source(bus, description: str, *, clock=time.monotonic, **start) -> ChipSource:
    """The chip on `bus`, started (`Adis16405.start(**start)`: self-test, rate, filter), read through the
    one timing path. clock: the host clock of the reads; for a free-running simulated chip (no real time)
    pass the chip's own `bus.now`. The bus is closed if the start fails."""
    driver = open_chip_driver(bus)
    try:
        driver.start(**start)
    except Exception:
        bus.close()
        raise
    return ChipSource(driver, bus, description, clock=clock)


def open_source(sensor_cfg: SensorSettings, *, clock=time.monotonic, faults=None, samples_as_records: bool = False):
    """The source `sensor_cfg` names (`source` = "sim" | "spi" | "iio" | "replay", with its keys:
    drivers.source_settings; the daemon's `[sensor]`, daemon.config.SensorConfig, is one): a chip with start-up retries and bus reconnection — read in a
    dedicated thread (`reader` = "thread"), in a child process ("process": drivers.process_source) or on the
    daemon's event loop ("event_loop") —, the kernel's IIO driver (drivers.iio_source), or a replay.

    faults: a drivers.faults.FaultPlan for the simulated chip (refused for a real sensor); the simulated chip
    is wrapped in drivers.ground_truth.GroundTruthSource, which accounts its lost samples against the truth.
    samples_as_records: the chip's drivers hand over SampleRecords (the reader process, drivers.process_source,
    which only packs them); the kernel's IIO scans and a recording are ImuSamples either way.
    """
    kind = sensor_cfg.source
    if kind in ("sim", "spi", "iio") and reader_kind(sensor_cfg) == "process":
        from ahrsd.drivers.process_source import ProcessSource

        return ProcessSource(sensor_cfg, faults=faults)     # the same source, read in a child process
    if kind == "replay":
        return _replay_source(sensor_cfg, clock)
    if kind == "iio":
        src = _iio_source(sensor_cfg, clock, faults)
    elif kind in ("spi", "sim"):
        build = _spi_chip_source if kind == "spi" else _simulated_chip_source
        src = build(sensor_cfg, clock, faults, samples_as_records)
    else:
        raise ValueError(f"no sensor source {kind!r}: choose sim, spi, iio or replay")
    src.start()
    return _off_the_loop(src, sensor_cfg, clock)


def _replay_source(sensor_cfg: SensorSettings, clock) -> ReplaySource:
    """A recording (`replay_file`), at its recorded pace × `replay_speed` or as fast as it is read."""
    from ahrsd.drivers.recording import iter_samples

    # a recording cut mid-row (a recorder killed) replays its complete rows, with a warning naming the line
    return ReplaySource(iter_samples(sensor_cfg.replay_file, strict=False), f"replay {sensor_cfg.replay_file}",
                        realtime=sensor_cfg.replay_realtime, clock=clock,
                        speed=sensor_cfg.replay_speed)


def _iio_source(sensor_cfg: SensorSettings, clock, faults):
    """The kernel's IIO driver (`iio_device`), not started."""
    if faults is not None:
        raise ValueError("fault injection (--sim-faults) needs the simulated sensor, not --iio")
    from ahrsd.drivers.iio_source import IioSource

    # rate_hz at the chip's default leaves the driver's sampling_frequency as it is (and needs no write access)
    rate = sensor_cfg.rate_hz
    return IioSource(sensor_cfg.iio_device, clock=clock, rate_hz=None if rate in (None, ADIS16405_RATE_HZ) else rate)


def _paced_by(line) -> dict:
    """The ReconnectingSource timing for reads paced by a data-ready `line` (drivers.data_ready)."""
    from ahrsd.drivers.data_ready import DataReadyTimer

    return {"make_timer": lambda period_s: DataReadyTimer(line, period_s)}


def _spi_chip_source(sensor_cfg: SensorSettings, clock, faults, samples_as_records: bool) -> ReconnectingSource:
    """The real chip on `spi_device`, re-opened when the bus fails, paced by the host timer or, when `data_ready`
    names its GPIO line, by the chip's data-ready edges; not started."""
    if faults is not None:
        raise ValueError("fault injection (--sim-faults) needs the simulated sensor, not --spi")
    path = sensor_cfg.spi_device
    spec = sensor_cfg.data_ready
    rate = sensor_cfg.rate_hz      # written to the chip's SMPL_PRD at each (re)start (None: the chip's own)
    if not spec:
        return ReconnectingSource(lambda: open_chip_bus("spi", spi_device=path),
                                  _chip_drivers(data_ready=False, samples_as_records=samples_as_records),
                                  f"ADIS16405 on {path}", clock=clock, sample_rate_hz=rate)
    from ahrsd.drivers.data_ready import open_gpio_line

    return ReconnectingSource(lambda: open_chip_bus("spi", spi_device=path),
                              _chip_drivers(data_ready=True, samples_as_records=samples_as_records),
                              f"ADIS16405 on {path}, paced by data-ready on {spec}", clock=clock,
                              sample_rate_hz=rate, **_paced_by(open_gpio_line(spec)))


def _simulated_chip_source(sensor_cfg: SensorSettings, clock, faults, samples_as_records: bool):
    """The simulated chip flying `scenario` (faults injected as planned), read as the real one is and accounted
    against its truth (drivers.ground_truth); not started."""
    from ahrsd.drivers.ground_truth import BurstIndexTap, GroundTruthSource

    # the simulator's work in a process of its own, out of the reader's GIL (drivers.sim_block_producer)
    chip = open_chip_bus("sim", scenario=sensor_cfg.scenario, seed=sensor_cfg.seed, errors=sensor_cfg.errors,
                         clock=clock, faults=faults, producer="process")
    what = f"simulated ADIS16405 ({sensor_cfg.scenario}{', faults injected' if faults is not None else ''})"
    tap = BurstIndexTap(chip)
    timing = {}
    if sensor_cfg.data_ready:       # the simulated chip's own DIO1 (drivers.simulated)
        from ahrsd.drivers.simulated import SimulatedDataReadyLine

        timing = _paced_by(SimulatedDataReadyLine(chip, host_clock=clock))
        what += ", paced by its data-ready line"
    drivers = _chip_drivers(data_ready=bool(timing), samples_as_records=samples_as_records)
    return GroundTruthSource(ReconnectingSource(lambda: tap, drivers, what, clock=clock, reopen_same_bus=True,
                                                sample_rate_hz=sensor_cfg.rate_hz, **timing), chip, tap)


def reader_kind(sensor_cfg: SensorSettings) -> str:
    """`[sensor] reader`: "auto" is a child process for a chip without a FIFO, real or simulated (its own GIL:
    docs/drivers.md, measured), so the simulated chip is read the way the real one is; a thread for the
    kernel's IIO buffer (the kernel reads the chip; the thread only drains the buffer)."""
    if sensor_cfg.reader == "auto":
        return "process" if sensor_cfg.source in ("spi", "sim") else "thread"
    return sensor_cfg.reader


def _off_the_loop(src, sensor_cfg: SensorSettings, clock):
    """The per-sample chip source read in its own thread (`[sensor] reader = "thread"`: drivers.threaded_source),
    or left to the daemon's event loop ("event_loop")."""
    if reader_kind(sensor_cfg) != "thread":
        return src
    from ahrsd.drivers.threaded_source import ThreadedSource

    if not src.per_sample:
        # the kernel's IIO buffer holds 10 s of scans: the thread only drains it, at normal priority and
        # without the shorter GIL switch interval a chip without a FIFO needs
        return ThreadedSource(src, clock=clock, realtime=False, switch_interval_s=None)
    return ThreadedSource(src, clock=clock)     # the reader thread starts at the daemon's first poll
