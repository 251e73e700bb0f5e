"""The calibration store: one human-readable JSON file in the state directory, written atomically.

Layout of `state_dir` (the service's `/var/lib/ahrsd`, systemd `StateDirectory=ahrsd`; the default when none is
given: core.state_dir):

    calibration.json        the calibration in force
    calibration.prev.json   the previous good calibration (rotated in by every save)

File format (JSON, indented, keys sorted)::

    {"format": "ahrsd-calibration", "schema_version": 1, "sha256": "<hex>", "calibration": {...}}

`sha256` is over the canonical JSON of the "calibration" object (sorted keys, no whitespace), so
re-indenting the file does not break it but changing any number does. `calibration` is
`Calibration.to_dict()`.

`save()` writes a temp file in the same directory, fsyncs it, copies the current good file to
`calibration.prev.json` the same way, renames the temp file over `calibration.json` and fsyncs the
directory: a crash at any point leaves a valid file (the old or the new) under one of the two names.

`load()` tries `calibration.json`, then `calibration.prev.json`, then falls back to the identity
calibration, logging why; `last_load` tells which file was used and why the others were not.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from .atomic_file import write_atomic
from .models import SCHEMA_VERSION, Calibration, InvalidCalibrationError

log = logging.getLogger(__name__)

FILE_FORMAT = "ahrsd-calibration"
CURRENT_NAME = "calibration.json"
PREVIOUS_NAME = "calibration.prev.json"
MAX_FILE_BYTES = 1_000_000  # a calibration is ~2 kB; anything this big is not one


class CalibrationFileError(InvalidCalibrationError):
    """A calibration file cannot be used. `path` and `reason` say which and why."""

    def __init__(self, path: os.PathLike | str, reason: str):
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def _canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def checksum(calibration_dict: dict) -> str:
    """sha256 hex of the canonical JSON of a `Calibration.to_dict()`."""
    return hashlib.sha256(_canonical(calibration_dict)).hexdigest()


def encode_calibration(cal: Calibration) -> bytes:
    """The file bytes for `cal` (the envelope with format, schema version and checksum)."""
    body = cal.to_dict()
    envelope = {"format": FILE_FORMAT, "schema_version": SCHEMA_VERSION, "sha256": checksum(body), "calibration": body}
    return (json.dumps(envelope, indent=2, sort_keys=True, allow_nan=False) + "\n").encode("utf-8")


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name} in file")


def decode_calibration(data: bytes, path: os.PathLike | str = "<bytes>") -> Calibration:
    """Parse and check file bytes; raises `CalibrationFileError` with the reason."""
    if len(data) == 0:
        raise CalibrationFileError(path, "file is empty (truncated write?)")
    if len(data) > MAX_FILE_BYTES:
        raise CalibrationFileError(path, f"file is {len(data)} bytes, too large to be a calibration")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CalibrationFileError(path, f"corrupt: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        envelope = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        truncated = exc.pos >= len(text.rstrip())  # ran out of text mid-object
        what = "truncated" if truncated else "corrupt"
        raise CalibrationFileError(path, f"{what}: invalid JSON at line {exc.lineno} column {exc.colno} ({exc.msg})") from None
    except ValueError as exc:  # NaN / Infinity
        raise CalibrationFileError(path, str(exc)) from None
    if not isinstance(envelope, dict):
        raise CalibrationFileError(path, "corrupt: top level is not a JSON object")
    if envelope.get("format") != FILE_FORMAT:
        raise CalibrationFileError(path, f"not an ahrsd calibration file (format {envelope.get('format')!r})")
    version = envelope.get("schema_version")
    if version != SCHEMA_VERSION:
        raise CalibrationFileError(
            path, f"wrong schema version {version!r}: this ahrsd reads version {SCHEMA_VERSION}"
        )
    for key in ("sha256", "calibration"):
        if key not in envelope:
            raise CalibrationFileError(path, f"missing key {key!r}")
    body = envelope["calibration"]
    try:
        actual = checksum(body)
    except (TypeError, ValueError) as exc:
        raise CalibrationFileError(path, f"corrupt calibration object ({exc})") from None
    if actual != envelope["sha256"]:
        raise CalibrationFileError(
            path, f"bad checksum: file says {str(envelope['sha256'])[:16]}…, contents hash to {actual[:16]}… "
            "(edited or corrupted; re-run the calibration)"
        )
    try:
        return Calibration.from_dict(body)
    except InvalidCalibrationError as exc:
        raise CalibrationFileError(path, str(exc)) from None


def load_calibration_file(path: os.PathLike | str) -> Calibration:
    """Read one calibration file. Raises `CalibrationFileError` (missing, unreadable, corrupt, truncated,
    wrong version, bad checksum, missing keys, non-finite numbers, wrong shapes, singular matrices)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationFileError(path, "file does not exist") from None
    except OSError as exc:
        raise CalibrationFileError(path, f"cannot read: {exc.strerror or exc}") from None
    return decode_calibration(data, path)


def _write_atomic(path: Path, data: bytes) -> None:
    """Calibration files are readable by the operator (0644); see atomic_file.write_atomic."""
    write_atomic(path, data, mode=0o644)


@dataclass(frozen=True)
class LoadReport:
    """What `CalibrationStore.load()` used: source is 'current', 'previous' or 'identity'."""

    source: str
    path: Path | None
    problems: tuple[str, ...] = field(default=())

    def describe(self) -> str:
        used = f"{self.source} ({self.path})" if self.path else self.source
        return used if not self.problems else f"{used}; " + "; ".join(self.problems)


class CalibrationStore:
    """Load and save the calibration in `state_dir` (see the module docstring)."""

    def __init__(self, state_dir: os.PathLike | str):
        self.state_dir = Path(state_dir)
        self.current_path = self.state_dir / CURRENT_NAME
        self.previous_path = self.state_dir / PREVIOUS_NAME
        self.last_load: LoadReport | None = None

    def load(self) -> Calibration:
        """The current calibration, else the previous good one, else identity. Never raises for bad files;
        logs a warning naming the file and the reason, and records it in `last_load`."""
        problems: list[str] = []
        for source, path in (("current", self.current_path), ("previous", self.previous_path)):
            try:
                cal = load_calibration_file(path)
            except CalibrationFileError as exc:
                missing = exc.reason == "file does not exist"
                problems.append(f"{source} unusable: {exc}")
                if not missing:
                    log.warning("calibration %s file rejected: %s", source, exc)
                continue
            self.last_load = LoadReport(source, path, tuple(problems))
            if problems:
                log.warning("using the previous good calibration %s (%s)", path, "; ".join(problems))
            else:
                log.info("calibration loaded from %s", path)
            return cal
        self.last_load = LoadReport("identity", None, tuple(problems))
        if all("file does not exist" in p for p in problems):
            log.info("no calibration in %s yet: using identity (uncalibrated sensors)", self.state_dir)
        else:
            log.warning("no usable calibration in %s: using identity (%s)", self.state_dir, "; ".join(problems))
        return Calibration.identity()

    def save(self, cal: Calibration) -> Path:
        """Write `cal` atomically as the current calibration; the old current (if valid) becomes previous."""
        if not isinstance(cal, Calibration):
            raise TypeError(f"expected a Calibration, got {type(cal).__name__}")
        data = encode_calibration(cal)
        decode_calibration(data, "<new calibration>")  # never write what we could not read back
        self.state_dir.mkdir(parents=True, exist_ok=True)
        try:
            old = self.current_path.read_bytes()
        except FileNotFoundError:
            old = None
        if old is not None:
            try:
                decode_calibration(old, self.current_path)
            except CalibrationFileError as exc:
                log.warning("not keeping the current calibration as previous: %s", exc)
            else:
                _write_atomic(self.previous_path, old)
        _write_atomic(self.current_path, data)
        log.info("calibration saved to %s", self.current_path)
        return self.current_path

    def __repr__(self) -> str:
        return f"CalibrationStore({str(self.state_dir)!r})"

