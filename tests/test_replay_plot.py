"""`ahrsd replay --plot`: the figure is written (with the truth error panel when the recording has truth), its
error against truth agrees with scipy's, decimation keeps a one-sample flag, and no matplotlib is a usage error."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.cli.main import main
from ahrsd.core.estimate import EstimateFlags
from ahrsd.estimator.replay import ATTITUDE_COLUMNS
from ahrsd.estimator.replay_plot import ReplayTrace, truth_errors_deg
from ahrsd.simulation import simulate

from support.recordings import write_block

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


def test_a_flag_raised_at_every_mag_update_is_drawn_as_the_stretch_it_covers():
    """ins flags the magnetometer rejected on each of its updates (one sample in 9 at 819.2 SPS): the angle
    panels shaded thousands of sub-pixel slivers (faint, sparse) while the flags panel looked solid. At the
    figure's resolution it is one span per stretch; a gap of seconds still splits it."""
    from matplotlib.colors import to_rgba

    from ahrsd.estimator.replay_plot import replay_figure

    n = int(200 * 819.2)
    table = np.zeros((n, len(ATTITUDE_COLUMNS)))
    t = np.arange(n) / 819.2
    table[:, 0] = t
    table[:, ATTITUDE_COLUMNS.index("qw")] = 1.0
    every_update = (np.arange(n) % 9 == 0) & (((t >= 74) & (t < 188)) | ((t >= 190) & (t < 195)))
    table[every_update, ATTITUDE_COLUMNS.index("flags")] = int(EstimateFlags.MAG_REJECTED)
    trace = ReplayTrace()
    trace.add(table)
    fig = replay_figure(trace)
    try:
        roll = next(a for a in fig.axes if a.get_ylabel() == "roll (°)")
        red = to_rgba("tab:red")[:3]
        spans = sorted((p.get_x(), p.get_x() + p.get_width()) for p in roll.patches
                       if tuple(p.get_facecolor()[:3]) == red and np.isfinite(p.get_x()))
        assert len(spans) == 2, len(spans)
        np.testing.assert_allclose(spans, [(74.0, 188.0), (190.0, 195.0)], atol=0.05)
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


@pytest.fixture(scope="module")
def truth_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("plot") / "md.csv"
    block = simulate("mag-disturbance", 40, rate_hz=50.0, seed=2)
    return write_block(path, block, with_truth=True)


@pytest.fixture
def figures(monkeypatch):
    """The figures `ahrsd replay --plot` draws, kept open for the test to read (and still written to the file)."""
    from ahrsd.estimator import replay_plot
    from support.kept_figures import kept_figures

    def figure_and_path(trace, path, *args, **kwargs):
        return replay_plot.replay_figure(trace, *args, **kwargs), path

    with kept_figures(monkeypatch, replay_plot, "plot_replay", figure_and_path) as kept:
        yield kept


def _replayed(recording, directory, *site):
    """`ahrsd replay RECORDING --plot` once (its figure kept open for the tests that read it, closed after the
    module): (exit code, the PNG's path, the output CSV's path, [the figure])."""
    from ahrsd.estimator import replay_plot
    from support.kept_figures import kept_figures

    def figure_and_path(trace, path, *args, **kwargs):
        return replay_plot.replay_figure(trace, *args, **kwargs), path

    png, out = directory / "replay.png", directory / "out.csv"
    with pytest.MonkeyPatch.context() as mp, kept_figures(mp, replay_plot, "plot_replay", figure_and_path) as kept:
        rc = main(["replay", str(recording), "--output", str(out), "--plot", str(png), *site, "--quiet"])
        yield rc, png, out, kept


@pytest.fixture(scope="module")
def replayed_at_the_site(truth_recording, tmp_path_factory):
    """The truth recording replayed with the site's declination (true north), for the tests that read it."""
    yield from _replayed(truth_recording, tmp_path_factory.mktemp("site"), "--lat", "36.42", "--lon", "54.98")


@pytest.fixture(scope="module")
def replayed_uncalibrated(truth_recording, tmp_path_factory):
    """The truth recording replayed without a site (magnetic north) and without a calibration (heading unknown)."""
    yield from _replayed(truth_recording, tmp_path_factory.mktemp("uncalibrated"))


def axis_labelled(fig, ylabel):
    found = [a for a in fig.axes if a.get_ylabel() == ylabel]
    assert len(found) == 1, [a.get_ylabel() for a in fig.axes]
    return found[0]


def error_lines(error_ax) -> dict:
    """The error panel's roll, pitch and heading lines by name (their labels: 'roll (RMS …)')."""
    return {ln.get_label().split(" ")[0]: ln for ln in error_ax.get_lines()
            if ln.get_label().split(" ")[0] in ("roll", "pitch", "heading")}


def known_rows(out_csv) -> dict:
    """Per angle, the replay's rows where it is known: not INITIALISING and its σ column below 90°."""
    header = out_csv.read_text().splitlines()[0].split(",")
    table = np.loadtxt(out_csv, delimiter=",", skiprows=1, ndmin=2)
    settled = (table[:, header.index("flags")].astype(np.int64) & int(EstimateFlags.INITIALISING)) == 0
    return {name: settled & (table[:, header.index(column)] < 90.0)
            for name, column in (("roll", "sigma_roll_deg"), ("pitch", "sigma_pitch_deg"), ("heading", "sigma_yaw_deg"))}


def scipy_errors_deg(out_csv, recording):
    """roll, pitch, heading error of the replay output against the recording's truth, by scipy (ZYX)."""
    from ahrsd.drivers.recording import read_recording

    header = out_csv.read_text().splitlines()[0].split(",")
    out = np.loadtxt(out_csv, delimiter=",", skiprows=1, ndmin=2)
    q = out[:, [header.index(c) for c in ("qw", "qx", "qy", "qz")]]
    truth = read_recording(recording).truth_q_wxyz
    to_xyzw = lambda wxyz: np.roll(wxyz, -1, axis=1)   # noqa: E731 - scipy is scalar-last
    est = Rotation.from_quat(to_xyzw(q)).as_euler("ZYX", degrees=True)
    ref = Rotation.from_quat(to_xyzw(truth)).as_euler("ZYX", degrees=True)
    d = (est - ref + 180.0) % 360.0 - 180.0
    return d[:, ::-1]                                   # roll, pitch, heading


def test_replay_plot_draws_the_truth_error_panel_that_scipy_computes(truth_recording, replayed_at_the_site):
    rc, png, out, figures = replayed_at_the_site
    assert rc == 0
    assert png.read_bytes()[:8] == PNG_MAGIC and out.exists()
    (fig,) = figures
    assert "through mekf" in fig.texts[0].get_text() and "true north" in fig.texts[0].get_text()
    error_ax = axis_labelled(fig, "error vs truth (°)")
    lines = error_lines(error_ax)
    assert sorted(lines) == ["heading", "pitch", "roll"]
    expected = scipy_errors_deg(out, truth_recording)
    known = known_rows(out)
    for k, name in enumerate(("roll", "pitch", "heading")):
        drawn = np.asarray(lines[name].get_ydata(), dtype=float)
        assert len(drawn) == len(expected)               # 2000 rows: not decimated
        settled = slice(100, None)
        np.testing.assert_allclose(drawn[settled], expected[settled, k], atol=1e-3)
        if known[name].any():   # the RMS where the angle is known: settled, σ below 90°
            rms = float(np.sqrt(np.mean(expected[known[name], k] ** 2)))
            assert f"RMS {rms:.2f}°" in lines[name].get_label()
        else:
            assert "unknown throughout" in lines[name].get_label()
    # the truth is drawn on each angle panel too
    for ylabel in ("roll (°)", "pitch (°)", "true heading (°)"):
        assert [ln for ln in axis_labelled(fig, ylabel).get_lines() if ln.get_label() == "truth"]


def test_without_truth_columns_there_is_no_error_panel(tmp_path, figures, capsys):
    rec = tmp_path / "plain.csv"
    block = simulate("static", 10, rate_hz=50.0, seed=3)
    write_block(rec, block)
    png = tmp_path / "p.png"
    assert main(["replay", str(rec), "--output", str(tmp_path / "o.csv"), "--plot", str(png)]) == 0
    assert f"ahrsd replay: figure written to {png}" in capsys.readouterr().err     # says where the figure went
    (fig,) = figures
    labels = [a.get_ylabel() for a in fig.axes]
    assert "error vs truth (°)" not in labels and "magnetic heading (°)" in labels
    assert "heading to magnetic north" in fig.texts[0].get_text() and "through mekf" in fig.texts[0].get_text()


def test_replay_plot_without_matplotlib_is_a_usage_error_before_any_work(truth_recording, tmp_path, monkeypatch,
                                                                           capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    rc = main(["replay", str(truth_recording), "--output", str(tmp_path / "out.csv"), "--plot",
               str(tmp_path / "x.png")])
    assert rc == 2 and f"{sys.executable} -m pip install matplotlib" in capsys.readouterr().err
    assert not (tmp_path / "out.csv").exists()


@pytest.fixture(scope="module")
def boat_with_gnss(tmp_path_factory):
    path = tmp_path_factory.mktemp("aided") / "boat.csv"
    # in this process: no interpreter start and ahrsd import (the console script is test_recording's)
    assert main(["record", "--sim", "boat", "--seconds", "15", "--rate-hz", "100", "--output", str(path),
                 "--quiet"]) == 0
    return path, path.with_name("boat.gnss.csv")


def test_an_aided_replay_plot_names_ins_and_true_north_and_draws_velocity_and_track(boat_with_gnss, tmp_path,
                                                                                    figures):
    rec, gnss = boat_with_gnss
    out = tmp_path / "out.csv"
    assert main(["replay", str(rec), "--gnss", str(gnss), "--output", str(out), "--plot", str(tmp_path / "p.png"),
                 "--quiet"]) == 0
    (fig,) = figures
    title = fig.texts[0].get_text()
    assert "through ins aided by GNSS" in title and "heading to true north" in title
    assert "at the first GNSS fix" in title and "None" not in title
    assert axis_labelled(fig, "true heading (°)")

    header = out.read_text().splitlines()[0].split(",")
    table = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    # ins's roll and pitch σ differ (more than 1 % somewhere): two bands, each named, not one for both
    roll_sigma, pitch_sigma = (table[:, header.index(c)] for c in ("sigma_roll_deg", "sigma_pitch_deg"))
    assert not np.allclose(roll_sigma, pitch_sigma, rtol=0.01, atol=1e-6)
    legend = [t.get_text() for t in axis_labelled(fig, "error vs truth (°)").get_legend().get_texts()]
    assert "roll ±1σ" in legend and "pitch ±1σ" in legend and "roll ≈ pitch ±1σ" not in legend
    fixes = np.genfromtxt(gnss, delimiter=",", names=True)
    t0 = table[0, 0]
    velocity = axis_labelled(fig, "velocity (m/s)")
    lines = {ln.get_label(): ln for ln in velocity.get_lines()}
    np.testing.assert_allclose(lines["north"].get_ydata(), table[:, header.index("vel_n_m_s")], atol=6e-5, equal_nan=True)
    np.testing.assert_allclose(lines["east"].get_ydata(), table[:, header.index("vel_e_m_s")], atol=6e-5, equal_nan=True)
    # the fixes' north velocity, as the receiver reported it, at their own times
    points = lines["GNSS fixes"]
    in_run = fixes["t_s"] >= t0
    np.testing.assert_allclose(points.get_xdata(), fixes["t_s"][in_run] - t0, atol=1e-6)   # t_s printed to 1 µs
    np.testing.assert_allclose(points.get_ydata(), fixes["vel_n_m_s"][in_run], atol=1e-9)

    track = axis_labelled(fig, "north (m)")
    assert track.get_xlabel() == "east (m)"
    drawn = {ln.get_label(): ln for ln in track.get_lines()}
    lat, lon = fixes["lat_deg"][in_run], fixes["lon_deg"][in_run]
    # the origin is the filter's first aided position (near the first fix), metres by the local radii
    est_lat = table[:, header.index("lat_deg")]
    flags = table[:, header.index("flags")].astype(int)
    first = np.flatnonzero(flags & int(EstimateFlags.GNSS_AIDED))[0]
    lat0, lon0 = est_lat[first], table[first, header.index("lon_deg")]
    north_m = np.radians(lat - lat0) * 6_371_008.8
    east_m = np.radians(lon - lon0) * 6_371_008.8 * np.cos(np.radians(lat0))
    np.testing.assert_allclose(drawn["GNSS fixes"].get_ydata(), north_m, atol=1e-3)   # lat, lon printed to 1e-9°
    np.testing.assert_allclose(drawn["GNSS fixes"].get_xdata(), east_m, atol=1e-3)
    assert np.hypot(*[np.asarray(v)[0] for v in drawn["start"].get_data()]) < 1e-9
    est_n = np.asarray(drawn["estimate"].get_ydata())
    assert np.all(np.isfinite(est_n)) and np.ptp(est_n) > 10     # the boat moved: a track, not a point at 0, 0


def test_each_error_band_is_named_in_the_legend_and_spans_its_own_sigma(replayed_at_the_site):
    """The ±1σ bands overlap into one grey: each must be in the legend (heading's in its line's colour; roll's and
    pitch's, equal in mekf, as one band named for both, session 23) and span the σ column the replay wrote for
    that angle (read from the CSV, not from the plot code)."""
    import matplotlib.colors
    rc, _png, out, figures = replayed_at_the_site
    assert rc == 0
    (fig,) = figures
    error_ax = axis_labelled(fig, "error vs truth (°)")
    legend = [t.get_text() for t in error_ax.get_legend().get_texts()]
    header = out.read_text().splitlines()[0].split(",")
    table = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)
    bands = {c.get_label(): c for c in error_ax.collections}
    lines = error_lines(error_ax)
    roll_sigma, pitch_sigma = (table[:, header.index(c)] for c in ("sigma_roll_deg", "sigma_pitch_deg"))
    # mekf: roll's and pitch's σ within 1 % on every row (the CSV's 6 decimals), drawn as one band named for both
    assert np.allclose(roll_sigma, pitch_sigma, rtol=0.01, atol=1e-6)
    assert "roll ≈ pitch ±1σ" in legend and "roll ±1σ" not in legend and "pitch ±1σ" not in legend
    for name, column in (("roll ≈ pitch", "sigma_roll_deg"), ("heading", "sigma_yaw_deg")):
        band = bands[f"{name} ±1σ"]
        if name == "heading":
            np.testing.assert_allclose(band.get_facecolor()[0][:3], matplotlib.colors.to_rgb(lines[name].get_color()))
        sigma = table[:, header.index(column)]
        known = sigma[np.isfinite(sigma) & (sigma < 90.0)]     # no band where the angle is unknown (σ ≥ 90°)
        paths = band.get_paths()
        if not known.size:
            assert not paths or not np.isfinite(np.concatenate([p.vertices for p in paths])).any()
            continue
        top = max(p.vertices[:, 1].max() for p in paths)
        assert top == pytest.approx(np.max(known), rel=1e-6)


def test_an_unknown_heading_neither_sets_the_error_scale_nor_the_rms(truth_recording, replayed_uncalibrated):
    """Without a calibration mekf's heading is unknown (σ 180°): its error (tens of degrees) must not squash the
    tilt errors flat, nor an initialisation set the RMS (session 23's walk: `replay gboat.csv --gnss` read 'heading
    RMS 8.66°' with roll and pitch flat lines, where the settled run had 0.80° / 0.11° / 0.09°). The scale is 1.3 ×
    the 99th percentile of the known rows' errors, computed here from scipy's errors and the CSV's flags and σ."""
    rc, _png, out, figures = replayed_uncalibrated
    assert rc == 0
    (fig,) = figures
    error_ax = axis_labelled(fig, "error vs truth (°)")
    expected, known = scipy_errors_deg(out, truth_recording), known_rows(out)
    assert not known["heading"].any() and known["roll"].any()       # the case: heading unknown, tilt known
    tilt = np.concatenate([expected[known["roll"], 0], expected[known["pitch"], 1]])
    span = max(float(np.percentile(np.abs(tilt), 99)) * 1.3, 0.5)
    assert error_ax.get_ylim() == pytest.approx((-span, span), rel=1e-6)   # scipy vs the plot: 5e-8
    assert np.abs(expected[:, 2]).max() > 3 * span              # the heading's error would have set it
    assert "heading error off scale" in error_ax.get_title(loc="left")
    lines = error_lines(error_ax)
    assert "unknown throughout" in lines["heading"].get_label()
    first = int(np.flatnonzero(known["roll"])[0])
    rms = float(np.sqrt(np.mean(expected[known["roll"], 0] ** 2)))
    t = np.asarray(lines["roll"].get_xdata(), dtype=float)
    assert lines["roll"].get_label() == f"roll (RMS {rms:.2f}° from {t[first]:.0f} s)"


def test_an_unknown_heading_has_no_band_but_says_so(replayed_uncalibrated):
    """σ 180° (no calibration) drew a ±180° band wrapped at 0/360° across the whole heading panel (session 23's
    walk): where the CSV's sigma_yaw_deg is ≥ 90° no band is drawn, and the panel says the heading is unknown."""
    rc, _png, out, figures = replayed_uncalibrated
    assert rc == 0
    (fig,) = figures
    header = out.read_text().splitlines()[0].split(",")
    sigma = np.loadtxt(out, delimiter=",", skiprows=1, ndmin=2)[:, header.index("sigma_yaw_deg")]
    unknown_share = float(np.mean(sigma >= 90.0))
    assert unknown_share > 0.9                                  # the case: no calibration, heading unknown
    heading_ax = axis_labelled(fig, "magnetic heading (°)")
    (band,) = [c for c in heading_ax.collections if c.get_label() == "±1σ"]
    drawn = np.concatenate([p.vertices for p in band.get_paths()]) if band.get_paths() else np.empty((0, 2))
    assert len(drawn) <= 4 * (1 - unknown_share) * len(sigma) + 8   # only the known rows' band, if any
    notes = [t.get_text() for t in heading_ax.texts if t.get_gid() == "unknown heading"]
    assert notes == [f"heading unknown (σ ≥ 90°, no band) on {100 * unknown_share:.0f} % of the run"]


def test_the_roll_panel_holds_the_truth_and_the_settled_estimate(tmp_path, figures):
    """The panels' limits came from the 0.5…99.5 percentiles: the highest wave peaks of the tour's boat were cut
    flat (session 23's walk, gatt.png's roll, its peaks during ins's 81 s of initialising). A trace with gusts
    well above the swell: the truth's while the filter initialised, the estimate's after; both inside the roll
    panel (the values are the arrays given, not read from the plot code)."""
    from ahrsd.estimator import replay_plot

    n = 4000
    t = np.arange(n) / 100.0
    roll = 2.0 * np.sin(2 * np.pi * t / 8.0)
    roll[1000:1010] = 6.5                    # a gust: 0.25 % of the rows
    table = np.zeros((n, len(ATTITUDE_COLUMNS)))
    col = {c: i for i, c in enumerate(ATTITUDE_COLUMNS)}
    table[:, col["t_s"]] = t
    table[:, col["roll_deg"]] = roll
    table[:, col["pitch_deg"]] = -roll / 2
    table[:, col["heading_true_deg"]] = table[:, col["yaw_deg"]] = 30.0
    for c in ("sigma_roll_deg", "sigma_pitch_deg", "sigma_yaw_deg"):
        table[:, col[c]] = 0.2
    table[:, col["qw"]] = 1.0
    table[:, col["flags"]] = int(EstimateFlags.INITIALISING)
    table[2000:, col["flags"]] = 0
    table[3000:3010, col["roll_deg"]] = -5.0    # a settled gust: the estimate's own
    truth_roll = np.radians(table[:, col["roll_deg"]])
    truth_q = np.column_stack([np.cos(truth_roll / 2), np.sin(truth_roll / 2), np.zeros(n), np.zeros(n)])
    trace = ReplayTrace()
    trace.add(table)
    fig = replay_plot.replay_figure(trace, truth_q, t)
    try:   # the truth's gust came while the filter initialised (the tour's ins initialises for 81 s)
        low, high = axis_labelled(fig, "roll (°)").get_ylim()
        assert low < -5.0 and 6.5 < high, (low, high)
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
