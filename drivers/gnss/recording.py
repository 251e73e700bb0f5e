"""Recordings of GNSS fixes: a CSV format beside the IMU recording (a public interface, docs/gnss.md).

The first line begins exactly with GNSS_RECORDING_HEADER, optionally followed by more columns:

    t_s,lat_deg,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s[,h_acc_m,v_acc_m,s_acc_m_s,fix_type,num_sats,hdop,...]

`t_s` is the time of validity of the fix on the IMU recording's time base; latitude/longitude WGS-84 degrees,
altitude above the ellipsoid, velocity NED in m/s (vel_d may be nan: not reported). The optional columns may
appear in any subset and order; a missing accuracy column (or an empty/nan cell) takes the default in
`ahrsd.core.gnss` (DEFAULT_H_ACC_M, DEFAULT_V_ACC_M, DEFAULT_S_ACC_M_S), a missing fix_type is 3 (3D fix), a
missing num_sats -1 (not reported). Any other column is kept by name in `GnssFix.extra`. Lines starting with
'#' after the header are comments. A file name ending in `.gz` is read and written gzip-compressed.
"""

from __future__ import annotations

import gzip
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TextIO

from ..errors import DriverError
from ahrsd.core.gnss import (DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, DEFAULT_V_ACC_M, GnssFix, GnssFixType,
                             make_fix)

GNSS_RECORDING_HEADER = "t_s,lat_deg,lon_deg,alt_m,vel_n_m_s,vel_e_m_s,vel_d_m_s"
GNSS_BASE_COLUMNS: tuple[str, ...] = tuple(GNSS_RECORDING_HEADER.split(","))
# The optional columns the reader maps onto GnssFix fields; the writer always writes them.
GNSS_OPTIONAL_COLUMNS = ("h_acc_m", "v_acc_m", "s_acc_m_s", "fix_type", "num_sats", "hdop")
_ACCURACY_DEFAULTS = {"h_acc_m": DEFAULT_H_ACC_M, "v_acc_m": DEFAULT_V_ACC_M, "s_acc_m_s": DEFAULT_S_ACC_M_S}
_MISSING = ("", "nan", "NaN", "NAN")


class GnssRecordingFormatError(DriverError, ValueError):
    """A GNSS recording that does not follow the format; the message names the file, line and problem."""


def gnss_path_for(recording_path: str | os.PathLike) -> Path:
    """The GNSS recording beside an IMU recording: boat.csv -> boat.gnss.csv, boat.csv.gz -> boat.gnss.csv.gz."""
    path = Path(recording_path)
    name = path.name
    for suffix in (".csv.gz", ".csv"):
        if name.endswith(suffix):
            return path.with_name(name[: -len(suffix)] + ".gnss" + suffix)
    return path.with_name(name + ".gnss.csv")


def _open_text(path: Path, mode: str) -> TextIO:
    if path.name.endswith(".gz"):
        return gzip.open(path, mode + "t", encoding="utf-8", newline="")
    return open(path, mode, encoding="utf-8", newline="")


# ------------------------------------------------------------------------------------------------ writing
class GnssRecordingWriter:
    """Write fixes to a GNSS recording, one CSV row each.

    The header is the 7 base columns, then GNSS_OPTIONAL_COLUMNS, then `extra_columns` (taken from
    `fix.extra` by name, nan when absent). `path` ending in .gz writes gzip.
    """

    def __init__(self, path: str | os.PathLike, extra_columns: Sequence[str] = (), flush_rows: int = 64):
        extra = tuple(extra_columns)
        names = GNSS_BASE_COLUMNS + GNSS_OPTIONAL_COLUMNS + extra
        if len(set(names)) != len(names) or not all(c and "," not in c and c == c.strip() for c in extra):
            raise ValueError(f"extra column names must be unique, non-empty, without commas: {extra}")
        self.path, self.columns, self.extra_columns = Path(path), names, extra
        self.rows_written, self._flush_rows = 0, flush_rows
        self._file = _open_text(self.path, "w")
        self._file.write(",".join(names) + "\n")

    def write(self, fix: GnssFix) -> None:
        vel = fix.vel_ned_m_s
        floats = (fix.t_s, fix.lat_deg, fix.lon_deg, fix.alt_m, vel[0], vel[1], vel[2], fix.h_acc_m, fix.v_acc_m,
                  fix.s_acc_m_s)
        row = [repr(float(v)) for v in floats] + [str(int(fix.fix_type)), str(int(fix.num_sats)), repr(float(fix.hdop))]
        row += [repr(float(fix.extra.get(name, math.nan))) for name in self.extra_columns]
        self._file.write(",".join(row) + "\n")
        self.rows_written += 1
        if self.rows_written % self._flush_rows == 0:
            self.flush()

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        """Close the file (flushes it; a .gz file gets its trailer only here)."""
        self._file.close()

    def __enter__(self) -> "GnssRecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ------------------------------------------------------------------------------------------------ reading
def read_gnss_header(line: str, path: str | os.PathLike = "<gnss recording>") -> tuple[str, ...]:
    """Validate a header line; returns the column names. Raises GnssRecordingFormatError saying what is wrong."""
    if not line.strip():
        raise GnssRecordingFormatError(f"{path}: line 1: empty file or empty header (expected: {GNSS_RECORDING_HEADER})")
    names = tuple(c.strip() for c in line.lstrip("\ufeff").rstrip("\r\n").split(","))
    base = GNSS_BASE_COLUMNS
    if names[:len(base)] != base:
        i = next((i for i, (got, want) in enumerate(zip(names, base)) if got != want), len(names))
        problem = (f"column {i + 1} is {names[i]!r} but must be {base[i]!r}" if i < len(names)
                   else f"{len(names)} columns (missing: {', '.join(base[i:])})")
        raise GnssRecordingFormatError(f"{path}: line 1: header {problem}; it must begin with {GNSS_RECORDING_HEADER}")
    bad = sorted({repr(c) if c else "an empty name" for c in names if not c or names.count(c) > 1})
    if bad:
        raise GnssRecordingFormatError(f"{path}: line 1: header column names must be unique and non-empty: "
                                       f"{', '.join(bad)}")
    return names


def iter_gnss_fixes(path: str | os.PathLike, source: str = "recording") -> Iterator[GnssFix]:
    """Read a GNSS recording one fix at a time. Raises GnssRecordingFormatError naming the bad line.

    Values are not judged here beyond being numbers (nan is allowed anywhere): the validator at the edge
    (drivers.gnss.validation) counts and rejects implausible fixes, as for a live receiver.
    """
    path = Path(path)
    try:
        f = _open_text(path, "r")
        header = f.readline()
    except (OSError, EOFError, UnicodeDecodeError) as exc:   # gzip.BadGzipFile is an OSError
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc   # not errno and path again
        raise GnssRecordingFormatError(f"{path}: cannot read: {reason}") from exc
    with f:
        columns = read_gnss_header(header, path)
        index = {name: i for i, name in enumerate(columns)}
        extra_names = [c for c in columns[len(GNSS_BASE_COLUMNS):] if c not in GNSS_OPTIONAL_COLUMNS]
        line_no = 1
        try:
            for line in f:
                line_no += 1
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                yield _fix_from_row(text.split(","), columns, index, extra_names, f"{path}: line {line_no}", source)
        except (OSError, EOFError, UnicodeDecodeError) as exc:
            raise GnssRecordingFormatError(f"{path}: line {line_no + 1}: cannot read: {exc}") from exc


def read_gnss_recording(path: str | os.PathLike, source: str = "recording") -> list[GnssFix]:
    """The whole GNSS recording as a list of fixes (see iter_gnss_fixes)."""
    return list(iter_gnss_fixes(path, source))


def _fix_from_row(fields: list[str], columns, index, extra_names, where: str, source: str) -> GnssFix:
    if len(fields) != len(columns):
        raise GnssRecordingFormatError(
            f"{where}: {len(fields)} fields, expected {len(columns)} (truncated or extra values?)")

    def number(name: str) -> float:
        text = fields[index[name]].strip()
        try:
            return float(text) if text not in _MISSING else math.nan
        except ValueError:
            raise GnssRecordingFormatError(f"{where}, column {name!r}: {text!r} is not a number") from None

    def integer(name: str, default: int) -> int:
        if name not in index or fields[index[name]].strip() in _MISSING:
            return default
        value = number(name)
        if not value.is_integer():
            raise GnssRecordingFormatError(f"{where}, column {name!r}: {fields[index[name]].strip()!r} is not an integer")
        return int(value)

    base = [number(name) for name in GNSS_BASE_COLUMNS]
    accuracy = {}
    for name, default in _ACCURACY_DEFAULTS.items():
        value = number(name) if name in index else math.nan
        accuracy[name] = value if not math.isnan(value) else default
    fix_code = integer("fix_type", int(GnssFixType.FIX_3D))
    try:
        fix_type = GnssFixType(fix_code)
    except ValueError:
        raise GnssRecordingFormatError(
            f"{where}, column 'fix_type': {fix_code} is not a fix type (0 no GPS, 1 no fix, 2 2D, 3 3D, "
            f"4 DGPS, 5 RTK float, 6 RTK fixed)") from None
    return make_fix(base[0], base[1], base[2], base[3], base[4:7], **accuracy, fix_type=fix_type,
                    num_sats=integer("num_sats", -1), hdop=number("hdop") if "hdop" in index else math.nan,
                    source=source, extra={name: number(name) for name in extra_names})
