"""The simulated vehicle's place and iron as a command line names them (`ahrsd record --sim --site/--iron`, and
the benches' `--site`/`--iron`): one parser of a place, one set of iron names."""

from __future__ import annotations

import argparse

SITE_FORMAT = "LAT,LON[,ALT_M[,YYYY-MM-DD]]"
VEHICLE_IRONS = ("default", "held-out", "unseen")
"""simulation.VehicleIron's irons by name; "unseen" (VehicleIron.unseen) was drawn, never used for a choice."""


def site_arg(text: str):
    """An option's place (argparse type): simulation.Site.parse of "LAT,LON[,ALT_M[,YYYY-MM-DD]]"; a mistyped
    place is a usage error naming the option (argparse adds its name), not a failed run."""
    from ahrsd.simulation import Site

    try:
        return Site.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def vehicle_iron(name: str):
    """The simulation.VehicleIron of one of VEHICLE_IRONS."""
    from ahrsd.simulation import VehicleIron

    return {"default": VehicleIron.default, "held-out": VehicleIron.held_out, "unseen": VehicleIron.unseen}[name]()
