"""The simulated vehicle's place and iron as a command line names them (`ahrsd record --sim --site/--iron`, and
the benches' `--site`/`--iron`): one parser of a place (Site.parse, as an argparse type), one set of iron names.
Every `ahrsd` command's parser reads this module, so the site and the irons are imported when a value is parsed,
not before (the package's own names are lazy too: simulation/__init__.py)."""

from __future__ import annotations

import argparse

SITE_FORMAT = "LAT,LON[,ALT_M[,YYYY-MM-DD]]"
VEHICLE_IRONS = ("default", "held-out", "unseen")
"""simulation.VehicleIron's irons by name; "unseen" (VehicleIron.unseen) was drawn, never used for a choice."""


def site_arg(text: str):
    """An option's place (argparse type): simulation.Site.parse of "LAT,LON[,ALT_M[,YYYY-MM-DD]]"; a mistyped
    place is a usage error naming the option (argparse adds its name), not a failed run."""
    from ahrsd.simulation.site import Site

    try:
        return Site.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def vehicle_iron(name: str):
    """The simulation.VehicleIron of one of VEHICLE_IRONS."""
    from ahrsd.simulation.magnetic import VehicleIron

    return {"default": VehicleIron.default, "held-out": VehicleIron.held_out, "unseen": VehicleIron.unseen}[name]()
