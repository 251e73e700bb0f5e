"""Every config key the daemon accepts is documented where a user looks it up (issue 30: a new user's walk found
`[sensor] source = "iio"`, `data_ready`, `iio_device`, `reader` and `[outputs] heading_good_sigma_deg` in the
code but not in docs/daemon.md's configuration table, and six of the `[outputs]` rate keys nowhere in docs/).

The keys come from the config dataclasses the parser checks a file against (each one's fields are the allowed
keys: `_parse_table` rejects any other by name); the documentation is the table row or the TOML example that
names the key, in the document the configuration table points to for that section."""

import argparse
import dataclasses
import pathlib
import re

import pytest

from ahrsd.cli import run as run_command
from ahrsd.daemon import config
from ahrsd.daemon.magcal_settings import MagCalSettings

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs"

# section -> (the dataclass whose fields are its keys, the document that lists them)
SECTIONS = {
    "sensor": (config.SensorConfig, "daemon.md"),
    "estimator": (config.EstimatorConfig, "daemon.md"),
    "location": (config.LocationConfig, "daemon.md"),
    "mavlink": (config.MavlinkConfig, "daemon.md"),
    "endpoint": (config.EndpointConfig, "daemon.md"),
    "outputs": (config.OutputsConfig, "daemon.md"),
    "state": (config.StateConfig, "daemon.md"),
    "signing": (config.SigningConfig, "daemon.md"),
    "daemon": (config.DaemonConfig, "daemon.md"),
    "gnss": (config.GnssConfig, "gnss.md"),
    "log": (config.LogConfig, "logging.md"),
    "magcal": (MagCalSettings, "magcal-field.md"),
    "nmea": (config.NmeaOutputConfig, "marine.md"),
}


def documented_names(doc: str) -> set[str]:
    """Names in backticks on a table row (`key`, or one of `a`, `b` in a row's cell), and `key =` lines of the
    document's TOML examples."""
    text = (DOCS / doc).read_text(encoding="utf-8")
    names: set[str] = set()
    for line in text.splitlines():
        if line.startswith("|"):
            names.update(re.findall(r"`(?:\[+[a-z_]+\]+\s+)?([a-z_][a-z0-9_]*)`", line))
    for block in re.findall(r"```toml\n(.*?)```", text, re.S):
        names.update(re.findall(r"^#?\s*([a-z_][a-z0-9_]*)\s*=", block, re.M))
    return names


def test_the_sections_are_the_parsers():
    """The table above covers every section a file may hold: a new section must say where it is documented."""
    top = {f.name for f in dataclasses.fields(config.Config)} - {"source_path"}
    top = {"endpoint" if n == "endpoints" else n for n in top}
    assert top == set(SECTIONS)


@pytest.mark.parametrize("section", sorted(SECTIONS))
def test_every_config_key_is_documented(section):
    cls, doc = SECTIONS[section]
    keys = [f.name for f in dataclasses.fields(cls)]
    assert keys, section
    missing = sorted(set(keys) - documented_names(doc))
    assert not missing, f"[{section}] keys not documented in docs/{doc}: {missing}"


def test_every_run_flag_is_in_the_daemons_doc(monkeypatch):
    """docs/daemon.md "Running it" lists `ahrsd run`'s flags (the walk found --nmea, --log-dir and --no-log missing
    there); the options come from the parser `ahrsd run` uses."""
    monkeypatch.setenv("COLUMNS", "1000")     # argparse wraps the help at the terminal's width: no flag split
    subparsers = argparse.ArgumentParser().add_subparsers()
    run_command.register(subparsers)
    help_text = subparsers.choices["run"].format_help()
    flags = set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", help_text)) - {"--help"}
    text = (DOCS / "daemon.md").read_text(encoding="utf-8")
    missing = sorted(f for f in flags if not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", text))
    assert flags and not missing, f"ahrsd run flags not in docs/daemon.md: {missing}"
