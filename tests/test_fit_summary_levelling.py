"""The report names what levelled the field: with --gnss the aided attitude, not the fit's internal "given"
(`ahrsd calibrate mag --gnss` printed "(levelled by given)")."""

from __future__ import annotations

from types import SimpleNamespace

from ahrsd.cli.fit_summary import mag_decision_lines


def _lines(quality):
    return mag_decision_lines(SimpleNamespace(quality=quality, residual_rms_ut=0.014), "accepted")


def test_aided_levelling_is_named():
    q = {"attitude_source": "given", "aided_levelling": {"estimator": "ins", "smoothed": True}}
    residual = [line for line in _lines(q) if "residual" in line][0]
    assert residual.endswith("(levelled by the GNSS-aided attitude (ins, smoothed))")
    assert "given" not in residual


def test_other_sources_are_passed_through():
    q = {"attitude_source": "accelerometer (low-pass τ=0.2 s)"}
    assert [line for line in _lines(q) if "residual" in line][0].endswith("(levelled by accelerometer (low-pass τ=0.2 s))")
    q = {"attitude_source": "given"}
    assert [line for line in _lines(q) if "residual" in line][0].endswith("(levelled by the attitude given to the fit)")
