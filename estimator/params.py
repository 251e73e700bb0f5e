"""Estimator parameters given by name (the daemon's config, `replay --set`): shared by every filter."""

from __future__ import annotations

from dataclasses import fields, replace


def with_overrides(base, overrides: dict, estimator: str):
    """The parameters dataclass `base` with some fields replaced; ValueError naming any unknown field."""
    unknown = set(overrides) - {f.name for f in fields(base)}
    if unknown:
        raise ValueError(f"unknown {estimator} parameter(s): {', '.join(sorted(unknown))}")
    return replace(base, **overrides)
