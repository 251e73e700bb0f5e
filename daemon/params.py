"""The MAVLink parameter set: a fixed, ordered list of REAL32 parameters persisted in the state directory.

Protocol rules this follows (MAVLink parameter protocol, mavlink.io
en/services/parameter.md): names ≤ 16 characters; every value is a float sent as
MAV_PARAM_TYPE_REAL32 (no byte-wise encoding questions); the set (names, count, indices) never changes once the
daemon runs; a write is validated against the parameter's range and, accepted or not, answered by a broadcast
PARAM_VALUE with the value now in force (the caller does the sending).

Persistence: only values written over MAVLink are stored (`params.json`, written atomically);
the config file provides the defaults, so editing the config still takes effect for untouched parameters.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ahrsd.calibration.atomic_file import write_atomic

log = logging.getLogger(__name__)

PARAMS_FILE = "params.json"
SCHEMA_VERSION = 1


@dataclass(frozen=True)
class ParamSpec:
    name: str            # ≤ 16 ASCII characters (PARAM_VALUE.param_id)
    default: float
    lo: float
    hi: float
    description: str     # with the unit
    integer: bool = False
    read_only: bool = False   # shown, never set over MAVLink (the daemon updates it: `ParamStore.show`)
    momentary: bool = False   # a write is a request: applied (on_change), not kept or persisted

    def __post_init__(self):
        if not (0 < len(self.name) <= 16 and self.name.isascii()):
            raise ValueError(f"parameter name {self.name!r} must be 1..16 ASCII characters")
        if not self.lo <= self.default <= self.hi:
            raise ValueError(f"parameter {self.name}: default {self.default} outside [{self.lo}, {self.hi}]")

    def check(self, value: float) -> str | None:
        """None if `value` is acceptable, else the reason it is not."""
        if not math.isfinite(value):
            return f"{self.name}: {value} is not a finite number"
        if not self.lo <= value <= self.hi:
            return f"{self.name}: {value:g} outside [{self.lo:g}, {self.hi:g}]"
        if self.integer and value != round(value):
            return f"{self.name}: {value:g} must be a whole number"
        return None


class ParamError(ValueError):
    pass


class ParamStore:
    """Holds the values; `set` validates and persists; `on_change(name, value)` applies them to the daemon."""

    def __init__(self, specs: list[ParamSpec], state_dir: Path | None = None,
                 on_change: Callable[[str, float], None] | None = None):
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise ValueError("duplicate parameter names")
        self.specs = tuple(specs)
        self._index = {s.name: i for i, s in enumerate(self.specs)}
        self._values = [s.default for s in self.specs]
        self._stored: dict[str, float] = {}
        self.path = Path(state_dir) / PARAMS_FILE if state_dir else None
        self.on_change = on_change
        self.rejected_writes = 0
        self.rejected_reads = 0        # PARAM_REQUEST_READ of an unknown name or index

    def __len__(self) -> int:
        return len(self.specs)

    def index_of(self, name: str) -> int | None:
        return self._index.get(name)

    def get(self, name: str) -> float:
        return self._values[self._index[name]]

    def item(self, index: int) -> tuple[str, float]:
        return self.specs[index].name, self._values[index]

    def load(self) -> list[str]:
        """Apply persisted values (those set over MAVLink earlier). Returns warnings; never raises."""
        warnings: list[str] = []
        if self.path is None or not self.path.exists():
            return warnings
        try:
            doc = json.loads(self.path.read_text())
            values = doc["values"]
            if doc.get("schema") != SCHEMA_VERSION or not isinstance(values, dict):
                raise ValueError(f"unsupported schema {doc.get('schema')!r}")
        except (OSError, ValueError, KeyError, TypeError) as exc:
            warnings.append(f"ignoring parameter file {self.path}: {exc}")
            return warnings
        for name, value in values.items():
            i = self._index.get(name)
            if i is None:
                warnings.append(f"ignoring stored parameter {name!r}: no longer exists")
                continue
            spec = self.specs[i]
            if spec.read_only or spec.momentary:
                continue        # never persisted (a file from elsewhere may hold them): not an error
            reason = spec.check(value) if isinstance(value, (int, float)) else "not a number"
            if reason:
                warnings.append(f"ignoring stored parameter {name}: {reason}")
                continue
            self._values[i] = float(value)
            self._stored[name] = float(value)
        for w in warnings:
            log.warning(w)
        return warnings

    def set(self, name: str, value: float) -> tuple[bool, str]:
        """Validate, apply (on_change) and persist. Returns (accepted, reason if refused)."""
        i = self._index.get(name)
        if i is None:
            self.rejected_writes += 1
            return False, f"unknown parameter {name!r}"
        value = float(value)
        spec = self.specs[i]
        reason = f"{name} is read-only" if spec.read_only else spec.check(value)
        if reason is None and self.on_change is not None:
            try:
                self.on_change(name, value)
            except ParamError as exc:
                reason = str(exc)
        if reason is not None:
            self.rejected_writes += 1
            return False, reason
        if spec.momentary:
            return True, ""
        self._values[i] = value
        self._stored[name] = value
        self._save()
        return True, ""

    def show(self, name: str, value: float) -> None:
        """Set a read-only parameter to the value the daemon has (not persisted, no on_change)."""
        i = self._index[name]
        if not self.specs[i].read_only:
            raise ValueError(f"{name} is not read-only")
        self._values[i] = float(value)

    def _save(self) -> None:
        if self.path is None:
            return
        doc = {"schema": SCHEMA_VERSION, "values": self._stored}
        try:
            write_atomic(self.path, json.dumps(doc, indent=1, sort_keys=True).encode())
        except OSError as exc:
            log.error("cannot persist parameters to %s: %s", self.path, exc)


def decode_param_id(raw) -> str:
    """PARAM_* param_id: char[16], NUL-terminated when shorter, no NUL when exactly 16 characters (pymavlink
    gives str or bytes). At most 16 characters are read, whatever the caller hands in."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return raw[:16].split("\0", 1)[0]


def printable_param_id(name: str) -> str:
    """`name` fit for a log line or STATUSTEXT: non-printable and non-ASCII characters shown as '?'."""
    return "".join(c if c.isascii() and c.isprintable() else "?" for c in name)
