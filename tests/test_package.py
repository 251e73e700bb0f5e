"""The package installs under one namespace and the console script answers --help."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ahrsd.core.sample import ImuSample, SampleFlags, make_sample
from ahrsd.core.wmm import earth_field


SUBCOMMANDS = {"run", "record", "replay", "calibrate", "magcal", "log"}


def _ahrsd(*args):
    """The installed console script (beside the interpreter running the tests), as a user would call it."""
    script = Path(sys.executable).with_name("ahrsd")
    return subprocess.run([str(script), *args], capture_output=True, text=True, timeout=120)


def test_cli_offers_exactly_the_documented_subcommands():
    out = _ahrsd("--help")
    assert out.returncode == 0 and "usage: ahrsd" in out.stdout
    listed = set(re.findall(r"^    (\w+) ", out.stdout, flags=re.MULTILINE))
    assert listed == SUBCOMMANDS, out.stdout
    # the parser's own list of choices, as it reports an unknown command
    bad = _ahrsd("no-such-command")
    assert bad.returncode == 2
    choices = re.search(r"invalid choice: 'no-such-command' \(choose from (.*)\)", bad.stderr)
    assert choices and set(re.findall(r"'(\w+)'", choices.group(1))) == SUBCOMMANDS, bad.stderr


@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_each_subcommand_answers_help(command):
    out = _ahrsd(command, "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"usage: ahrsd {command}"), out.stdout


def test_make_sample_coerces_vectors():
    s = make_sample(1.5, [1, 2, 3], (0, 0, -9.81), np.array([[20.0], [0], [45]]))
    assert isinstance(s, ImuSample) and s.t_s == 1.5
    for got, given in ((s.gyro_rad_s, [1.0, 2.0, 3.0]), (s.accel_m_s2, [0.0, 0.0, -9.81]), (s.mag_ut, [20.0, 0.0, 45.0])):
        assert got.dtype == np.float64 and got.shape == (3,) and got.tolist() == given
    assert s.flags == SampleFlags.NONE


def test_wmm_berlin_matches_published_magnitude():
    # WMM2025 at Berlin: total field about 50 µT, inclination about 68°, declination about +5°.
    f = earth_field(52.5, 13.4)
    assert 49.0 < f.total_ut < 51.5
    assert 66.5 < np.degrees(f.inclination_rad) < 69.5
    assert 3.0 < np.degrees(f.declination_rad) < 7.0
    assert np.isclose(np.hypot(f.horizontal_ut, f.down_ut), f.total_ut)
