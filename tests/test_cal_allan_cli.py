"""`ahrsd calibrate allan` end to end: a gzip-compressed recording streamed through the CLI, the --json keys
(old and new), the human report and the plot."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest

import allan_noise as gen
from ahrsd.drivers.recording import RECORDING_HEADER

ARW = math.radians(2.0) / 60.0


@pytest.fixture(scope="module")
def static_gz(tmp_path_factory):
    rng = np.random.default_rng(3)
    rate, n = 50.0, 60_000          # 20 min
    t = np.arange(n) / rate
    gyro = np.column_stack([gen.white(n, rate, ARW, rng) for _ in range(3)])
    accel = np.column_stack([gen.white(n, rate, 0.2 / 60.0, rng) for _ in range(3)]) + [0.0, 0.0, -9.81]
    mag = rng.standard_normal((n, 3)) * 0.125 + [20.0, 0.0, 40.0]
    path = tmp_path_factory.mktemp("allan") / "static.csv.gz"
    with gzip.open(path, "wt") as f:
        np.savetxt(f, np.column_stack([t, gyro, accel, mag]), delimiter=",", header=RECORDING_HEADER, comments="",
                   fmt="%.9g")
    return path


def run(capsys, *args):
    from ahrsd.cli.main import main

    capsys.readouterr()
    rc = main(["calibrate", "allan", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_json_keys_old_and_new(static_gz, tmp_path, capsys):
    rc, out, err = run(capsys, static_gz, "--state-dir", tmp_path, "--json")
    assert rc == 0, err
    doc = json.loads(out)
    g = doc["gyro"]["x"]
    for key in ("white_noise", "bias_instability", "rate_random_walk", "quantization", "tau_bias_instability_s",
                "curve_minimum", "tau_curve_minimum_s", "std", "gauss_markov_sigma", "gauss_markov_tau_s", "flags"):
        assert key in g
    assert g["white_noise"] == pytest.approx(ARW, rel=0.03)
    assert g["bias_instability"] is None and g["terms"]["flicker"] is None
    assert g["terms"]["white"]["uncertainty"] > 0 and len(g["terms"]["white"]["tau_range_s"]) == 2
    rrw = g["not_seen"]["rate_random_walk"]
    assert rrw["upper_bound"] > rrw["detection_limit"] > 0 and rrw["recording_needed_s"] > 0
    assert len(doc["curves"]["gyro"]["z"]["upper"]) == len(doc["curves"]["taus_s"])
    assert len(doc["kalman"]["Q_diag"]) == 6 and len(doc["kalman"]["R_diag"]) == 6
    assert any(a["key"] == "gyro_bias_instability_rad_s.x" for a in doc["kalman"]["assumed"])
    assert doc["samples"] == 60_000 and doc["rate_hz"] == pytest.approx(50.0)
    assert json.loads((tmp_path / "noise.json").read_text())["format"] == "ahrsd-noise"


def test_report_and_plot(static_gz, tmp_path, capsys, monkeypatch):
    """The plot's Allan deviation curves are the recording's overlapping Allan deviation (from its definition) and
    white noise's N/√τ (the densities the recording was made with) for τ ≤ 10 s, within IEEE Std 952's 3σ."""
    pytest.importorskip("matplotlib")
    from ahrsd.drivers.recording import read_recording
    from support.figures import line, overlapping_adev, saved_figures

    png = tmp_path / "allan.png"
    with saved_figures(monkeypatch) as figs:
        rc, out, err = run(capsys, static_gz, "--state-dir", tmp_path, "--dry-run", "--plot", png)
    assert rc == 0, err
    assert "ARW 5.8" in out and "not seen" in out and "not saved (--dry-run)" in out
    assert png.read_bytes()[:4] == b"\x89PNG" and len(figs) == 1
    density = {"gyro": ARW, "accel": 0.2 / 60.0, "mag": 0.125 / math.sqrt(50.0)}     # per √s, as generated
    panels = {ax.get_title(): ax for ax in figs[0].axes}
    rec = read_recording(static_gz)
    data = {"gyro": rec.gyro_rad_s, "accel": rec.accel_m_s2, "mag": rec.mag_ut}
    for sensor, n in density.items():
        for i, axis in enumerate("xyz"):
            curve = line(panels[f"{sensor} {axis}"], "Allan deviation")
            for tau, adev in curve[[0, len(curve) // 2]]:      # exactly this recording's Allan deviation
                assert adev == pytest.approx(overlapping_adev(data[sensor][:, i], 50.0, int(round(tau * 50.0))),
                                             rel=0.01), (sensor, axis, tau)
            short = curve[curve[:, 0] <= 10.0]
            assert len(short) >= 5, curve[:, 0]
            # IEEE Std 952 (C.2): a σ read at τ from T seconds is known to 1/√(2(T/τ − 1)); 3 of those
            tol = 3.0 / np.sqrt(2.0 * (1200.0 / short[:, 0] - 1.0))
            assert np.all(np.abs(short[:, 1] / (n / np.sqrt(short[:, 0])) - 1) < tol), (sensor, axis)
    assert not (tmp_path / "noise.json").exists()


def test_too_short_recording_is_refused(tmp_path, capsys):
    path = tmp_path / "short.csv"
    path.write_text(RECORDING_HEADER + "\n" + "".join(f"{k / 10},0,0,0,0,0,9.8,20,0,40\n" for k in range(10)))
    rc, out, err = run(capsys, path, "--state-dir", tmp_path)
    assert rc == 1 and "too short" in err
