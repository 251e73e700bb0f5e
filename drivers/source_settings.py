"""What drivers.source reads to build a sensor source: its settings, by type.

Every field drivers.source reads is declared here with its one default, so a source is never built from a
probe of whatever object it was handed (issue #29: an optional part is None or a null object by type).
daemon.config.SensorConfig (the `[sensor]` table) is a SensorSettings with what the daemon adds (the mounting,
its poll and stale timing) and its own default rate; a test or a bench builds a SensorSettings directly.

The rate has one meaning: `rate_hz` is the output data rate asked of the chip at every (re)start, and None asks
for none (the chip keeps its own SMPL_PRD; through the kernel's IIO driver, the driver's sampling_frequency is
only read). The daemon asks for the chip's default, 819.2 SPS (daemon.config.SensorConfig), so a chip whose
flash holds another SMPL_PRD still runs at the rate the daemon is built for; with the IIO driver that one value
is not written (drivers.source: the kernel driver starts the chip at it, and a write needs the udev rule).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass(frozen=True)
class SensorSettings:
    """The sensor source to build (drivers.source.open_source) and how to read it."""

    source: str = "sim"                 # "sim" (simulated ADIS16405 chip), "spi" (real chip), "iio" (the kernel's
                                        # adis16400 IIO driver), "replay" (CSV)
    scenario: str = "static"            # simulated scenario (source = "sim")
    seed: int = 0                       # simulator noise seed
    errors: str = "adis16405"           # simulated sensor errors: "adis16405" (datasheet) or "ideal"
    spi_device: str = "/dev/spidev0.0"  # source = "spi"
    data_ready: str = ""                # source = "spi": the GPIO of the chip's DIO1 data-ready, "gpiochip0:25"
                                        # ("": reads paced by the host timer); source = "sim": any non-empty
                                        # value paces the reads by the simulated chip's own DIO1
    iio_device: str = "iio:device0"     # source = "iio": the IIO device (name under /sys/bus/iio/devices)
    reader: str = "auto"                # sim/spi/iio: read in a dedicated "thread", a child "process", on the
                                        # "event_loop"; "auto": process for spi and sim, thread for iio
                                        # (docs/drivers.md)
    replay_file: str = ""               # source = "replay": a recording written by `ahrsd record`
    replay_realtime: bool = True        # replay at the recorded pace (false: as fast as possible)
    replay_speed: float = 1.0           # realtime replay: this many times faster than recorded (1 = real time)
    rate_hz: float | None = None        # sim/spi/iio: the chip's output data rate, SPS, asked at every (re)start
                                        # (the nearest SMPL_PRD setting: 1638.404 / (N + 1); iio: written to the
                                        # driver's sampling_frequency unless at the chip's default 819.2); None:
                                        # the chip's own setting, not written (module docstring)

    def read_in_thread(self) -> SensorSettings:
        """These settings alone (not what a subclass adds: daemon.config.SensorConfig's) with `reader` "thread":
        what the reader child process opens (drivers.process_source), so the child imports nothing above
        drivers to unpickle it."""
        own = {f.name for f in dataclasses.fields(SensorSettings)}
        values = {name: value for name, value in dataclasses.asdict(self).items() if name in own}
        return SensorSettings(**{**values, "reader": "thread"})
