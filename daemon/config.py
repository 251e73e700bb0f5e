"""The daemon's configuration: a TOML file whose sections map one-to-one onto the objects that use them.

    [sensor]     -> SensorConfig     where samples come from (simulated chip, SPI, recording), mounting
    [estimator]  -> EstimatorConfig  which attitude filter
    [gnss]       -> GnssConfig       where GNSS fixes come from (none, serial receiver, autopilot, recording,
                                     simulator), the antenna lever arm
    [location]   -> LocationConfig   where we are (declination for true heading)
    [mavlink]    -> MavlinkConfig    identity and routing policy
    [[endpoint]] -> EndpointConfig   one pymavlink connection each
    [[nmea]]     -> NmeaOutputConfig one NMEA 0183 heading output each (serial, UDP, TCP server; docs/marine.md)
    [outputs]    -> OutputsConfig    message rates
    [state]      -> StateConfig      the state directory (calibration, parameters, signing timestamp)
    [signing]    -> SigningConfig    optional MAVLink 2 signing
    [daemon]     -> DaemonConfig     process behaviour (status line)
    [log]        -> LogConfig        on-vehicle logs: raw samples and MAVLink traffic (daemon.vehicle_log)
    [magcal]     -> daemon.magcal_settings.MagCalSettings  field magnetometer calibration (validated by that module)

Every key is checked; an error names the key, the bad value and what is allowed. Unknown sections and keys
are rejected by name (a typo must not silently fall back to a default). Command-line flags override the file
via `Config.with_overrides`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ahrsd.core.state_dir import default_state_dir
from ahrsd.daemon.magcal_settings import settings_from_mapping
from ahrsd.drivers.chip_source import ADIS16405_RATE_HZ
from ahrsd.drivers.iio_source import driver_rate_hz
from ahrsd.drivers.registers import SMPL_PRD_DIVISOR_MASK, TIME_BASE_FAST_HZ, nearest_rate_hz
from ahrsd.drivers.source_settings import SensorSettings
from ahrsd.daemon.nmea_sentences import (DEFAULT_RATES_HZ, LOW_SPEED_BELOW_BAUD, LOW_SPEED_RATES_HZ, SENTENCE_IDS,
                                         worst_case_bytes)
from ahrsd.daemon.output_profiles import DEFAULT_PROFILE, PROFILES
from ahrsd.daemon.output_registry import BY_CONFIG_KEY, OUTPUTS
from ahrsd.estimator import AIDED_ESTIMATOR, ESTIMATORS, UNAIDED_ESTIMATOR
from ahrsd.simulation import SCENARIOS

DEFAULT_CONFIG_PATH = Path("/etc/ahrsd/ahrsd.toml")
DEFAULT_ENDPOINT = "udpout:127.0.0.1:14550"   # the ground-station port by convention (QGC, MAVSDK)
MAV_TYPES = {"imu": 40, "onboard_controller": 18}  # MAV_TYPE_IMU / MAV_TYPE_ONBOARD_CONTROLLER (minimal.xml)
MIN_HEADING_SLEW_DEG_S = 0.1   # slower would take an hour for a 180° change
MAX_HEADING_SLEW_DEG_S = 90.0
SERIAL_DEFAULT_BAUD = 115200                   # pymavlink mavserial's default
MIN_REPLAY_SPEED, MAX_REPLAY_SPEED = 0.01, 100.0
# [sensor] rate_hz: the ADIS16405's default (SMPL_PRD 0x01) is the most the daemon is built and measured for;
# the least is the fast time base's largest divisor (1638.404 / 128 = 12.8 SPS)
CHIP_DEFAULT_RATE_HZ = ADIS16405_RATE_HZ
MIN_RATE_HZ = TIME_BASE_FAST_HZ / (SMPL_PRD_DIVISOR_MASK + 1)
STALE_PERIODS = 5          # sample periods within [sensor] stale_timeout_s: one late sample is no failure
ENDPOINT_PREFIXES = ("udpout:", "udpin:", "udpbcast:", "udp:", "tcp:", "tcpin:", "uds:", "unix:")


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the key, the value and what is allowed."""


def _fail(key: str, value: Any, allowed: str) -> ConfigError:
    return ConfigError(f"config key {key} = {value!r} is invalid: {allowed}")


# -- small typed checkers: each returns the normalised value or raises ConfigError -------------------------

def _number(key, value, lo=-math.inf, hi=math.inf, *, integer=False) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        kind = "an integer" if integer else "a number"
        raise _fail(key, value, f"expected {kind} in [{lo:g}, {hi:g}]")
    if not math.isfinite(value) or not lo <= value <= hi:
        raise _fail(key, value, f"must be within [{lo:g}, {hi:g}]")
    return int(value) if integer else float(value)


def _choice(key, value, choices) -> str:
    if value not in choices:
        raise _fail(key, value, "one of " + ", ".join(repr(c) for c in choices))
    return value


def _bool(key, value) -> bool:
    if not isinstance(value, bool):
        raise _fail(key, value, "true or false")
    return value


def _string(key, value) -> str:
    if not isinstance(value, str):
        raise _fail(key, value, "a string")
    return value


def _is_host_port(host_port: str) -> bool:
    """HOST:PORT (HOST may be empty) with a port in 1..65535: the network URLs of [[endpoint]] and [[nmea]]."""
    return bool(re.fullmatch(r"[^:\s]*:\d{1,5}", host_port)) and 0 < int(host_port.rsplit(":", 1)[1]) < 65536


def _endpoint_url(key, value) -> str:
    value = _string(key, value).strip()
    if value.startswith(ENDPOINT_PREFIXES):
        host_port = value.split(":", 1)[1]
        if value.startswith(("uds:", "unix:")):
            if host_port:
                return value
        elif _is_host_port(host_port):
            return value
        raise _fail(key, value, "a pymavlink URL such as udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, "
                    "tcpin:HOST:PORT with a port in 1..65535")
    if value.startswith("/dev/") or value.startswith("COM"):
        # serial: "/dev/ttyAMA0,921600" or "/dev/ttyAMA0" (115200 baud)
        device, _, baud = value.partition(",")
        if device and (not baud or (baud.isdigit() and 1200 <= int(baud) <= 12_000_000)):
            return value
        raise _fail(key, value, "a serial port as DEVICE or DEVICE,BAUD with BAUD in 1200..12000000")
    raise _fail(key, value, "a pymavlink URL (udpout:, udpin:, udpbcast:, tcp:, tcpin:, uds:) or a serial "
                "device /dev/...,BAUD")


# -- the sections --------------------------------------------------------------------------------------------
# Each section lists one checker per key, `(key_path, value) -> normalised value`; `_parse_table` applies
# them and rejects unknown keys, and `parse` adds the checks that involve several keys.

def _number_in(lo, hi, integer=False):
    return lambda k, v: _number(k, v, lo, hi, integer=integer)


def _choice_of(choices):
    return lambda k, v: _choice(k, v, choices)


def _mounting(k, value):
    if not isinstance(value, list) or len(value) != 3:
        raise _fail(k, value, "a list of three angles [roll, pitch, yaw] in degrees")
    limits = (180.0, 90.0, 180.0)
    return tuple(_number(f"{k}[{i}]", v, -lim, lim) for i, (v, lim) in enumerate(zip(value, limits)))


def _parse_table(cls, d: dict, prefix: str, checks: dict) -> dict:
    out = {}
    for key, value in d.items():
        check = checks.get(key)
        if check is None:
            raise _unknown(f"{prefix}.{key}", cls)
        out[key] = check(f"{prefix}.{key}", value)
    return out


def _parse_output_table(cls, d: Any, prefix: str, example_url: str, checks: dict) -> dict:
    """An output's table ([[endpoint]], [[nmea]]): a table, and one that names where the output goes (url)."""
    if not isinstance(d, dict):
        raise _fail(prefix, d, "a table with key url")
    if "url" not in d:
        raise _fail(f"{prefix}.url", None, f"required (e.g. url = \"{example_url}\")")
    return _parse_table(cls, d, prefix, checks)


@dataclass(frozen=True)
class SensorConfig(SensorSettings):
    """[sensor]: where samples come from and how they are read (drivers.source_settings.SensorSettings, the
    settings drivers.source builds the source from: this table is one, and is handed to it as it is), how the
    sensor sits in the vehicle, and the daemon's timing of its samples."""

    mounting_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor axes in the body FRD, ZYX Euler deg
    poll_hz: float = 200.0              # replay: polls per second (the chip is read once per sample)
    stale_timeout_s: float = 0.1        # no new sample for this long = sensor failure
    # the daemon always asks the chip for a rate (SensorSettings.rate_hz; lower costs less CPU): by default the
    # chip's own default, so a chip whose flash holds another SMPL_PRD still runs at the rate the daemon is
    # built and measured for
    rate_hz: float = CHIP_DEFAULT_RATE_HZ

    @property
    def chip_rate_hz(self) -> float:
        """The rate the chip runs at for `rate_hz` (its nearest SMPL_PRD setting)."""
        return nearest_rate_hz(self.rate_hz)

    @classmethod
    def parse(cls, d: dict, prefix="sensor") -> "SensorConfig":
        cfg = cls(**_parse_table(cls, d, prefix, {
            "source": _choice_of(("sim", "spi", "iio", "replay")), "data_ready": _string, "iio_device": _string,
            "reader": _choice_of(("auto", "thread", "process", "event_loop")), "scenario": _choice_of(SCENARIOS),
            "seed": _number_in(0, 2**32 - 1, integer=True), "errors": _choice_of(("adis16405", "ideal")),
            "spi_device": _string, "replay_file": _string, "replay_realtime": _bool,
            "replay_speed": _number_in(MIN_REPLAY_SPEED, MAX_REPLAY_SPEED), "mounting_rpy_deg": _mounting,
            "poll_hz": _number_in(10.0, 2000.0), "stale_timeout_s": _number_in(0.005, 10.0),
            "rate_hz": _number_in(MIN_RATE_HZ, CHIP_DEFAULT_RATE_HZ)}))
        cfg.check_rate(f"{prefix}.rate_hz")      # the table on its own: an error names the file (load_config)
        if cfg.source == "replay" and not cfg.replay_file:
            raise _fail(f"{prefix}.replay_file", cfg.replay_file, "a recording path (required when source = 'replay')")
        if cfg.source == "iio" and not cfg.iio_device:
            raise _fail(f"{prefix}.iio_device", cfg.iio_device, "an IIO device: iio:device0, its name (adis16405) "
                        "or its sysfs directory")
        if cfg.source == "spi" and not cfg.spi_device.startswith("/dev/"):
            raise _fail(f"{prefix}.spi_device", cfg.spi_device, "a device path such as /dev/spidev0.0")
        return cfg

    def check_rate(self, key: str) -> None:
        """rate_hz is the chip's SMPL_PRD (through the kernel driver's sampling_frequency with iio); a recording
        has its own rate; and a sample period must fit the stale timeout several times over, or a late sample is
        a sensor failure. key: where rate_hz came from, named in the error ("sensor.rate_hz", "--rate-hz")."""
        if self.rate_hz != CHIP_DEFAULT_RATE_HZ and self.source == "replay":
            raise _fail(key, self.rate_hz, "not for source = 'replay': a recording replays at the "
                        "rate it was recorded at")
        # the kernel's set_freq rounds by its own integer rule (12.8 becomes 10.570 SPS: drivers.iio_source)
        rate = driver_rate_hz(self.rate_hz) if self.source == "iio" else self.chip_rate_hz
        if self.stale_timeout_s < STALE_PERIODS / rate:
            raise _fail(key, self.rate_hz, f"at {rate:.4g} SPS {STALE_PERIODS} sample "
                        f"periods are {STALE_PERIODS / rate:.3g} s, longer than stale_timeout_s = "
                        f"{self.stale_timeout_s:g}: raise the rate or stale_timeout_s")


@dataclass(frozen=True)
class EstimatorConfig:
    # "mekf" (multiplicative EKF), "thesis" (the thesis filter), "ins" (GNSS-aided); "" = automatic:
    # AIDED_ESTIMATOR when a GNSS source is configured, else UNAIDED_ESTIMATOR (Config.estimator_name)
    name: str = ""

    @classmethod
    def parse(cls, d: dict, prefix="estimator") -> "EstimatorConfig":
        return cls(**_parse_table(cls, d, prefix, {"name": _estimator_name}))


def _estimator_name(k, value) -> str:
    if value != "" and value not in ESTIMATORS:
        raise _fail(k, value, '"" (automatic: ins with a [gnss] source, else mekf) or one of '
                    + ", ".join(repr(c) for c in ESTIMATORS))
    return value


GNSS_SOURCES = ("none", "serial", "mavlink", "replay", "sim")
GNSS_PROTOCOLS = ("auto", "ubx", "nmea")
GNSS_BAUDS = (4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
GNSS_SIM_GLITCH_KINDS = ("position_jump", "velocity_spike", "nan")   # simulation.gnss.GLITCH_KINDS a wire carries
MAX_SIM_TIME_S = 7 * 86400.0         # sim faults are placed within a week of scenario time
MIN_SIM_GLITCH_EVERY_S = 1.0         # a glitch on every fix (0.2 s) would be a broken receiver, not a glitch
MAX_SIM_GLITCH_MAGNITUDE = 1000.0    # m or m/s
MAX_LEVER_ARM_M = 100.0


def checked_lever_arm_m(values) -> tuple[float, float, float]:
    """An antenna lever arm given on a command line (body FRD from the IMU, m): three finite numbers within
    ±MAX_LEVER_ARM_M, the bound of `[gnss] lever_arm_m`; ValueError otherwise."""
    arm = tuple(float(v) for v in values)
    if len(arm) != 3 or not all(math.isfinite(v) and abs(v) <= MAX_LEVER_ARM_M for v in arm):
        raise ValueError(f"{' '.join(f'{v:g}' for v in arm)}: expected three numbers in "
                         f"[-{MAX_LEVER_ARM_M:g}, {MAX_LEVER_ARM_M:g}] m")
    return arm


def _lever_arm(k, value):
    if not isinstance(value, list) or len(value) != 3:
        raise _fail(k, value, "a list of three numbers [x, y, z] in metres, body FRD (antenna relative to the IMU)")
    return tuple(_number(f"{k}[{i}]", v, -MAX_LEVER_ARM_M, MAX_LEVER_ARM_M) for i, v in enumerate(value))


def _gnss_device(k, value):
    value = _string(k, value)
    if value and not value.startswith("/dev/"):     # "" = not set (required with source = "serial")
        raise _fail(k, value, "a serial device path such as /dev/serial0 or /dev/ttyACM0")
    return value


def _sim_glitch_every(k, value):
    value = _number(k, value, 0.0, MAX_SIM_TIME_S)
    if 0.0 < value < MIN_SIM_GLITCH_EVERY_S:
        raise _fail(k, value, f"0 (no glitches) or a period of at least {MIN_SIM_GLITCH_EVERY_S:g} s")
    return value


def _gnss_baud(k, value):
    if isinstance(value, bool) or not isinstance(value, int) or value not in GNSS_BAUDS:
        raise _fail(k, value, "one of " + ", ".join(map(str, GNSS_BAUDS)))
    return value


@dataclass(frozen=True)
class GnssConfig:
    """Where GNSS fixes come from (docs/gnss.md). Every fix goes through one validator, then to the aided
    estimator; the position also resolves the declination."""

    source: str = "none"           # "none", "serial" (a receiver on a UART/USB), "mavlink" (the autopilot's
                                   # GPS_RAW_INT), "replay" (a GNSS recording, with [sensor] source = "replay"),
                                   # "sim" (the simulated receiver of the [sensor] scenario, UBX over a pty)
    device: str = ""               # serial: the port, e.g. /dev/serial0
    baud: int = 115200             # serial: the receiver's baud rate
    protocol: str = "auto"         # serial: "ubx" (NAV-PVT), "nmea" (RMC/GGA/VTG) or "auto" (both, UBX preferred)
    latency_s: float = 0.12        # serial: receiver output latency (measurement epoch -> end of message), s
    file: str = ""                 # replay: a GNSS recording (REC.gnss.csv beside the IMU recording)
    use_fused: bool = False        # mavlink: fall back to GLOBAL_POSITION_INT (the autopilot's fused velocity)
                                   # when no GPS_RAW_INT fix arrives (docs/gnss.md "The loop through the autopilot")
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # antenna relative to the IMU, body FRD, m
    # sim: faults of the simulated receiver, on the scenario's time (seconds since the simulated sensor started)
    sim_outage_start_s: float = 60.0   # the receiver loses the sky at this time, s
    sim_outage_s: float = 0.0          # for this long (0: no outage), s
    sim_outage_no_fix: bool = False    # during it, NO_FIX solutions (a u-blox that lost lock) instead of silence
    sim_glitch_every_s: float = 0.0    # a bad fix reported as good at every multiple of this (0: none), s
    sim_glitch_kind: str = "position_jump"   # "position_jump", "velocity_spike" or "nan" (invalid position)
    sim_glitch_magnitude: float = 0.0  # the jump (m) or spike (m/s); 0: the simulator's 50 m / 5 m/s

    @classmethod
    def parse(cls, d: dict, prefix="gnss") -> "GnssConfig":
        cfg = cls(**_parse_table(cls, d, prefix, {
            "source": _choice_of(GNSS_SOURCES), "device": _gnss_device,
            "baud": _gnss_baud,
            "protocol": _choice_of(GNSS_PROTOCOLS), "latency_s": _number_in(0.0, 2.0), "file": _string,
            "use_fused": _bool, "lever_arm_m": _lever_arm,
            "sim_outage_start_s": _number_in(0.0, MAX_SIM_TIME_S), "sim_outage_s": _number_in(0.0, MAX_SIM_TIME_S),
            "sim_outage_no_fix": _bool, "sim_glitch_every_s": _sim_glitch_every,
            "sim_glitch_kind": _choice_of(GNSS_SIM_GLITCH_KINDS),
            "sim_glitch_magnitude": _number_in(0.0, MAX_SIM_GLITCH_MAGNITUDE)}))
        cfg.check(prefix)
        return cfg

    def check(self, prefix="gnss") -> None:
        if self.source == "serial" and not self.device:
            raise _fail(f"{prefix}.device", self.device, "a serial device path (required when source = 'serial')")
        if self.source == "replay" and not self.file:
            raise _fail(f"{prefix}.file", self.file, "a GNSS recording path (required when source = 'replay')")


@dataclass(frozen=True)
class LocationConfig:
    """Where the vehicle is, for the WMM declination (true heading = magnetic heading + declination).

    Priority: declination_deg if set; else lat/lon if set; else the [gnss] receiver's position; else the
    autopilot's GLOBAL_POSITION_INT/GPS_RAW_INT (when use_autopilot_position); else the position remembered in
    the state directory (daemon.position_memory); else the simulator's site for source = "sim"; else 0 with a
    warning (daemon.position, daemon.declination).
    """

    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float = 0.0
    declination_deg: float | None = None
    use_autopilot_position: bool = True

    @classmethod
    def parse(cls, d: dict, prefix="location") -> "LocationConfig":
        out = _parse_table(cls, d, prefix, {
            "lat_deg": _number_in(-90.0, 90.0), "lon_deg": _number_in(-180.0, 180.0),
            "alt_m": _number_in(-1000.0, 100_000.0), "declination_deg": _number_in(-180.0, 180.0),
            "use_autopilot_position": _bool})
        if ("lat_deg" in out) != ("lon_deg" in out):
            missing = "lon_deg" if "lat_deg" in out else "lat_deg"
            raise _fail(f"{prefix}.{missing}", None, "lat_deg and lon_deg must be given together")
        return cls(**out)


def _endpoint_outputs(k, value) -> tuple[tuple[str, float], ...]:
    if not isinstance(value, dict):
        raise _fail(k, value, "a table of [outputs] rate keys, e.g. { attitude_hz = 10.0 }")
    limits = {o.config_key: o.max_rate_hz for o in OUTPUTS}
    out = []
    for key, hz in value.items():
        if key not in limits:
            raise ConfigError(f"unknown config key {k}.{key}: allowed keys are " + ", ".join(limits))
        out.append((key, _number(f"{k}.{key}", hz, 0.0, limits[key])))
    return tuple(out)


@dataclass(frozen=True)
class EndpointConfig:
    """One pymavlink connection: udpout:/udpin:/tcp:/tcpin: URL or a serial port "/dev/ttyAMA0,921600",
    with the outputs it gets: a profile (daemon.output_profiles: "gcs" everything, "autopilot" VPE and
    SYS_STATUS) and per-message rate overrides (`outputs = { attitude_hz = 10.0 }`, Hz, 0 = off)."""

    url: str
    profile: str = DEFAULT_PROFILE
    outputs: tuple[tuple[str, float], ...] = ()

    @classmethod
    def parse(cls, d: dict, prefix="endpoint") -> "EndpointConfig":
        return cls(**_parse_output_table(cls, d, prefix, "udpout:127.0.0.1:14550", {
            "url": _endpoint_url, "profile": _choice_of(tuple(PROFILES)), "outputs": _endpoint_outputs}))

    @property
    def overrides_hz(self) -> dict[int, float]:
        """The rate overrides by message id."""
        return {BY_CONFIG_KEY[key].message_id: hz for key, hz in self.outputs}

    @property
    def serial_baud(self) -> int | None:
        """The baud rate of a serial endpoint (pymavlink's default 115200 when the URL gives none), else None."""
        if not self.url.startswith(("/dev/", "COM")):
            return None
        _, _, baud = self.url.partition(",")
        return int(baud) if baud else SERIAL_DEFAULT_BAUD


NMEA_PREFIXES = ("udp:", "udpbcast:", "tcpserver:", "serial:")
NMEA_DEFAULT_BAUD = 4800            # classic NMEA 0183 (IEC 61162-1); 38400 is "high speed" (IEC 61162-2)
NMEA_MAX_RATE_HZ = 50.0
NMEA_BUDGET_FRACTION = 1.0          # a serial port whose sentences need more than its byte rate is refused


def _nmea_url(key, value) -> str:
    value = _string(key, value).strip()
    if value.startswith("serial:"):
        device, _, baud = value[len("serial:"):].partition(",")
        if device.startswith("/dev/") and (not baud or (baud.isdigit() and 1200 <= int(baud) <= 12_000_000)):
            return value
        raise _fail(key, value, "serial:/dev/DEVICE or serial:/dev/DEVICE,BAUD with BAUD in 1200..12000000")
    if value.startswith(NMEA_PREFIXES):
        host_port = value.split(":", 1)[1]
        if _is_host_port(host_port):
            return value
    raise _fail(key, value, "udp:HOST:PORT (unicast), udpbcast:HOST:PORT (broadcast), tcpserver:HOST:PORT "
                "(clients connect; 10110 is the usual NMEA port) or serial:/dev/DEVICE[,BAUD]")


def _nmea_talker(key, value) -> str:
    value = _string(key, value)
    if re.fullmatch(r"[A-Z][A-Z0-9]", value):
        return value
    raise _fail(key, value, "a two-character NMEA talker ID such as HC (compass heading sensor) or IN "
                "(integrated navigation)")


def _nmea_sentences(key, value) -> dict[str, float]:
    if not isinstance(value, dict):
        raise _fail(key, value, "a table of sentence rates in Hz, e.g. { HDT = 10.0, ROT = 5.0 } (0 = off)")
    for name in value:
        if name not in SENTENCE_IDS:
            raise ConfigError(f"unknown NMEA sentence {key}.{name}: allowed are " + ", ".join(SENTENCE_IDS))
    return {name: _number(f"{key}.{name}", hz, 0.0, NMEA_MAX_RATE_HZ) for name, hz in value.items()}


def _nmea_serial_baud(url: str) -> int | None:
    if not url.startswith("serial:"):
        return None
    _, _, baud = url.partition(",")
    return int(baud) if baud else NMEA_DEFAULT_BAUD


def nmea_default_rates_hz(url: str) -> dict[str, float]:
    """The sentence rates an output gets unless its table says otherwise (slow serial ports get fewer)."""
    baud = _nmea_serial_baud(url)
    return dict(LOW_SPEED_RATES_HZ if baud is not None and baud < LOW_SPEED_BELOW_BAUD else DEFAULT_RATES_HZ)


@dataclass(frozen=True)
class NmeaOutputConfig:
    """One NMEA 0183 output: where (`url`), as which talker, which sentences at which rates (Hz, 0 = off).
    A serial output is checked against its baud rate (8N1: baud/10 bytes/s) with each sentence at its
    longest, and refused when they do not fit."""

    url: str
    talker: str = "HC"
    sentences: tuple[tuple[str, float], ...] = ()    # overrides of nmea_default_rates_hz(url)

    @classmethod
    def parse(cls, d: dict, prefix="nmea") -> "NmeaOutputConfig":
        parsed = _parse_output_table(cls, d, prefix, "udp:127.0.0.1:10110", {
            "url": _nmea_url, "talker": _nmea_talker, "sentences": _nmea_sentences})
        parsed["sentences"] = tuple(parsed.get("sentences", {}).items())
        cfg = cls(**parsed)
        cfg.check_budget(prefix)
        return cfg

    @property
    def rates_hz(self) -> dict[str, float]:
        """The sentences that are on, Hz."""
        rates = {**nmea_default_rates_hz(self.url), **dict(self.sentences)}
        return {name: hz for name, hz in rates.items() if hz > 0.0}

    @property
    def serial_baud(self) -> int | None:
        return _nmea_serial_baud(self.url)

    def bytes_per_s(self) -> float:
        """What the sentences need at their longest, bytes per second."""
        return sum(hz * worst_case_bytes(name, self.talker) for name, hz in self.rates_hz.items())

    def check_budget(self, prefix="nmea") -> None:
        baud = self.serial_baud
        if baud is None:
            return
        capacity = baud / 10.0
        need = self.bytes_per_s()
        if need > NMEA_BUDGET_FRACTION * capacity:
            listing = ", ".join(f"{name} {hz:g} Hz" for name, hz in self.rates_hz.items())
            raise ConfigError(
                f"{prefix}: {self.url} carries {capacity:.0f} bytes/s at {baud} baud, but {listing} need up to "
                f"{need:.0f} bytes/s: lower the rates (sentences = {{ ... }}) or raise the baud rate (38400 is "
                "NMEA 0183 high speed)")


@dataclass(frozen=True)
class MavlinkConfig:
    system_id: int = 0                  # 0 = latch the first autopilot's system id (1 until then)
    component_id: int = 200             # MAV_COMP_ID_IMU (minimal.xml MAV_COMPONENT)
    mav_type: str = "imu"               # HEARTBEAT.type: "imu" (40) or "onboard_controller" (18)
    accept_broadcast_commands: bool = True  # act on COMMAND_LONG with target_component 0

    @classmethod
    def parse(cls, d: dict, prefix="mavlink") -> "MavlinkConfig":
        return cls(**_parse_table(cls, d, prefix, {
            "system_id": _number_in(0, 255, integer=True), "component_id": _number_in(1, 255, integer=True),
            "mav_type": _choice_of(tuple(MAV_TYPES)), "accept_broadcast_commands": _bool}))


RESTART_YAW_MODES = ("auto", "slew", "reset_counter", "source_set")


class _OutputsParse:
    @classmethod
    def parse(cls, d: dict, prefix="outputs") -> "OutputsConfig":
        checks = {o.config_key: _number_in(0.0, o.max_rate_hz) for o in OUTPUTS}
        checks["heading_slew_deg_s"] = _number_in(MIN_HEADING_SLEW_DEG_S, MAX_HEADING_SLEW_DEG_S)
        checks["restart_slew_deg_s"] = _number_in(MIN_HEADING_SLEW_DEG_S, MAX_HEADING_SLEW_DEG_S)
        checks["reset_counter_on_calibration"] = _bool
        checks["restart_yaw"] = _choice_of(RESTART_YAW_MODES)
        checks["ardupilot_source_set"] = lambda k, v: _choice(k, _number(k, v, 0, 3, integer=True), (0, 2, 3))
        checks["heading_good_sigma_deg"] = _number_in(0.1, 90.0)
        out = cls(**_parse_table(cls, d, prefix, checks))
        if out.restart_yaw == "source_set" and out.ardupilot_source_set == 0:
            raise _fail(f"{prefix}.restart_yaw", "source_set", "needs ardupilot_source_set = 2 or 3")
        return out


# [outputs]: one rate key per entry of daemon.output_registry.OUTPUTS (Hz, 0 = off; HEARTBEAT is always 1 Hz),
# then the calibration-change policy:
# * heading_slew_deg_s: a calibration change moves the VISION_POSITION_ESTIMATE yaw towards the new heading at
#   this rate (EKF3 rejects an external-yaw step beyond its innovation gate in flight);
# * restart_slew_deg_s: the same after a restart with another heading (daemon.restart_heading: the lag of
#   EKF3's yaw behind a ramp must stay inside its smallest gate; docs/daemon.md "Restarts"); both are held to
#   2 °/s while the offset left is large (estimator.slewed_yaw.LARGE_OFFSET_MAX_RATE_RAD_S);
# * reset_counter_on_calibration: also increment VISION_POSITION_ESTIMATE.reset_counter on a calibration change
#   (PX4 EKF2 then resets its yaw; ArduPilot reads it as a position reset): docs/daemon.md "reset_counter".
# * restart_yaw: how a restart with another heading reaches the autopilot (daemon.restart_heading): "slew",
#   "reset_counter" (PX4), "source_set" (ArduPilot, needs ardupilot_source_set), or "auto" (by the autopilot's
#   HEARTBEAT: PX4 → reset_counter, ArduPilot with ardupilot_source_set → source_set, else slew);
# * ardupilot_source_set: 0 (off), or the EKF source set (2, 3) ahrsd may switch ArduPilot to and back to
#   re-align EKF3's yaw (daemon.source_set_realign): identical to set 1 except a yaw source other than ExtNav.
# * heading_good_sigma_deg: "heading good" (MAV_STATE_ACTIVE, SYS_STATUS AHRS healthy) only while the heading
#   state is known (MAGNETOMETER, GNSS_ONLY, LEARNING) with a yaw 1σ below this: not good at once above it, good
#   again once below it for 2 s
#   (daemon.heading_status; 5° as ArduPilot's compass learning trusts a GSF yaw, Compass_learn.cpp).
OutputsConfig = dataclasses.make_dataclass(
    "OutputsConfig",
    [(o.config_key, float, field(default=o.default_hz)) for o in OUTPUTS]
    + [("heading_slew_deg_s", float, field(default=2.0)), ("restart_slew_deg_s", float, field(default=3.0)),
       ("reset_counter_on_calibration", bool, field(default=False)),
       ("restart_yaw", str, field(default="auto")), ("ardupilot_source_set", int, field(default=0)),
       ("heading_good_sigma_deg", float, field(default=5.0))],
    bases=(_OutputsParse,), frozen=True)
OutputsConfig.__module__ = __name__
OutputsConfig.__doc__ = "Message rates in Hz (0 = off), one per output of the registry, and the heading slew."


@dataclass(frozen=True)
class StateConfig:
    dir: str = ""   # "" = core.state_dir.default_state_dir: $STATE_DIRECTORY, /var/lib/ahrsd, ~/.local/state/ahrsd

    @classmethod
    def parse(cls, d: dict, prefix="state") -> "StateConfig":
        return cls(**_parse_table(cls, d, prefix, {"dir": _string}))

    def resolve(self, environ=os.environ) -> Path:
        return Path(self.dir).expanduser() if self.dir else default_state_dir(environ)


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 signing (mavlink.io en/guide/message_signing.md). The key is read from a file and never logged."""

    key_file: str = ""                  # 32 raw bytes, or 64 hex characters; "" = signing off
    link_id: int = 0
    refuse_unsigned_commands: bool = True   # state-changing commands and PARAM_SET must be signed

    @classmethod
    def parse(cls, d: dict, prefix="signing") -> "SigningConfig":
        return cls(**_parse_table(cls, d, prefix, {
            "key_file": _string, "link_id": _number_in(0, 255, integer=True), "refuse_unsigned_commands": _bool}))


@dataclass(frozen=True)
class DaemonConfig:
    status_line: str = "auto"   # "auto" (when stdout is a terminal), "on", "off"

    @classmethod
    def parse(cls, d: dict, prefix="daemon") -> "DaemonConfig":
        return cls(**_parse_table(cls, d, prefix, {"status_line": _choice_of(("auto", "on", "off"))}))


@dataclass(frozen=True)
class LogConfig:
    """On-vehicle logs (docs/logging.md): raw samples as .csv.gz, MAVLink traffic as .tlog."""

    enabled: bool | None = None   # None = on when run by systemd (NOTIFY_SOCKET or INVOCATION_ID set), else off
    dir: str = ""                 # "" = <state dir>/logs
    max_total_mb: float = 1024.0  # all the log files together (each log its share, oldest files deleted first)
    rotate_mb: float = 64.0       # a new file at this size ...
    rotate_s: float = 3600.0      # ... or this age
    samples: bool = True          # raw driver samples
    tlog: bool = True             # every MAVLink frame in and out

    @classmethod
    def parse(cls, d: dict, prefix="log") -> "LogConfig":
        cfg = cls(**_parse_table(cls, d, prefix, {
            "enabled": _bool, "dir": _string, "max_total_mb": _number_in(1.0, 1e7),
            "rotate_mb": _number_in(0.01, 1e6), "rotate_s": _number_in(1.0, 7 * 86400.0),
            "samples": _bool, "tlog": _bool}))
        if cfg.rotate_mb > cfg.max_total_mb:
            raise _fail(f"{prefix}.rotate_mb", cfg.rotate_mb, f"at most max_total_mb ({cfg.max_total_mb:g})")
        return cfg

    def is_enabled(self, environ=os.environ) -> bool:
        if self.enabled is not None:
            return self.enabled
        return bool(environ.get("NOTIFY_SOCKET") or environ.get("INVOCATION_ID"))

    def resolve_dir(self, state_dir: Path) -> Path:
        return Path(self.dir).expanduser() if self.dir else Path(state_dir) / "logs"


def _unknown(key: str, cls) -> ConfigError:
    if cls is None:
        return ConfigError(f"unknown config section [{key}]: allowed sections are " + ", ".join(SECTIONS))
    allowed = ", ".join(f.name for f in dataclasses.fields(cls))
    return ConfigError(f"unknown config key {key}: allowed keys are {allowed}")


@dataclass(frozen=True)
class Config:
    sensor: SensorConfig = field(default_factory=SensorConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    location: LocationConfig = field(default_factory=LocationConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    endpoints: tuple[EndpointConfig, ...] = (EndpointConfig(DEFAULT_ENDPOINT),)
    nmea: tuple[NmeaOutputConfig, ...] = ()
    outputs: OutputsConfig = field(default_factory=OutputsConfig)
    state: StateConfig = field(default_factory=StateConfig)
    signing: SigningConfig = field(default_factory=SigningConfig)
    daemon: DaemonConfig = field(default_factory=DaemonConfig)
    log: LogConfig = field(default_factory=LogConfig)
    magcal: Any = None      # daemon.magcal_settings.MagCalSettings, or None for its defaults
    source_path: str = ""   # the file this came from ("" = built-in defaults)

    @property
    def estimator_name(self) -> str:
        """The estimator to run: the configured name, else AIDED_ESTIMATOR with a GNSS source, else UNAIDED."""
        if self.estimator.name:
            return self.estimator.name
        return AIDED_ESTIMATOR if self.gnss.source != "none" else UNAIDED_ESTIMATOR

    @property
    def estimator_options(self) -> dict:
        """What the estimator needs from the rest of the configuration: the aided one, the antenna lever arm."""
        return {"lever_arm_m": self.gnss.lever_arm_m} if self.estimator_name == AIDED_ESTIMATOR else {}

    def check(self, rate_key: str = "sensor.rate_hz") -> None:
        """The checks that involve several sections or a flag (run by with_overrides, once the flags are in): the
        rate against the source (--rate-hz, --iio or --replay may have replaced the file's; rate_key names where
        the rate came from)."""
        self.sensor.check_rate(rate_key)
        if self.gnss.source == "replay" and self.sensor.source != "replay":
            raise _fail("gnss.source", "replay", "a GNSS recording replays in step with an IMU recording: "
                        "needs [sensor] source = 'replay' (--replay REC)")
        if self.gnss.source == "sim" and self.sensor.source != "sim":
            raise _fail("gnss.source", "sim", "the simulated receiver follows the simulated sensor's scenario: "
                        "needs [sensor] source = 'sim' (--sim SCENARIO)")

    def with_overrides(self, *, sim: str | None = None, spi: str | None = None, replay: str | None = None,
                       iio: str | None = None,
                       mavlink: list[str] | None = None, state_dir: str | None = None,
                       replay_speed: float | None = None, gnss_replay: str | None = None,
                       gnss_serial: str | None = None, gnss_sim: bool = False,
                       estimator: str | None = None,
                       log_dir: str | None = None, log_enabled: bool | None = None,
                       nmea: list[str] | None = None, rate_hz: float | None = None) -> "Config":
        """Apply command-line flags (they win over the file); values are validated like file values, in the order
        of the steps below (the first bad flag is the one reported)."""
        if sum(bool(x) for x in (gnss_replay, gnss_serial, gnss_sim)) > 1:
            raise ConfigError("--gnss-replay, --gnss-serial and --gnss-sim are mutually exclusive")
        if sum(x is not None for x in (sim, spi, replay, iio)) > 1:
            raise ConfigError("--sim, --spi, --iio and --replay are mutually exclusive")
        cfg = self._with_sensor_flag(sim=sim, spi=spi, replay=replay, iio=iio)
        if rate_hz is not None:
            cfg = dataclasses.replace(cfg, sensor=dataclasses.replace(
                cfg.sensor, rate_hz=_number("--rate-hz", rate_hz, MIN_RATE_HZ, CHIP_DEFAULT_RATE_HZ)))
        cfg = cfg._with_output_flags(mavlink, nmea)
        if state_dir is not None:
            cfg = dataclasses.replace(cfg, state=StateConfig(dir=state_dir))
        if replay_speed is not None:
            cfg = dataclasses.replace(cfg, sensor=dataclasses.replace(
                cfg.sensor, replay_speed=_number("--replay-speed", replay_speed, MIN_REPLAY_SPEED, MAX_REPLAY_SPEED)))
        cfg = cfg._with_gnss_flag(gnss_replay=gnss_replay, gnss_serial=gnss_serial, gnss_sim=gnss_sim)
        if estimator is not None:
            cfg = dataclasses.replace(cfg, estimator=EstimatorConfig(_choice("--estimator", estimator, ESTIMATORS)))
        cfg = cfg._with_log_flags(log_dir, log_enabled)
        cfg.gnss.check("gnss")
        cfg.check(rate_key="sensor.rate_hz" if rate_hz is None else "--rate-hz")
        return cfg

    def _with_sensor_flag(self, *, sim: str | None, spi: str | None, replay: str | None,
                          iio: str | None) -> "Config":
        """The sensor source one of --sim, --spi, --iio, --replay names (at most one is given)."""
        sensor = self.sensor
        if iio is not None:
            if not iio:
                raise _fail("--iio", iio, "an IIO device: iio:device0, its name (adis16405) or its sysfs directory")
            sensor = dataclasses.replace(sensor, source="iio", iio_device=iio)
        if sim is not None:
            sensor = dataclasses.replace(sensor, source="sim", scenario=_choice("--sim", sim, SCENARIOS))
        if spi is not None:
            if not spi.startswith("/dev/"):
                raise _fail("--spi", spi, "a device path such as /dev/spidev0.0")
            sensor = dataclasses.replace(sensor, source="spi", spi_device=spi)
        if replay is not None:
            sensor = dataclasses.replace(sensor, source="replay", replay_file=replay)
        return self if sensor is self.sensor else dataclasses.replace(self, sensor=sensor)

    def _with_output_flags(self, mavlink: list[str] | None, nmea: list[str] | None) -> "Config":
        """--mavlink URLs replace the configured endpoints, --nmea URLs the NMEA outputs (each within its line's
        budget)."""
        cfg = self
        if mavlink:
            cfg = dataclasses.replace(cfg, endpoints=tuple(
                EndpointConfig(_endpoint_url("--mavlink", url)) for url in mavlink))
        if nmea:
            outputs = tuple(NmeaOutputConfig(_nmea_url("--nmea", url)) for url in nmea)
            for i, out in enumerate(outputs):
                out.check_budget(f"--nmea {nmea[i]}")
            cfg = dataclasses.replace(cfg, nmea=outputs)
        return cfg

    def _with_gnss_flag(self, *, gnss_replay: str | None, gnss_serial: str | None, gnss_sim: bool) -> "Config":
        """The GNSS source one of --gnss-replay, --gnss-serial DEVICE[,BAUD], --gnss-sim names (at most one)."""
        gnss = self.gnss
        if gnss_replay is not None:
            gnss = dataclasses.replace(gnss, source="replay", file=gnss_replay)
        if gnss_serial is not None:
            device, _, baud = gnss_serial.partition(",")
            gnss = dataclasses.replace(gnss, source="serial", device=_gnss_device("--gnss-serial", device))
            if baud:
                if not baud.isdigit() or int(baud) not in GNSS_BAUDS:
                    raise _fail("--gnss-serial", gnss_serial, "DEVICE or DEVICE,BAUD with BAUD one of "
                                + ", ".join(map(str, GNSS_BAUDS)))
                gnss = dataclasses.replace(gnss, baud=int(baud))
        if gnss_sim:
            gnss = dataclasses.replace(gnss, source="sim")
        return self if gnss is self.gnss else dataclasses.replace(self, gnss=gnss)

    def _with_log_flags(self, log_dir: str | None, log_enabled: bool | None) -> "Config":
        """--log-dir turns logging on unless --no-log (log_enabled False) says otherwise."""
        log = self.log
        if log_dir is not None:
            log = dataclasses.replace(log, dir=_string("--log-dir", log_dir), enabled=True)
        if log_enabled is not None:
            log = dataclasses.replace(log, enabled=log_enabled)
        return self if log is self.log else dataclasses.replace(self, log=log)


SECTIONS = {
    "sensor": SensorConfig, "estimator": EstimatorConfig, "gnss": GnssConfig, "location": LocationConfig, "mavlink": MavlinkConfig,
    "endpoint": EndpointConfig, "outputs": OutputsConfig, "state": StateConfig, "signing": SigningConfig,
    "daemon": DaemonConfig, "log": LogConfig, "magcal": None, "nmea": NmeaOutputConfig,
}


def _parse_magcal(value) -> Any:
    """[magcal] belongs to the field magnetometer calibration, which validates it."""
    if not isinstance(value, dict):
        raise _fail("magcal", value, "a [magcal] table")
    try:
        return settings_from_mapping(value)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def parse_config(doc: dict, source_path: str = "") -> Config:
    """Validate a parsed TOML document into a Config (raises ConfigError)."""
    parts: dict[str, Any] = {"source_path": source_path}
    for section, value in doc.items():
        if section not in SECTIONS:
            raise _unknown(section, None)
        if section == "endpoint":
            if not isinstance(value, list) or not value:
                raise _fail("endpoint", value, "one or more [[endpoint]] tables, each with url = \"...\"")
            parts["endpoints"] = tuple(EndpointConfig.parse(t, f"endpoint[{i}]") for i, t in enumerate(value))
            continue
        if section == "magcal":
            parts["magcal"] = _parse_magcal(value)
            continue
        if section == "nmea":
            if not isinstance(value, list):
                raise _fail("nmea", value, "one or more [[nmea]] tables, each with url = \"...\"")
            parts["nmea"] = tuple(NmeaOutputConfig.parse(t, f"nmea[{i}]") for i, t in enumerate(value))
            continue
        if not isinstance(value, dict):
            raise _fail(section, value, f"a [{section}] table")
        parts[section] = SECTIONS[section].parse(value)
    return Config(**parts)


def load_config(path: str | os.PathLike) -> Config:
    """Read and validate a TOML config file (raises ConfigError with the file name on any problem)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file {path} does not exist") from None
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:      # tomllib decodes UTF-8 itself: binary junk must not escape as a traceback
        raise ConfigError(f"config file {path} is not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    try:
        return parse_config(doc, str(path))
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def default_config_path(environ=os.environ) -> Path | None:
    """The file `ahrsd run` reads without --config: $CONFIGURATION_DIRECTORY/ahrsd.toml or /etc/ahrsd/ahrsd.toml."""
    if environ.get("CONFIGURATION_DIRECTORY"):
        candidate = Path(environ["CONFIGURATION_DIRECTORY"].split(":")[0]) / "ahrsd.toml"
        if candidate.is_file():
            return candidate
    return DEFAULT_CONFIG_PATH if DEFAULT_CONFIG_PATH.is_file() else None
