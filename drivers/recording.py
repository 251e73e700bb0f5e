"""Recordings of raw IMU samples: a CSV format that other tools write and read (a public interface).

The first line is exactly RECORDING_HEADER, optionally followed by more columns:

    t_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,mag_x_ut,mag_y_ut,mag_z_ut[,extra...]

Sensor/body frame as recorded, SI units, accelerometer as specific force (+9.81 on the up axis at rest),
magnetic field in µT. Known extra columns: temp_c, supply_v, flags (SampleFlags as an integer), diag_stat,
counter, and for simulated data the truth attitude truth_qw,truth_qx,truth_qy,truth_qz (body->NED, scalar
first). Any other extra column is kept by name. Lines starting with '#' after the header are comments.
A gzip-compressed recording (`.csv.gz`) is written by name and read transparently (recognised by its magic
bytes, whatever the name); `iter_recording_chunks` reads a long file a chunk of rows at a time.
"""

from __future__ import annotations

import gzip
import itertools
import logging
import math
import os
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import DriverError
from ahrsd.core.sample import ImuSample, SampleFlags

log = logging.getLogger(__name__)

RECORDING_HEADER = ("t_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
                    "mag_x_ut,mag_y_ut,mag_z_ut")
BASE_COLUMNS: tuple[str, ...] = tuple(RECORDING_HEADER.split(","))
SAMPLE_COLUMNS = ("temp_c", "supply_v", "flags", "diag_stat", "counter")   # taken from the ImuSample
TRUTH_COLUMNS = ("truth_qw", "truth_qx", "truth_qy", "truth_qz")
_INT_COLUMNS = {"flags", "diag_stat", "counter"}
CHUNK_ROWS = 65536


class RecordingFormatError(DriverError, ValueError):
    """A recording file that does not follow the format; the message names the file, line and problem."""


# ------------------------------------------------------------------------------------------------ writing
class RecordingWriter:
    """Write samples to a recording, one CSV row each.

    extra_columns: names after the 10 base columns. temp_c, supply_v, flags, diag_stat and counter are taken
    from the sample unless given to `write()`; other columns (e.g. TRUTH_COLUMNS) come from `write(**values)`
    and are written as nan when missing. Rows are flushed every `flush_rows` rows and on close.
    """

    def __init__(self, path: str | os.PathLike, extra_columns: Sequence[str] = (), flush_rows: int = 4096):
        extra = tuple(extra_columns)
        names = BASE_COLUMNS + extra
        bad = [c for c in extra if not c or "," in c or c != c.strip()]
        if bad or len(set(names)) != len(names):
            raise ValueError(f"extra column names must be unique, non-empty, without commas: {extra}")
        self.path = Path(path)
        self.columns = names
        self.extra_columns = extra
        self._flush_rows = flush_rows
        # per extra column: its name, whether it is written as an int, whether the sample has it, its truth index
        self._extra_plan = tuple((name, name in _INT_COLUMNS, name in SAMPLE_COLUMNS,
                                  TRUTH_COLUMNS.index(name) if name in TRUTH_COLUMNS else -1) for name in extra)
        self._row_format = ",".join(["%r"] * len(BASE_COLUMNS)
                                    + ["%d" if n in _INT_COLUMNS else "%r" for n in extra]) + "\n"
        self.rows_written = 0
        self._file = open_text(self.path, "w")
        self._file.write(",".join(names) + "\n")

    def write(self, sample: ImuSample, truth_q_wxyz=None, **values) -> None:
        """One row. `truth_q_wxyz` (4,) fills the truth_q* columns; other keyword values fill extra columns."""
        truth = None
        if truth_q_wxyz is not None:     # over any truth_q* keyword values
            truth = (truth_q_wxyz.tolist() if truth_q_wxyz.__class__ is np.ndarray and truth_q_wxyz.ndim == 1
                     and truth_q_wxyz.dtype == np.float64 else [float(v) for v in truth_q_wxyz])
        row = [float(sample.t_s), *sample.gyro_rad_s.tolist(), *sample.accel_m_s2.tolist(), *sample.mag_ut.tolist()]
        for name, is_int, from_sample, truth_index in self._extra_plan:
            if truth is not None and 0 <= truth_index < len(truth):
                v = truth[truth_index]
            elif name in values:
                v = values[name]
            elif from_sample:
                v = getattr(sample, name)
            else:
                v = math.nan
            row.append(int(v) if is_int else float(v))
        # "%r" of a float is its repr, "%d" of an int its str: the row as repr/str would write it, in one call
        self._file.write(self._row_format % tuple(row))
        self.rows_written += 1
        if self.rows_written % self._flush_rows == 0:
            self._file.flush()

    def comment(self, text: str) -> None:
        """A '#' comment line (readers skip it): e.g. where the samples came from."""
        for line in text.splitlines() or [""]:
            self._file.write("# " + line + "\n")

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ------------------------------------------------------------------------------------------------ reading
@dataclass(frozen=True)
class Recording:
    """A recording in memory: the base columns as arrays plus every extra column by name."""

    path: Path
    columns: tuple[str, ...]
    t_s: np.ndarray               # (n,)
    gyro_rad_s: np.ndarray        # (n, 3)
    accel_m_s2: np.ndarray        # (n, 3)
    mag_ut: np.ndarray            # (n, 3)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_s)

    def __getitem__(self, name: str) -> np.ndarray:
        """Any column by name (base or extra)."""
        if name in self.extra:
            return self.extra[name]
        if name not in BASE_COLUMNS:
            raise KeyError(f"{self.path}: no column {name!r} (columns: {', '.join(self.columns)})")
        i = BASE_COLUMNS.index(name)
        if i == 0:
            return self.t_s
        return (self.gyro_rad_s, self.accel_m_s2, self.mag_ut)[(i - 1) // 3][:, (i - 1) % 3]

    @property
    def truth_q_wxyz(self) -> np.ndarray | None:
        """(n, 4) truth attitude if the recording has the truth columns, else None."""
        if all(c in self.extra for c in TRUTH_COLUMNS):
            return np.column_stack([self.extra[c] for c in TRUTH_COLUMNS])
        return None

    @property
    def sample_rate_hz(self) -> float:
        """Median sample rate from the timestamps (nan with fewer than two samples)."""
        if len(self.t_s) < 2:
            return math.nan
        return 1.0 / float(np.median(np.diff(self.t_s)))

    def samples(self) -> Iterator[ImuSample]:
        yield from _samples_from_table(self.columns, self._table())

    def _table(self) -> np.ndarray:
        base = np.column_stack([self.t_s, self.gyro_rad_s, self.accel_m_s2, self.mag_ut])
        if not self.extra:
            return base
        return np.column_stack([base] + [self.extra[c] for c in self.columns[len(BASE_COLUMNS):]])


def check_recording(path: str | os.PathLike) -> tuple[str, ...]:
    """Open a recording and validate its header (the columns); raises OSError or RecordingFormatError naming the
    file. A run that replays it checks this first, so a wrong path fails at once with one line."""
    if os.path.isdir(path):
        raise RecordingFormatError(f"{path}: is a directory, not a recording")
    with open_text(path) as f:
        try:
            line = f.readline()
        except (EOFError, gzip.BadGzipFile, zlib.error, UnicodeDecodeError) as exc:
            raise RecordingFormatError(f"{path}: cannot read the header: {exc}") from None
    return read_header(line, path)


def read_header(line: str, path: str | os.PathLike = "<recording>") -> tuple[str, ...]:
    """Validate a header line; returns the column names. Raises RecordingFormatError saying what is wrong."""
    names = tuple(c.strip() for c in line.lstrip("\ufeff").rstrip("\r\n").split(","))
    if not line.strip():
        raise RecordingFormatError(f"{path}: empty file or empty header line (expected: {RECORDING_HEADER})")
    for i, want in enumerate(BASE_COLUMNS):
        if i >= len(names):
            raise RecordingFormatError(
                f"{path}: header has {len(names)} columns, the first {len(BASE_COLUMNS)} must be {RECORDING_HEADER} "
                f"(missing: {', '.join(BASE_COLUMNS[i:])})")
        if names[i] != want:
            raise RecordingFormatError(
                f"{path}: header column {i + 1} is {names[i]!r} but must be {want!r} "
                f"(the header must start with {RECORDING_HEADER})")
    extra = names[len(BASE_COLUMNS):]
    if any(not c for c in extra):
        raise RecordingFormatError(f"{path}: header has an empty column name after the base columns")
    dup = sorted({c for c in names if names.count(c) > 1})
    if dup:
        raise RecordingFormatError(f"{path}: header repeats column(s) {', '.join(dup)}")
    return names


def _parse_chunk(lines: list[str], ncols: int, first_line_no: int, path, columns) -> np.ndarray:
    try:
        table = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=np.float64, comments="#")
        if table.size == 0:
            return np.empty((0, ncols))
        if table.shape[1] == ncols:  # never reshape: rows all one field short must not be re-cut silently
            return table
    except ValueError:
        pass
    # find and name the offending line
    for k, line in enumerate(lines):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        fields = text.split(",")
        where = f"{path}: line {first_line_no + k}"
        if len(fields) != ncols:
            raise RecordingFormatError(f"{where}: {len(fields)} fields, expected {ncols} (truncated or extra values?)")
        for name, value in zip(columns, fields):
            try:
                float(value)
            except ValueError:
                raise RecordingFormatError(f"{where}, column {name!r}: {value.strip()!r} is not a number") from None
    raise RecordingFormatError(f"{path}: cannot parse rows {first_line_no}..{first_line_no + len(lines) - 1}")


GZIP_MAGIC = b"\x1f\x8b"


def open_text(path: str | os.PathLike, mode: str = "r"):
    """A recording opened as text: mode "r" (UTF-8; gzip recognised by its magic bytes, whatever the name) or
    "w" (ASCII; gzip when the name ends in `.gz`)."""
    if mode not in ("r", "w"):
        raise ValueError(f"mode must be 'r' or 'w', got {mode!r}")
    if mode == "r":
        with open(path, "rb") as raw:
            compressed = raw.read(2) == GZIP_MAGIC
        if compressed:
            return gzip.open(path, "rt", encoding="utf-8", newline="")
        return open(path, "r", encoding="utf-8", newline="")
    if os.fspath(path).endswith(".gz"):
        return gzip.open(path, "wt", encoding="ascii", newline="\n")
    return open(path, "w", encoding="ascii", newline="\n")


def _complete_lines(f, path) -> Iterator[str]:
    """The lines of `f`; a gzip stream cut short (a logger killed, a power loss) ends at what it holds, with
    a warning: its last line may then be incomplete, which `_iter_tables` drops when not strict."""
    try:
        yield from f
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:
        log.warning("%s: the compressed stream ends early (%s): reading what it holds", path, exc)


def _iter_tables(path, strict: bool, chunk_rows: int = CHUNK_ROWS) -> Iterator[tuple[tuple[str, ...], np.ndarray]]:
    with open_text(path) as f:
        lines_in = _complete_lines(f, path)
        header = next(lines_in, "")
        columns = read_header(header, path)
        ncols = len(columns)
        line_no = 2
        rows_before = 0
        while True:
            lines = list(itertools.islice(lines_in, chunk_rows))
            if not lines:
                break
            cut_line = None   # only a file's last line can lack its newline
            if not strict and not lines[-1].endswith("\n"):
                last = lines[-1].strip()
                if last and len(last.split(",")) != ncols:
                    cut_line = line_no + len(lines) - 1
                    lines = lines[:-1]
            table = _parse_chunk(lines, ncols, line_no, path, columns) if lines else np.empty((0, ncols))
            line_no += len(lines)
            rows_before += len(table)
            if cut_line is not None:
                log.warning("%s: line %d is incomplete (the file ends mid-row): using the %d complete rows before it",
                            path, cut_line, rows_before)
            yield columns, table


def read_recording(path: str | os.PathLike, strict: bool = True, on_rows=None,
                   chunk_rows: int = CHUNK_ROWS) -> Recording:
    """Load a whole recording (numpy, `chunk_rows` rows at a time). Any file whose header starts with the 10 base
    columns works; `.csv.gz` is read transparently.

    strict=False drops an incomplete final line (a recorder killed mid-write) with a warning instead of failing.
    on_rows(n): called after each chunk of n rows (a progress bar).
    """
    columns: tuple[str, ...] = ()
    tables = []
    for columns, table in _iter_tables(path, strict, chunk_rows):
        tables.append(table)
        if on_rows is not None:
            on_rows(len(table))
    if not columns:
        raise RecordingFormatError(f"{path}: empty file")
    data = np.concatenate(tables) if tables else np.empty((0, len(columns)))
    return _recording(path, columns, data)


def iter_recording_chunks(path: str | os.PathLike, strict: bool = True,
                          chunk_rows: int = CHUNK_ROWS) -> Iterator[Recording]:
    """Read a recording as consecutive Recordings of up to `chunk_rows` rows each (constant memory for a
    long file: one chunk at a time). Same checks and messages as `read_recording`; `.csv.gz` too."""
    for columns, table in _iter_tables(path, strict, chunk_rows):
        if len(table):
            yield _recording(path, columns, table)


def _recording(path, columns: tuple[str, ...], data: np.ndarray) -> Recording:
    nb = len(BASE_COLUMNS)
    extra = {name: np.ascontiguousarray(data[:, nb + i]) for i, name in enumerate(columns[nb:])}
    return Recording(Path(path), columns, np.ascontiguousarray(data[:, 0]), np.ascontiguousarray(data[:, 1:4]),
                     np.ascontiguousarray(data[:, 4:7]), np.ascontiguousarray(data[:, 7:10]), extra)


def iter_samples(path: str | os.PathLike, strict: bool = True, chunk_rows: int = CHUNK_ROWS) -> Iterator[ImuSample]:
    """Replay a recording as ImuSamples, `chunk_rows` rows at a time (constant memory for long files).

    Columns the file lacks take ImuSample's defaults (temp/supply NaN, flags NONE, diag_stat 0); without a
    counter column the counter is the row index.
    """
    first_index = 0
    flag_cache: dict[int, SampleFlags] = {}
    for columns, table in _iter_tables(path, strict, chunk_rows):
        yield from _samples_from_table(columns, table, first_index, flag_cache)
        first_index += len(table)


def _samples_from_table(columns: tuple[str, ...], table: np.ndarray, first_index: int = 0,
                        flag_cache: dict[int, SampleFlags] | None = None) -> Iterator[ImuSample]:
    """The rows of `table` as ImuSamples; each sample's vectors are rows of per-chunk (n, 3) arrays, and the
    scalar columns are converted for the whole chunk at once (a replay reads ~10⁵ samples a second)."""
    n = len(table)
    if n == 0:
        return
    idx = {name: i for i, name in enumerate(columns)}
    t = table[:, 0].tolist()
    gyro = np.ascontiguousarray(table[:, 1:4])
    accel = np.ascontiguousarray(table[:, 4:7])
    mag = np.ascontiguousarray(table[:, 7:10])
    nans = [math.nan] * n
    temp = table[:, idx["temp_c"]].tolist() if "temp_c" in idx else nans
    supply = table[:, idx["supply_v"]].tolist() if "supply_v" in idx else nans
    flags = _int_column(table, idx.get("flags"), [0] * n)
    diag = _int_column(table, idx.get("diag_stat"), [0] * n)
    counter = _int_column(table, idx.get("counter"), range(first_index, first_index + n))
    cache = {} if flag_cache is None else flag_cache   # the IntFlag constructor is slow; few values occur
    for k in range(n):
        f = flags[k]
        sample_flags = cache.get(f)
        if sample_flags is None:
            sample_flags = cache[f] = SampleFlags(f)
        yield ImuSample(t[k], gyro[k], accel[k], mag[k], temp[k], supply[k], sample_flags, diag[k], counter[k])


def _int_column(table: np.ndarray, i: int | None, missing) -> list[int]:
    """Column i as Python ints; `missing` where the file has no such column, and its entry where a value is NaN."""
    if i is None:
        return list(missing)
    column = table[:, i]
    finite = np.isfinite(column)
    if finite.all():
        return column.astype(np.int64).tolist()
    return np.where(finite, column, np.asarray(missing, dtype=np.float64)).astype(np.int64).tolist()
