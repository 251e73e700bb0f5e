"""ahrsd.estimator: rotation maths, Wahba solvers, the thesis Kalman filter, the default MEKF and the GNSS-aided
INS."""

from __future__ import annotations

from .kernel_cache import use_source_keyed_cache

KERNEL_CACHE_DIR = use_source_keyed_cache()   # before any kernel is compiled or loaded (kernel_cache.py)

from ahrsd.core.estimator_names import ESTIMATORS  # noqa: E402  (named in core: the command line reads them)

from .base import Estimator  # noqa: E402

UNAIDED_ESTIMATOR = "mekf"     # the daemon's choice without a GNSS source
AIDED_ESTIMATOR = "ins"        # ... and with one; also the aided levelling of back-stepping --gnss
DEFAULT_ESTIMATOR = "mekf"


def make_estimator(name: str = DEFAULT_ESTIMATOR, *, declination_rad: float = 0.0, **params) -> Estimator:
    """Build an estimator by name. `declination_rad` turns magnetic heading into true heading;
    other keyword arguments are fields of that estimator's parameters dataclass."""
    if name == "mekf":
        from .mekf import Mekf

        return Mekf(declination_rad=declination_rad, **params)
    if name == "thesis":
        from .thesis_kf import ThesisKf

        return ThesisKf(declination_rad=declination_rad, **params)
    if name == "ins":
        from .ins import Ins

        return Ins(declination_rad=declination_rad, **params)
    raise ValueError(f"unknown estimator {name!r}; choose one of {', '.join(ESTIMATORS)}")


__all__ = ["Estimator", "ESTIMATORS", "DEFAULT_ESTIMATOR", "make_estimator"]
