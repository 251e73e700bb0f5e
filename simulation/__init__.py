"""ahrsd.simulation: truth trajectories, the site's gravity and magnetic field, and a sensor error model.

    from ahrsd.simulation import open_stream, simulate, SCENARIOS, DEFAULT_SITE, SensorErrors
    block = open_stream("level-turns", seed=1).next_block(82)
    fixes = simulate_gnss(simulate("boat", 300.0, rate_hz=200.0), rate_hz=5.0, seed=1)   # GnssFix list

See docs/simulation.md for the scenarios and the error-model defaults.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# Each name below is imported from its module on first use (PEP 562), not when the package is: a command line that
# only names a place or an iron (simulation/place_options.py, read by every `ahrsd` command's parser) then loads
# neither the scenarios nor the streams. `from ahrsd.simulation import X` works for each of them.
_MODULE_OF = {
    "SensorErrors": "errors",
    "PassingMagnet": "magnetic", "VehicleIron": "magnetic",
    "EXTRA_SCENARIOS": "scenarios", "SCENARIOS": "scenarios", "Scenario": "scenarios", "make_scenario": "scenarios",
    "DEFAULT_SITE": "site", "Site": "site",
    "SensorBlock": "stream", "SensorStream": "stream", "Truth": "stream", "open_stream": "stream",
    "simulate": "stream",
    "GnssErrors": "gnss", "GnssGlitch": "gnss", "GnssOutage": "gnss", "GnssSimulator": "gnss",
    "in_arrival_order": "gnss", "simulate_gnss": "gnss",
}

__all__ = list(_MODULE_OF)


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value          # the next read is a plain module attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:    # what a reader and a type checker see: the same names, from their modules
    from ahrsd.simulation.errors import SensorErrors
    from ahrsd.simulation.gnss import (GnssErrors, GnssGlitch, GnssOutage, GnssSimulator, in_arrival_order,
                                       simulate_gnss)
    from ahrsd.simulation.magnetic import PassingMagnet, VehicleIron
    from ahrsd.simulation.scenarios import EXTRA_SCENARIOS, SCENARIOS, Scenario, make_scenario
    from ahrsd.simulation.site import DEFAULT_SITE, Site
    from ahrsd.simulation.stream import SensorBlock, SensorStream, Truth, open_stream, simulate
