"""Estimator parameters given by name (the daemon's config, `replay --set`): shared by every filter."""

from __future__ import annotations

import numbers
from dataclasses import fields, replace

import numpy as np


def with_overrides(base, overrides: dict, estimator: str):
    """The parameters dataclass `base` with some fields replaced; ValueError naming any unknown field, or a value of
    the wrong kind for its field (a switch given anything but true/false, a number given text): `replay --set
    iron_refine=false` once passed the text "false", which Python takes as true."""
    unknown = set(overrides) - {f.name for f in fields(base)}
    if unknown:
        raise ValueError(f"unknown {estimator} parameter(s): {', '.join(sorted(unknown))}")
    for name, value in overrides.items():
        _check_kind(estimator, name, getattr(base, name), value)
    return replace(base, **overrides)


def _check_kind(estimator: str, name: str, default, value) -> None:
    """A switch takes a bool, a number a real number (not a bool): the field's default says which."""
    if isinstance(default, (bool, np.bool_)):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{estimator} parameter {name}: expected true or false, got {value!r}")
    elif isinstance(default, numbers.Real):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise ValueError(f"{estimator} parameter {name}: expected a number, got {value!r}")
