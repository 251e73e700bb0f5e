"""ahrsd.simulation: truth trajectories, the site's gravity and magnetic field, and a sensor error model.

    from ahrsd.simulation import open_stream, simulate, SCENARIOS, DEFAULT_SITE, SensorErrors
    block = open_stream("level-turns", seed=1).next_block(82)
    fixes = simulate_gnss(simulate("boat", 300.0, rate_hz=200.0), rate_hz=5.0, seed=1)   # GnssFix list

See docs/simulation.md for the scenarios and the error-model defaults.
"""

from ahrsd.simulation.errors import SensorErrors
from ahrsd.simulation.magnetic import PassingMagnet, VehicleIron
from ahrsd.simulation.scenarios import EXTRA_SCENARIOS, SCENARIOS, Scenario, make_scenario
from ahrsd.simulation.site import DEFAULT_SITE, Site
from ahrsd.simulation.stream import SensorBlock, SensorStream, Truth, open_stream, simulate
from ahrsd.simulation.gnss import (GnssErrors, GnssGlitch, GnssOutage, GnssSimulator, in_arrival_order,  # noqa: E402
                                   simulate_gnss)

__all__ = [
    "SCENARIOS", "EXTRA_SCENARIOS", "DEFAULT_SITE", "Site", "SensorErrors", "VehicleIron", "PassingMagnet", "Scenario",
    "make_scenario", "SensorBlock", "SensorStream", "Truth", "open_stream", "simulate",
    "GnssErrors", "GnssGlitch", "GnssOutage", "GnssSimulator", "simulate_gnss", "in_arrival_order",
]
