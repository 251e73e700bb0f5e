"""ahrsd.simulation: truth trajectories, the site's gravity and magnetic field, and a sensor error model.

    from ahrsd.simulation import open_stream, simulate, SCENARIOS, DEFAULT_SITE, SensorErrors
    block = open_stream("level-turns", seed=1).next_block(82)

See docs/simulation.md for the scenarios and the error-model defaults.
"""

from ahrsd.simulation.errors import SensorErrors
from ahrsd.simulation.magnetic import PassingMagnet, VehicleIron
from ahrsd.simulation.scenarios import EXTRA_SCENARIOS, SCENARIOS, Scenario, make_scenario
from ahrsd.simulation.site import DEFAULT_SITE, Site
from ahrsd.simulation.stream import SensorBlock, SensorStream, open_stream, simulate

__all__ = [
    "SCENARIOS", "EXTRA_SCENARIOS", "DEFAULT_SITE", "Site", "SensorErrors", "VehicleIron", "PassingMagnet", "Scenario",
    "make_scenario", "SensorBlock", "SensorStream", "open_stream", "simulate",
]
