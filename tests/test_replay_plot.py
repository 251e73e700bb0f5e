"""`ahrsd replay --plot`: the figure is written (with the truth error panel when the recording has truth), its
error against truth agrees with scipy's, decimation keeps a one-sample flag, and no matplotlib is a usage error."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.cli.main import main
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import make_sample
from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter
from ahrsd.estimator.replay import ATTITUDE_COLUMNS
from ahrsd.estimator.replay_plot import ReplayTrace, truth_errors_deg
from ahrsd.simulation import simulate

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_truth_errors_are_the_euler_differences_scipy_gives():
    rng = np.random.default_rng(4)
    truth = Rotation.from_euler("ZYX", np.column_stack([rng.uniform(-180, 180, 50), rng.uniform(-60, 60, 50),
                                                         rng.uniform(-170, 170, 50)]), degrees=True)
    d_ypr = np.column_stack([rng.uniform(-5, 5, 50), rng.uniform(-2, 2, 50), rng.uniform(-3, 3, 50)])
    est_ypr = truth.as_euler("ZYX", degrees=True) + d_ypr
    est = Rotation.from_euler("ZYX", est_ypr, degrees=True)
    to_wxyz = lambda r: np.roll(r.as_quat(), 1, axis=1)   # scipy is scalar-last
    err = truth_errors_deg(to_wxyz(est), to_wxyz(truth))
    np.testing.assert_allclose(err, d_ypr[:, ::-1], atol=1e-6)   # roll, pitch, heading


def test_decimation_keeps_a_flag_raised_for_one_sample():
    trace = ReplayTrace(max_rows=1000)
    table = np.zeros((10_000, len(ATTITUDE_COLUMNS)))
    table[:, 0] = np.arange(10_000) * 0.01
    table[7_777, ATTITUDE_COLUMNS.index("flags")] = int(EstimateFlags.MAG_REJECTED)
    for k in range(0, 10_000, 1234):
        trace.add(table[k:k + 1234])
    kept = trace.table()
    assert len(kept) <= 1000 and trace.stride >= 10
    flagged = kept[kept[:, -1].astype(int) & int(EstimateFlags.MAG_REJECTED) != 0, 0]
    assert len(flagged) == 1 and abs(flagged[0] - 77.77) <= trace.stride * 0.01


@pytest.fixture(scope="module")
def truth_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("plot") / "md.csv"
    block = simulate("mag-disturbance", 40, rate_hz=50.0, seed=2)
    with RecordingWriter(path, extra_columns=TRUTH_COLUMNS) as w:
        for i in range(len(block)):
            w.write(make_sample(block.t_s[i], block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]),
                    truth_q_wxyz=block.truth_q_wxyz[i])
    return path


def test_replay_writes_the_plot_beside_the_csv(truth_recording, tmp_path):
    png = tmp_path / "replay.png"
    rc = main(["replay", str(truth_recording), "--output", str(tmp_path / "out.csv"), "--plot", str(png),
               "--lat", "36.42", "--lon", "54.98", "--quiet"])
    assert rc == 0
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 20_000
    assert (tmp_path / "out.csv").exists()


def test_replay_plot_without_matplotlib_is_a_usage_error_before_any_work(truth_recording, tmp_path, monkeypatch,
                                                                           capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    rc = main(["replay", str(truth_recording), "--output", str(tmp_path / "out.csv"), "--plot",
               str(tmp_path / "x.png")])
    assert rc == 2 and f"{sys.executable} -m pip install matplotlib" in capsys.readouterr().err
    assert not (tmp_path / "out.csv").exists()
