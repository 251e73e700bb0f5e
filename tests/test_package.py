"""The package installs under one namespace and the console script answers --help."""

import re
import subprocess
import sys

import numpy as np

from ahrsd.core.sample import ImuSample, SampleFlags, make_sample
from ahrsd.core.wmm import earth_field


def test_cli_help_lists_subcommands():
    out = subprocess.run([sys.executable, "-m", "ahrsd.cli", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    assert "usage: ahrsd" in out.stdout
    listed = re.findall(r"^    (\S+)", out.stdout, flags=re.MULTILINE)   # argparse's subcommand lines
    assert listed == ["run", "record", "replay", "calibrate", "magcal"]


def test_make_sample_coerces_vectors():
    s = make_sample(1.5, [1, 2, 3], (0, 0, -9.81), np.array([20.0, 0, 45]))
    assert isinstance(s, ImuSample)
    assert s.gyro_rad_s.dtype == np.float64 and s.gyro_rad_s.shape == (3,)
    assert s.flags == SampleFlags.NONE


def test_wmm_berlin_matches_published_magnitude():
    # WMM2025 at Berlin: total field about 50 µT, inclination about 68°, declination about +5°.
    f = earth_field(52.5, 13.4)
    assert 49.0 < f.total_ut < 51.5
    assert 66.5 < np.degrees(f.inclination_rad) < 69.5
    assert 3.0 < np.degrees(f.declination_rad) < 7.0
    assert np.isclose(np.hypot(f.horizontal_ut, f.down_ut), f.total_ut)
