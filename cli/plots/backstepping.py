"""The back-stepping report figure (matplotlib, the optional `plot` extra).

The field is levelled with the attitude the fit used: the aided levelling of `--gnss` when the result carries it
(MagFitResult.levelling), else the accelerometer as the fit took it, so the vertical field drawn is the one whose
residual the fit reports."""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import down_in_body, roll_pitch_from_accel, wrap_180_deg

from ahrsd.calibration.mag import swing
from ahrsd.calibration.mag.backstepping import BacksteppingOptions, fit_blocks_lowpassed
from ahrsd.calibration.mag.backstepping_paper import BacksteppingError, magnetic_heading_deg
from ahrsd.calibration.mag.fit_types import MagFitInput, MagFitResult, finite_rows
from ahrsd.calibration.mag.observability import level_vectors, lowpass
from ahrsd.core.plotting import pyplot
from ahrsd.calibration.mag.vertical_channel import centripetal_direction, corrected_down

def plot_backstepping(result: MagFitResult, data: MagFitInput, path, **options) -> None:
    """`backstepping_figure(result, data, **options)` written to `path`."""
    plt = pyplot()
    fig = backstepping_figure(result, data, **options)
    try:
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)


def backstepping_figure(result: MagFitResult, data: MagFitInput, *, roll_rad=None, pitch_rad=None,
                        reference=None, swing_table=None):
    """Report figure (returned; the caller saves and closes it): levelled horizontal field before/after (should
    be a circle of the WMM's horizontal intensity H), the calibrated field's magnitude |m| and levelled vertical m_z over
    time as departures from the reference's F and Z, and heading error vs heading when
    data.heading_ref_deg exists or a compass-swing table `swing_table=(reference_deg, compass_deg)` is given (its
    points and the fitted card). roll_rad/pitch_rad: the levelling, per row of `data` (default: the fit's own,
    `result.levelling`, then the accelerometer). Raises PlotUnavailableError when matplotlib is not installed."""
    plt = pyplot()
    d, cal, roll_rad, pitch_rad, levelled_by = _levelled(result, data, roll_rad, pitch_rad)
    raw = d.mag_ut - np.median(d.mag_ut, axis=0)
    lv_raw, lv_cal = level_vectors(raw, roll_rad, pitch_rad), level_vectors(cal, roll_rad, pitch_rad)
    has_ref = (d.heading_ref_deg is not None and np.isfinite(d.heading_ref_deg).any()) or swing_table is not None
    fig, axes = plt.subplots(1, 3 if has_ref else 2, figsize=(15 if has_ref else 10, 4.5))
    q = result.quality.get("reference", {})
    _horizontal_panel(axes[0], lv_raw, lv_cal, q)
    _field_panel(axes[1], result, d, cal, lv_cal, q, levelled_by)
    if has_ref:
        _heading_error_panel(axes[2], result, d, cal, roll_rad, pitch_rad, q, swing_table)
    fig.tight_layout()
    return fig


def _levelled(result: MagFitResult, data: MagFitInput, roll_rad, pitch_rad):
    """(the rows with a finite field, their calibrated field, roll and pitch, what levelled them): the given
    attitude, else the fit's aided levelling, else the accelerometer as the fit took it."""
    levelled_by = "the accelerometer"
    if roll_rad is None and result.levelling is not None:
        roll_rad, pitch_rad, used = result.levelling
        data = data.select(used)
        roll_rad, pitch_rad = np.asarray(roll_rad)[used], np.asarray(pitch_rad)[used]
        levelled_by = "the aided attitude the fit used"
    elif roll_rad is not None:
        levelled_by = "the given attitude"
    ok = finite_rows(data.mag_ut)
    d = data.select(ok)
    cal = result.model.apply(d.mag_ut)
    gyro_rad_s = d.gyro_rad_s
    if roll_rad is None:
        if d.accel_m_s2 is None:
            raise BacksteppingError("plot needs roll/pitch or accelerometer samples")
        tau_s = BacksteppingOptions.accel_tau_s
        roll_rad, pitch_rad = roll_pitch_from_accel(lowpass(d.accel_m_s2, d.t_s, tau_s))
        if fit_blocks_lowpassed(result.quality):
            # the fit low-passed the magnetometer and gyro with the accelerometer (backstepping._levelling_attitude:
            # the wave tilt then shrinks on both sides); levelling the raw field with the filtered tilt would draw
            # the filter's lag as a wave-period wobble of the vertical field that the fit never had
            cal = lowpass(cal, d.t_s, tau_s)
            gyro_rad_s = None if gyro_rad_s is None else lowpass(gyro_rad_s, d.t_s, tau_s)
            # said, since every drawn sample is then quieter than the fit's unfiltered 10 Hz blocks the title's
            # residual is of (unsaid, the drawn residual reads smaller than the title's)
            levelled_by = f"the accelerometer, drawn low-passed (τ {tau_s:g} s) as fitted"
        # level as the fit did: without the accelerometer's lean into turns (the fitted forward speed)
        speed = result.quality.get("vertical_channel", {}).get("centripetal_speed_m_s")
        if isinstance(speed, (int, float)) and gyro_rad_s is not None:
            d0 = down_in_body(roll_rad, pitch_rad)
            dn = corrected_down(d0, centripetal_direction(gyro_rad_s, d0), speed)
            roll_rad, pitch_rad = np.arctan2(dn[:, 1], dn[:, 2]), -np.arcsin(np.clip(dn[:, 0], -1.0, 1.0))
    else:
        roll_rad, pitch_rad = np.asarray(roll_rad)[ok], np.asarray(pitch_rad)[ok]
    return d, cal, roll_rad, pitch_rad, levelled_by


def _horizontal_panel(ax, lv_raw, lv_cal, q: dict) -> None:
    """The levelled horizontal field, raw (centred) and calibrated, against the WMM's horizontal intensity."""
    ax.plot(lv_raw[:, 1], lv_raw[:, 0], ".", ms=1, label="raw (centred)")
    ax.plot(lv_cal[:, 1], lv_cal[:, 0], ".", ms=1, label="calibrated")
    if q.get("vertical_ut") is not None:
        hh = math.sqrt(max(q["total_ut"] ** 2 - q["vertical_ut"] ** 2, 0))
        th = np.linspace(0, 2 * math.pi, 200)
        ax.plot(hh * np.sin(th), hh * np.cos(th), "k--", lw=0.8, label=f"WMM H (horizontal) {hh:.1f} µT")
    ax.set_aspect("equal")
    ax.set_xlabel("east-ish (µT)")
    ax.set_ylabel("north-ish (µT)")
    ax.set_title("levelled horizontal field")
    _legend_below(ax, markerscale=8)


def _field_panel(ax, result: MagFitResult, d: MagFitInput, cal, lv_cal, q: dict, levelled_by: str) -> None:
    """The calibrated field's magnitude |m| and levelled vertical m_z over time, as their departures from the
    reference's total F and vertical Z (the WMM's names; its H is the horizontal intensity of the other panel):
    drawn as absolutes (41–50 µT) the hundredths of a µT the title quotes were two flat lines; as departures the
    residual is what the eye sees, against the zero line of the reference. The title names each residual by the
    samples it is of (the unfiltered block means, or the blocks fitted), the labels that of the samples drawn."""
    total, vertical_ref = q.get("total_ut"), q.get("vertical_ut")
    magnitude, vertical = np.linalg.norm(cal, axis=1), lv_cal[:, 2]
    if total and vertical_ref is not None:
        # each trace's own RMS in its label: the samples drawn here carry every sample's noise, which the fit's
        # averaged blocks (the title's residual) do not, so the eye sees a wider band than the title quotes
        for departure, name in ((magnitude - total, f"|m| − WMM F ({total:.2f} µT)"),
                                (vertical - vertical_ref, f"m_z − WMM Z ({vertical_ref:.2f} µT)")):
            ax.plot(d.t_s, departure, lw=0.6, label=f"{name}: RMS {_rms(departure):.3f} µT of the samples drawn")
        ax.axhline(0.0, color="k", ls="--", lw=0.8, label="WMM reference")
        ax.set_ylabel("calibrated − reference (µT)")
    else:   # no reference field: the values themselves
        ax.plot(d.t_s, magnitude, lw=0.6, label="|m| calibrated")
        ax.plot(d.t_s, vertical, lw=0.6, label="m_z calibrated")
        ax.set_ylabel("µT")
    ax.set_xlabel("t (s)")
    channel = result.quality.get("vertical_channel") or {}
    vertical_rms, magnitude_fitted = channel.get("vertical_rms_ut"), channel.get("magnitude_rms_ut")
    fit_rate_hz = result.quality.get("fit_rate_hz")
    at_rate = f" (fit at {fit_rate_hz:g} Hz)" if isinstance(fit_rate_hz, (int, float)) else ""
    fitted = []     # the vertical-channel fit's own residuals, of the (low-passed, when so levelled) blocks it fitted
    if fit_blocks_lowpassed(result.quality) and isinstance(magnitude_fitted, (int, float)):
        fitted.append(f"|m| − F {magnitude_fitted:.3f} µT")
    if isinstance(vertical_rms, (int, float)):
        fitted.append(f"m_z − Z {vertical_rms:.3f} µT")
    ax.set_title(f"{result.method}{at_rate}: |m| − F RMS {result.residual_rms_ut:.3f} µT"
                 + (" of the block means" if at_rate else "")
                 + (f"\nof the blocks fitted: {', '.join(fitted)}" if fitted else "")
                 + f"\nlevelled by {levelled_by}", fontsize=9)
    _legend_below(ax)


def _legend_below(ax, **options) -> None:
    """The legend under the panel, outside it: matplotlib's default "best" searched a 200 s recording's 160 000
    points for a free spot (seconds, and a UserWarning "Creating legend with loc="best" can be slow" printed to
    the user), and inside the circle panel it covered the raw field it sat on."""
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), borderaxespad=0.0, fontsize=7, **options)


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def _heading_error_panel(ax, result: MagFitResult, d: MagFitInput, cal, roll_rad, pitch_rad, q: dict,
                         swing_table) -> None:
    """Reference minus calibrated magnetometer heading against heading: the recording's heading_ref_deg, the
    swing table's points and the fitted card."""
    if d.heading_ref_deg is not None and np.isfinite(d.heading_ref_deg).any():
        psi = magnetic_heading_deg(cal, roll_rad, pitch_rad)
        decl = q.get("declination_deg", 0.0) or 0.0
        err = wrap_180_deg((d.heading_ref_deg - decl) - psi)
        ax.plot(psi, err, ".", ms=2, label="recording (heading_ref_deg)")
    if swing_table is not None:
        ref_deg, compass_deg = (np.asarray(a, dtype=np.float64) for a in swing_table)
        ax.plot(compass_deg, wrap_180_deg(ref_deg - compass_deg), "o", label="swing table")
        card = result.quality.get("heading_reference", {})
        if "B_deg" in card:
            grid = np.linspace(0.0, 360.0, 181)
            coef = swing.DeviationCoefficients(card["A_deg"], card["B_deg"], card["C_deg"], card["D_deg"],
                                               card["E_deg"])
            ax.plot(grid, coef.deviation_deg(grid), "k-", lw=0.8, label="card A..E (before folding A)")
    ax.legend(fontsize=7)
    ax.set_xlabel("magnetic heading (deg)")
    ax.set_ylabel("reference − magnetometer (deg)")
    ax.set_title("heading error vs heading")
