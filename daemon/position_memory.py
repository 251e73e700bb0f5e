"""The position the daemon last knew, kept in the state directory (`last_position.json`): a start without a fix
still has the declination of where the vehicle was, and `ahrsd calibrate mag` a reference field.

What others keep (read from their source): PX4's EKF2 with EKF2_DECL_TYPE bit 1 ("save") writes the declination
it used to EKF2_MAG_DECL once per boot while disarmed and starts from it next time, whatever its age (EKF2.cpp,
`_param_ekf2_mag_decl.commit_no_notification`; PX4-Autopilot #10023/#10024); ArduPilot's COMPASS_AUTODEC sets
COMPASS_DEC from the first location without saving it (AP_Compass.cpp `try_set_initial_location`:
`_declination.set`), so every boot starts from the stored COMPASS_DEC; a u-blox receiver keeps its last position
in battery-backed RAM for a hot start. Here the position is kept, not the declination: the WMM gives the
declination at today's date from it (so the position's age adds no secular-variation error), and
`calibrate mag` the whole reference field.

* Saved: the position of the resolver's GNSS receiver or autopilot (daemon.position), never the configured one
  (it is in the config), the simulator's site, or anything during a run of the simulator or a replay (those
  positions are not where the vehicle is: `record` is False there). Written when the vehicle moved more than
  SAVE_DISTANCE_M from the saved position, SAVE_PERIOD_S after the last save (so the date stays the date it
  was last known there), and at shutdown; atomically (calibration/atomic_file.py).
* Used: by daemon.position below the autopilot and above the simulator, when no older than MAX_AGE_DAYS. The
  age does not make the declination wrong; what it stands for is the chance that the vehicle was carried
  elsewhere while switched off, which a limit cannot bound (a shipped vehicle is wrong at any age). A vehicle
  laid up for a season is where it was; one unused for over a year has more likely been moved, serviced or sold,
  and then "no position yet" (a warning, true = magnetic heading until a fix) is safer than a far place taken
  silently. docs/daemon.md ("The remembered position") gives the declination error for a vehicle moved 50 km.
* Rejected (a warning naming the file and the reason, counted in `rejected_files`, never raised, never a
  position): unreadable, not JSON, another format or schema version, missing keys, non-finite or out-of-range
  numbers, an unknown source. A missing file is no rejection: nothing was known yet.
"""

from __future__ import annotations

import datetime
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ahrsd.calibration.atomic_file import write_atomic

log = logging.getLogger(__name__)

FILE_NAME = "last_position.json"
FILE_FORMAT = "ahrsd-last-position"
SCHEMA_VERSION = 1
SAVE_DISTANCE_M = 1000.0        # moved this far from the saved position: save now
SAVE_PERIOD_S = 3600.0          # still here: refresh the saved date this often
MAX_AGE_DAYS = 365.0            # older: not used (module docstring)
REMEMBERED_SOURCES = ("gnss", "autopilot")
ALT_RANGE_M = (-1000.0, 100_000.0)   # below the Dead Sea shore … the edge of space: anything else is not a vehicle
EARTH_RADIUS_M = 6_371_008.8    # mean radius (IUGG): the 1 km save threshold needs no ellipsoid


@dataclass(frozen=True)
class RememberedPosition:
    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str              # where the daemon had it from: "gnss" or "autopilot"
    wall_time_s: float       # when it was last known there (Unix time: the monotonic clock restarts with the host)

    @property
    def saved_date(self) -> datetime.date:
        return datetime.datetime.fromtimestamp(self.wall_time_s, datetime.timezone.utc).date()

    def age_s(self, now_wall_s: float) -> float:
        return now_wall_s - self.wall_time_s

    def too_old(self, now_wall_s: float) -> bool:
        """Older than MAX_AGE_DAYS: not used (the module docstring says why)."""
        return self.age_s(now_wall_s) > MAX_AGE_DAYS * 86400

    def describe_age(self, now_wall_s: float) -> str:
        """"1.2 days old"; a clock behind the saved time (a host without a real-time clock before its time is
        set) cannot tell the age and says so."""
        age = self.age_s(now_wall_s)
        if age < 0:
            return "age unknown (the clock is behind that date)"
        if age < 2 * 3600:
            return f"{age / 60:.0f} min old"
        if age < 2 * 86400:
            return f"{age / 3600:.0f} h old"
        return f"{age / 86400:.1f} days old"


def distance_m(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Great-circle distance on the mean sphere (haversine)."""
    p1, p2 = math.radians(lat1_deg), math.radians(lat2_deg)
    dp, dl = p2 - p1, math.radians(lon2_deg - lon1_deg)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(h)))


class PositionFileError(ValueError):
    """The file cannot give a position; the message says why."""


def decode_position(data: bytes) -> RememberedPosition:
    """Parse and check the file's bytes (raises PositionFileError with the reason)."""
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=lambda name: float("nan"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PositionFileError(f"not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise PositionFileError("not a JSON object")
    if doc.get("format") != FILE_FORMAT or doc.get("schema_version") != SCHEMA_VERSION:
        raise PositionFileError(f"format {doc.get('format')!r} version {doc.get('schema_version')!r}, expected "
                                f"{FILE_FORMAT!r} version {SCHEMA_VERSION}")
    try:
        pos = RememberedPosition(float(doc["lat_deg"]), float(doc["lon_deg"]), float(doc["alt_m"]),
                                 str(doc["source"]), float(doc["wall_time_s"]))
    except KeyError as exc:
        raise PositionFileError(f"missing key {exc}") from None
    except (TypeError, ValueError) as exc:
        raise PositionFileError(f"not a number ({exc})") from None
    if not all(math.isfinite(v) for v in (pos.lat_deg, pos.lon_deg, pos.alt_m, pos.wall_time_s)):
        raise PositionFileError("a number is not finite")
    if not (-90.0 <= pos.lat_deg <= 90.0 and -180.0 <= pos.lon_deg <= 180.0):
        raise PositionFileError(f"position out of range: lat {pos.lat_deg}, lon {pos.lon_deg}")
    if not ALT_RANGE_M[0] <= pos.alt_m <= ALT_RANGE_M[1]:
        raise PositionFileError(f"altitude {pos.alt_m} m out of range")
    if pos.source not in REMEMBERED_SOURCES:
        raise PositionFileError(f"unknown source {pos.source!r}")
    if pos.wall_time_s <= 0.0:
        raise PositionFileError(f"save time {pos.wall_time_s} is not a date")
    return pos


def encode_position(pos: RememberedPosition) -> bytes:
    doc = {"format": FILE_FORMAT, "schema_version": SCHEMA_VERSION, "lat_deg": pos.lat_deg,
           "lon_deg": pos.lon_deg, "alt_m": pos.alt_m, "source": pos.source, "wall_time_s": pos.wall_time_s,
           "saved_utc": datetime.datetime.fromtimestamp(pos.wall_time_s, datetime.timezone.utc)
           .isoformat(timespec="seconds")}      # for the reader; wall_time_s is what is read back
    return (json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n").encode()


def read_position_file(state_dir: Path) -> tuple[RememberedPosition | None, str | None]:
    """(the position, None) or (None, why not); (None, None) when there is no file."""
    path = Path(state_dir) / FILE_NAME
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, f"{path}: cannot read: {exc.strerror or exc}"
    try:
        return decode_position(data), None
    except PositionFileError as exc:
        return None, f"{path}: {exc}"


def _wall_time_s() -> float:
    return time.time()      # host clock: a date persisted across reboots (the monotonic clock restarts)


class PositionMemory:
    """Loads the remembered position at construction; `note` takes each live position the resolver has (saving
    by the rule above), `usable` gives the remembered one while young enough, `save_now` at shutdown."""

    def __init__(self, state_dir: Path, *, record: bool = True,
                 background: Callable[[Callable[[], None]], None] | None = None,
                 wall_clock: Callable[[], float] | None = None):
        self.path = Path(state_dir) / FILE_NAME
        self.record = record
        self.background = background or (lambda fn: fn())
        self.wall_clock = wall_clock or _wall_time_s
        self.rejected_files = 0
        self.saves = 0
        self.save_failures = 0
        self.remembered, problem = read_position_file(Path(state_dir))   # what the last run left
        if problem is not None:
            self.rejected_files += 1
            log.warning("remembered position rejected: %s", problem)
        self._saved = self.remembered       # the position in the file now
        self._latest: RememberedPosition | None = None   # the last live position noted this run

    def usable(self) -> RememberedPosition | None:
        """The last position known: this run's last live one, else the one the last run left; None when there
        is none or it is older than MAX_AGE_DAYS."""
        pos = self._latest or self.remembered
        if pos is None or pos.too_old(self.wall_clock()):
            return None
        return pos

    def note(self, lat_deg: float, lon_deg: float, alt_m: float, source: str) -> None:
        """A live position (GNSS receiver, autopilot): saved when it moved SAVE_DISTANCE_M from the saved one or
        SAVE_PERIOD_S after the last save (a wall clock stepped back counts as due)."""
        if not self.record or source not in REMEMBERED_SOURCES:
            return
        now = self.wall_clock()
        self._latest = RememberedPosition(float(lat_deg), float(lon_deg), float(alt_m), source, now)
        saved = self._saved
        if (saved is None or not 0.0 <= now - saved.wall_time_s < SAVE_PERIOD_S
                or distance_m(saved.lat_deg, saved.lon_deg, lat_deg, lon_deg) > SAVE_DISTANCE_M):
            self._save(self._latest, background=True)

    def save_now(self) -> None:
        """At shutdown: the last live position of this run, when it is not the one saved."""
        if self._latest is not None and self._latest != self._saved:
            self._save(self._latest, background=False)

    def counters(self) -> dict:
        return {"rejected_files": self.rejected_files, "saves": self.saves, "save_failures": self.save_failures}

    def _save(self, pos: RememberedPosition, *, background: bool) -> None:
        self._saved = pos
        data = encode_position(pos)
        (self.background if background else (lambda fn: fn()))(lambda: self._write(data))

    def _write(self, data: bytes) -> None:
        try:
            write_atomic(self.path, data, mode=0o644)
            self.saves += 1
        except OSError as exc:
            self.save_failures += 1
            log.warning("cannot save the position to %s: %s", self.path, exc)
