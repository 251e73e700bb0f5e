"""Newcomer-path fixes of the `ahrsd` CLI and the annotated example config (review of README + docs).

Each test fails on the code before its fix: a traceback on a closed stdout, misleading help, a fixed-yaw
position that silently used longitude 0, a bad --target that waited for a daemon, an example config that
documented keys or defaults the code does not have.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ahrsd.cli import magcal
from ahrsd.cli.main import build_parser
from ahrsd.daemon.config import Config, load_config

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "systemd" / "ahrsd.toml"


def _help(*argv: str) -> str:
    node = build_parser()
    for name in argv:                                               # walk down to the (sub)command's parser
        node = node._subparsers._group_actions[0].choices[name]   # noqa: SLF001
    return " ".join(node.format_help().split())


# -- a closed stdout (`ahrsd ... | head`) ends quietly ---------------------------------------------------------

@pytest.mark.parametrize("argv", [["run", "--config", str(EXAMPLE), "--check-config"]])
def test_closed_stdout_gives_no_traceback(argv):
    read_end, write_end = os.pipe()
    os.close(read_end)                 # the reader is gone before anything is written: every write is EPIPE
    try:
        proc = subprocess.run([sys.executable, "-c", "import sys; from ahrsd.cli.main import main; "
                               "sys.exit(main())", *argv], stdout=write_end, stderr=subprocess.PIPE,
                              text=True, timeout=60)
    finally:
        os.close(write_end)
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr
    assert proc.returncode == 141


# -- help that says what the defaults are -----------------------------------------------------------------------

def test_calibrate_help_states_the_state_dir_default_and_the_gravity_default():
    text = _help("calibrate", "accel")
    assert "/var/lib/ahrsd, the service's" in text and "~/.local/state/ahrsd" in text and "ahrsd run" in text
    # the old text read "latitude (deg) ... (default: 9.80665)", a latitude of 9.8°
    assert re.search(r"--lat LAT latitude \(deg\) for local gravity \(default: none, standard gravity", text)
    mag = _help("calibrate", "mag")
    assert "default: ellipsoid" in mag and "backstepping for a vehicle that cannot be tumbled" in mag


def test_record_help_has_no_none_defaults_and_keeps_real_ones():
    text = _help("record")
    assert "(default: None)" not in text and "(default: False)" not in text
    assert "simulation seed (--sim) (default: 0)" in text and "(default: adis16405)" in text
    assert "--sim alone: static" in text


# -- ahrsd magcal argument checks --------------------------------------------------------------------------------

def test_magcal_fixed_yaw_position_needs_both_coordinates():
    ns = argparse.Namespace
    assert magcal._fixed_yaw_position(ns(lat=None, lon=None)) == (0.0, 0.0)   # daemon's own position
    assert magcal._fixed_yaw_position(ns(lat=52.0, lon=4.4)) == (52.0, 4.4)
    for lat, lon in ((52.0, None), (None, 4.4), (95.0, 4.4), (52.0, 200.0)):
        with pytest.raises(ValueError):
            magcal._fixed_yaw_position(ns(lat=lat, lon=lon))


def test_magcal_fixed_yaw_with_one_coordinate_exits_2_before_connecting(capsys):
    args = build_parser().parse_args(["magcal", "--connect", "udpin:127.0.0.1:1", "fixed-yaw", "90", "--lat", "50"])
    assert args.lat == 50.0 and args.lon is None
    assert magcal.run(args) == 2
    assert "--lat and --lon together" in capsys.readouterr().err


@pytest.mark.parametrize("target", ["abc", "1:300", "1", "0:200"])
def test_magcal_bad_target_is_a_usage_error(target, capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["magcal", "--target", target, "status"])
    assert exc.value.code == 2 and "--target" in capsys.readouterr().err


# -- systemd/ahrsd.toml documents exactly what the code has ------------------------------------------------------

def test_example_config_values_are_the_defaults_except_the_two_it_names():
    cfg = load_config(EXAMPLE)
    default = Config()
    for section in ("sensor", "estimator", "gnss", "location", "mavlink", "outputs", "state", "signing", "daemon"):
        got, want = dataclasses.asdict(getattr(cfg, section)), dataclasses.asdict(getattr(default, section))
        if section == "sensor":
            assert got.pop("source") == "spi" and want.pop("source") == "sim"
        assert got == want, section
    assert [e.url for e in cfg.endpoints] != [e.url for e in default.endpoints]
    header = EXAMPLE.read_text().split("\n\n", 1)[0]
    assert 'source = "spi" (default "sim")' in header and "udpout:127.0.0.1:14550" in header


def test_every_commented_key_of_the_example_exists_and_parses(tmp_path):
    """Uncomment every `# key = value` and `# [section]` line: an unknown or removed key is an error."""
    out, uncommented = [], 0
    for line in EXAMPLE.read_text().splitlines():
        m = re.match(r"#\s?(\[\[?\w+\]\]?|\w+ = .*)$", line.split("  #")[0].rstrip())
        if m:
            line, uncommented = m.group(1), uncommented + 1
        out.append(line)
    assert uncommented >= 20                      # the [magcal] keys and the optional ones of the other sections
    path = tmp_path / "all.toml"
    path.write_text("\n".join(out) + "\n")
    cfg = load_config(path)
    assert cfg.magcal is not None and cfg.magcal.accept_broadcast is False and cfg.magcal.fitness_mgauss == 16.0
    assert cfg.location.declination_deg == 1.5 and len(cfg.endpoints) == 4
    assert [e.profile for e in cfg.endpoints] == ["gcs", "autopilot", "gcs", "autopilot"]   # serial + PX4 examples


# -- ahrsd calibrate: usage errors exit 2 (docs/calibration.md), checked before any sensor or file is touched -----

@pytest.mark.parametrize("argv, message", [
    (["accel"], "give a RECORDING"),
    (["accel", "--live"], "--live needs exactly one of"),
    (["accel", "--live", "--sim", "static", "--spi", "/dev/spidev0.0"], "--live needs exactly one of"),
    (["accel", "some.csv", "--live", "--sim", "static"], "not both"),
    (["accel", "some.csv", "--sim", "static"], "go with --live"),
    (["mag", "some.csv", "--lat", "1", "--lon", "2", "--align-recording", "t.csv"], "goes with --method three-step"),
])
def test_calibrate_usage_errors_exit_2(argv, message, tmp_path, capsys, monkeypatch):
    from ahrsd.cli.main import main

    # the recording exists (empty): `calibrate mag` says "no such file" before a usage error, and the usage checks
    # run before the file is read
    monkeypatch.chdir(tmp_path)
    (tmp_path / "some.csv").write_text("")
    rc = main(["calibrate", *argv, "--state-dir", str(tmp_path / "st"), "--dry-run"])
    err = capsys.readouterr().err
    assert rc == 2 and message in err, err
    assert not (tmp_path / "st").exists()


@pytest.mark.parametrize("extra", [["--lat", "95", "--lon", "0"], ["--lat", "1", "--lon", "2", "--date", "2026-13-01"]])
def test_calibrate_mag_bad_site_is_a_usage_error_on_stderr_and_in_json(extra, tmp_path, capsys):
    import json

    from ahrsd.cli.main import main

    recording = tmp_path / "some.csv"      # exists: a missing file is said first (exit 1), before the site
    recording.write_text("")
    rc = main(["calibrate", "mag", str(recording), *extra, "--state-dir", str(tmp_path), "--json"])
    out, err = capsys.readouterr()
    assert rc == 2 and "ahrsd calibrate mag:" in err
    assert json.loads(out)["sensor"] == "mag" and json.loads(out)["error"]   # stdout stays one JSON object


@pytest.mark.parametrize("seconds", ["nan", "inf", "-1", "0"])
def test_record_rejects_non_finite_or_non_positive_seconds(seconds, tmp_path, capsys):
    from ahrsd.cli.main import main

    out = tmp_path / "r.csv"
    assert main(["record", "--sim", "static", "-o", str(out), "-q", "--seconds", seconds]) == 2
    assert "--seconds must be a positive, finite number" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("argv", [
    ["magcal", "--timeout", "nan", "status"], ["magcal", "--timeout", "0", "status"],
    ["magcal", "fixed-yaw", "inf"], ["magcal", "fixed-yaw", "nan"], ["magcal", "start", "--delay", "-1"],
    ["magcal", "start", "--max-time", "nan"], ["magcal", "status", "--seconds", "-3"],
])
def test_magcal_numbers_must_be_finite_and_in_range(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(argv)
    assert exc.value.code == 2 and "expected a finite number" in capsys.readouterr().err


def test_magcal_numbers_in_range_parse():
    args = build_parser().parse_args(["magcal", "--timeout", "2.5", "fixed-yaw", "-10.5"])
    assert args.timeout == 2.5 and args.yaw_deg == -10.5
