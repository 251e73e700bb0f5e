"""Calibration results as text for a person: the lines `ahrsd calibrate` prints (the JSON form is to_json_dict).

Each function returns a list of lines (two-space indented under the caller's title line); nothing here prints.
"""

from __future__ import annotations

import math

import numpy as np

# quality entries shown elsewhere (the model lines, the deviation card) or too long for a terminal
_QUALITY_NOT_LISTED = ("position_residuals_m_s2", "faces", "rejected_model", "initial_hard_iron_ut",
                       "heading_reference", "holds", "face_alignment")
_ALLAN_UNITS = {"gyro": ("ARW", "rad/s/√Hz", "rad/s"), "accel": ("VRW", "m/s²/√Hz", "m/s²"),
                "mag": ("white", "µT/√Hz", "µT")}


def fmt_vec(v, fmt: str = "{:+.5f}") -> str:
    return "[" + ", ".join(fmt.format(x) for x in v) + "]"


def fmt_mat(m, fmt: str = "{:+.6f}", indent: str = "    ") -> str:
    return "\n".join(indent + fmt_vec(row, fmt) for row in m)


def sig_figs(value: float, digits: int = 3) -> str:
    """`value` with `digits` significant digits, trailing zeros kept (2.00, not 2: a figure that says how well it
    is known), exponent form only where plain digits would not show them (as :g: 1.23e+04, 4.56e-05)."""
    text = f"{value:#.{digits}g}"
    return text if "e" in text else text.rstrip(".")


def fmt_value(value) -> str:
    """Quality values for a person: 4 significant digits."""
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(fmt_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {fmt_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def accel_model_lines(model, result) -> list[str]:
    """An AccelModel and the residual of the fit (AccelFitResult) that made it."""
    q = result.quality
    return [
        "  bias (m/s²): " + fmt_vec(model.bias_m_s2),
        "  matrix:\n" + fmt_mat(model.matrix),
        "  quadratic (1/(m/s²)): " + fmt_vec(model.quadratic, "{:+.3e}"),
        f"  residual |f| − g: RMS {result.residual_rms_m_s2 * 1e3:.3f} mm/s², "
        f"max {q.get('residual_max_m_s2', float('nan')) * 1e3:.3f} mm/s²",
    ]


def accel_alignment_line(alignment: dict) -> str:
    """The housing alignment of `calibrate accel --align-to-faces` (accel_alignment.align_to_faces)."""
    return (f"  housing alignment: a rotation of {alignment['rotation_deg']:.3f}° (rotation vector "
            + fmt_vec(alignment["rotation_vector_deg"], "{:+.3f}") + " deg), after which the six faces agree to "
            f"{alignment['face_residual_rms_deg']:.3f}° RMS")


def accel_holds_line(holds: dict, min_still_s: float) -> str:
    """What the still periods' lengths cost (inertial.accel.hold_cost): how long the holds were, the noise each
    position mean carries against a 10-s hold's, and what was too short to use."""
    mg = 1e3 / 9.80665
    parts = []
    if "hold_s_min" in holds:
        parts.append(f"holds {holds['hold_s_min']:.1f}–{holds['hold_s_median']:.1f} s (shortest–median), each "
                     f"averaged over ≥ {holds['averaged_s_min']:.1f} s; noise on each position mean "
                     f"{holds['position_noise_m_s2_median'] * mg:.2f} mg median, {holds['position_noise_m_s2_max'] * mg:.2f} "
                     f"mg worst (10-s holds: {holds['position_noise_m_s2_10s_hold'] * mg:.2f} mg)")
    skipped = holds.get("still_periods_skipped_short", 0)
    if skipped:
        parts.append(f"{skipped} still period{'s' if skipped != 1 else ''} shorter than --min-still-s "
                     f"{min_still_s:g} not used (the longest {holds['skipped_longest_s']:.1f} s)")
    return "  " + "; ".join(parts) if parts else ""


def gyro_model_lines(model, result) -> list[str]:
    """A GyroModel and the residual of the fit that made it."""
    return [
        "  bias (rad/s): " + fmt_vec(model.bias_rad_s, "{:+.6f}")
        + "  (°/s: " + fmt_vec(np.degrees(model.bias_rad_s), "{:+.4f}") + ")",
        "  matrix:\n" + fmt_mat(model.matrix),
        f"  residual RMS {math.degrees(result.residual_rms_rad_s):.4f} °/s",
    ]


def mag_model_lines(model, result) -> list[str]:
    """A MagModel, the fit's residual and coverage, and the deviation card when there is one."""
    q = result.quality
    rate_hz = q.get("fit_rate_hz")    # the back-stepping fit's blocks: their means, not every sample
    of_what = f" of the {rate_hz:g} Hz block means" if isinstance(rate_hz, (int, float)) else ""
    return [
        "  hard iron (µT): " + fmt_vec(model.hard_iron_ut, "{:+.3f}"),
        "  soft iron:\n" + fmt_mat(model.soft_iron),
        f"  residual | |m| − |F| |: RMS {result.residual_rms_ut:.3f} µT, "
        f"max {q.get('residual_max_ut', float('nan')):.3f} µT{of_what}",
        f"  coverage {q.get('coverage', float('nan')):.0%}; hard-iron 1σ "
        + fmt_vec(q.get("sigma_hard_iron_ut", [float("nan")] * 3), "{:.3f}") + " µT",
        *deviation_card_lines(q),
    ]


def deviation_card_lines(quality: dict) -> list[str]:
    """The deviation card A..E in quality["heading_reference"] (none: no lines)."""
    rep = quality.get("heading_reference")
    if not rep:
        return []
    src = "swing table " + rep["file"] if rep.get("source") == "swing-table" else "heading_ref_deg column"
    lines = [f"  deviation card from the {src} ({rep.get('n')} headings; δψ = A + B sinψ + C cosψ + D sin2ψ + E cos2ψ):",
             f"    A {rep['A_deg']:+.2f}° (A alone {rep['A_only_deg']:+.2f}°), folded into the soft iron: "
             f"{rep.get('folded_offset_deg', 0.0):+.2f}°",
             f"    B {rep['B_deg']:+.2f}°  C {rep['C_deg']:+.2f}°  D {rep['D_deg']:+.2f}°  E {rep['E_deg']:+.2f}°"
             "  (reported, not applied; near 0 after a good field fit)",
             f"    heading RMS vs the reference {rep['rms_before_deg']:.2f}° before the card, "
             f"{rep['rms_after_deg']:.2f}° after A..E"]
    for key in ("note", "warning"):
        if rep.get(key):
            lines.append(f"    {key}: {rep[key]}")
    return lines
