"""The back-stepping figure levels the field with the attitude the fit used (the aided levelling of
`calibrate mag --gnss`), so the vertical field it draws scatters as much as the fit's own vertical residual says,
not the ±1.5 µT an accelerometer levelling shows on a turning, heaving boat."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from ahrsd.calibration.mag.backstepping import fit_backstepping  # noqa: E402
from ahrsd.calibration.mag.fit_types import MagFitInput  # noqa: E402
from ahrsd.cli.plots.backstepping import backstepping_figure  # noqa: E402
from ahrsd.core.wmm import earth_field  # noqa: E402
from ahrsd.simulation import DEFAULT_SITE, simulate  # noqa: E402


@pytest.fixture(scope="module")
def boat():
    block = simulate("boat", 240, rate_hz=50.0, seed=3)
    q = block.truth_q_wxyz
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    data = MagFitInput(block.t_s, block.mag_ut, block.accel_m_s2, block.gyro_rad_s)
    field = DEFAULT_SITE.earth_field()
    return data, roll, pitch, field


def vertical_spread_ut(fig, vertical_ut):
    """RMS of the drawn m_z about the reference Z (the figure draws m_z − Z; its label names Z)."""
    (hz,) = [ln for ax in fig.axes for ln in ax.get_lines() if ln.get_label().startswith("m_z − WMM Z")]
    assert f"({vertical_ut:.2f} µT)" in hz.get_label()
    y = np.asarray(hz.get_ydata(), dtype=float)
    return float(np.sqrt(np.mean(y ** 2)))


def test_the_figure_draws_the_vertical_field_the_fit_saw(boat):
    import matplotlib.pyplot as plt

    data, roll, pitch, field = boat
    res = fit_backstepping(data, field, roll_rad=roll, pitch_rad=pitch)
    assert res.ok, res.refused
    aided = dataclasses.replace(res, levelling=(roll, pitch, np.ones(len(roll), dtype=bool)))
    fit_vertical_ut = res.quality["vertical_channel"]["vertical_rms_ut"]
    noise_ut = 0.05                          # a few samples' magnetometer noise on top of the fit's block residual
    fig = backstepping_figure(aided, data)
    try:
        spread = vertical_spread_ut(fig, res.quality["reference"]["vertical_ut"])
        assert "levelled by the aided attitude the fit used" in " ".join(ax.get_title() for ax in fig.axes)
        # the residual the title quotes is visible: the panel spans tenths of a µT, not the 41–50 µT of the
        # absolute |H| and H_z (session 23's walk: two flat lines), with the reference as a named zero line
        (panel,) = [ax for ax in fig.axes if ax.get_ylabel() == "calibrated − reference (µT)"]
        low, high = panel.get_ylim()
        assert high - low < 20 * math.hypot(fit_vertical_ut, noise_ut) and low < 0 < high
        assert [ln for ln in panel.get_lines() if ln.get_label() == "WMM reference"]
        assert f"m_z − Z {fit_vertical_ut:.3f} µT" in " ".join(ax.get_title() for ax in fig.axes)
        # the title's residual is the fit's, at its averaged rate; the band drawn carries every sample's noise,
        # so each trace's label says its own RMS (walk26: a band of ±0.2 µT under a title of 0.014 µT looked
        # like a contradiction)
        assert f"(fit at {res.quality['fit_rate_hz']:g} Hz)" in panel.get_title()
        for line in panel.get_lines()[:2]:
            y = np.asarray(line.get_ydata(), dtype=float)
            assert f"RMS {np.sqrt(np.mean(y[np.isfinite(y)] ** 2)):.3f} µT of the samples drawn" in line.get_label()
    finally:
        plt.close(fig)
    assert spread <= 2.0 * math.hypot(fit_vertical_ut, noise_ut), (spread, fit_vertical_ut)
    # the accelerometer's levelling of the same fit (what the figure drew before) scatters far more
    fig = backstepping_figure(res, data)
    try:
        accel_spread = vertical_spread_ut(fig, res.quality["reference"]["vertical_ut"])
    finally:
        plt.close(fig)
    assert accel_spread > 3.0 * spread, (accel_spread, spread)


def test_the_accelerometer_levelled_figure_draws_the_vertical_field_the_fit_saw(boat):
    """Without --gnss the fit levels with the low-passed accelerometer and low-passes the magnetometer alike
    (the wave tilt shrinks on both sides): the figure must filter both too, or the filter's lag on one side
    only shows as a wave-period wobble of H_z that the fit's residual never had."""
    import matplotlib.pyplot as plt

    data, _, _, field = boat
    res = fit_backstepping(data, field)
    assert res.ok, res.refused
    assert "magnetometer and gyro alike" in res.quality["attitude_source"]
    fit_vertical_ut = res.quality["vertical_channel"]["vertical_rms_ut"]
    noise_ut = 0.02                          # the low-passed per-sample magnetometer noise
    fig = backstepping_figure(res, data)
    try:
        spread = vertical_spread_ut(fig, res.quality["reference"]["vertical_ut"])
        # the drawn field is low-passed, so its labels' RMS can be below the title's (the fit's unfiltered 10 Hz
        # blocks): the title says so (walk28: the tour's boat drew 0.028 µT under a title of 0.042 µT, unexplained)
        titles = " ".join(ax.get_title() for ax in fig.axes)
        assert "levelled by the accelerometer, drawn low-passed (τ 0.2 s) as fitted" in titles, titles
        # the title's two magnitude residuals, each named by its samples (walk28: "|H| residual 0.042 µT" of the
        # unfiltered blocks beside the fit's own 0.029 µT of the low-passed ones, and "|H|" read as the WMM's H,
        # the horizontal intensity the other panel's circle is)
        channel = res.quality["vertical_channel"]
        assert f"|m| − F RMS {res.residual_rms_ut:.3f} µT of the block means" in titles, titles
        assert (f"of the blocks fitted: |m| − F {channel['magnitude_rms_ut']:.3f} µT, "
                f"m_z − Z {fit_vertical_ut:.3f} µT") in titles, titles
        labels = [ln.get_label() for ax in fig.axes for ln in ax.get_lines()]
        assert any(label.startswith("WMM H (horizontal) ") for label in labels), labels
        assert not any("|H|" in label or "H_h" in label for label in labels + [titles]), labels
    finally:
        plt.close(fig)
    assert spread <= 1.5 * math.hypot(fit_vertical_ut, noise_ut), (spread, fit_vertical_ut)


def test_no_legend_searches_the_samples_for_a_free_spot(boat, monkeypatch):
    """Every legend of the figure has its place: matplotlib's default "best" searches every drawn point (a 200 s
    recording at 819.2 SPS: 160 000 per trace) and, past a second, printed a UserWarning "Creating legend with
    loc="best" can be slow with large amounts of data" into `calibrate mag --gnss --plot`'s report (walk30)."""
    import io

    import matplotlib.legend
    import matplotlib.pyplot as plt

    def searched(self, *args, **kwargs):
        raise AssertionError("a legend searched the data for the best spot")

    monkeypatch.setattr(matplotlib.legend.Legend, "_find_best_position", searched)
    data, roll, pitch, field = boat
    res = fit_backstepping(data, field, roll_rad=roll, pitch_rad=pitch)
    for fig in (backstepping_figure(res, data), backstepping_figure(res, data, roll_rad=roll, pitch_rad=pitch)):
        try:
            assert sum(ax.get_legend() is not None for ax in fig.axes) == 2
            fig.savefig(io.BytesIO(), format="png", dpi=40)
        finally:
            plt.close(fig)
