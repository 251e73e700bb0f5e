"""A compass-swing table applied to a magnetometer fit: fit the deviation card to it and fold A into the model.

The table is the CSV `reference_deg,compass_deg` of `swing.load_swing_table` (compass = the heading the new
calibration gives). The card δψ = A + B sinψ + C cosψ + D sin2ψ + E cos2ψ (NGA Pub. 226, "Handbook of
Magnetic Compass Adjustment") is fitted to it; the constant A is folded into the soft iron (heading += A,
magnitude unchanged) and the whole card is kept in quality["heading_reference"]: MagModel has no terms for
B..E, so they are reported, not applied.
"""

from __future__ import annotations

import dataclasses
import math

from . import swing
from .backstepping import fold_heading_offset
from .magfit import MagFitResult

# A of the full fit and A alone differ by more than this when the headings are too few or bunched together
A_AGREEMENT_DEG = 1.0


def fit_deviation_card(heading_deg, reference_deg, reference_name: str = "swing headings") -> tuple[
        swing.DeviationCoefficients, dict]:
    """The card A..E of `heading_deg` against `reference_deg` and its report: the card's to_dict(), a "note"
    when the headings could give A only, a "warning" when A of the full fit and A alone disagree (headings
    too few or bunched). Raises swing.SwingFitError when not even A can be fitted."""
    rep: dict = {}
    try:
        card = swing.fit_deviation(heading_deg, reference_deg)
    except swing.SwingFitError as exc:
        card = swing.fit_offset(heading_deg, reference_deg)
        rep["note"] = f"A only: {exc}"
    rep.update(card.to_dict())
    if math.isfinite(card.a_only_deg) and abs(card.a_deg - card.a_only_deg) > A_AGREEMENT_DEG:
        rep["warning"] = (f"A of the full fit ({card.a_deg:.2f}°) differs from A alone ({card.a_only_deg:.2f}°): the "
                          f"{reference_name} are too few or unevenly spread (seed 002 §5)")
    return card, rep


def apply_swing_table(result: MagFitResult, reference_deg, compass_deg, path) -> MagFitResult:
    """`result` with A folded into its model and the card in quality["heading_reference"] (an earlier
    heading_reference, from the recording's own column, moves to "heading_reference_column").

    Falls back to A alone when the headings cannot determine B..E; raises swing.SwingFitError when not even A
    can be fitted.
    """
    card, card_report = fit_deviation_card(compass_deg, reference_deg)
    rep = {"source": "swing-table", "file": str(path), **card_report, "folded_offset_deg": card.a_deg}
    quality = dict(result.quality)
    if "heading_reference" in quality:
        quality["heading_reference_column"] = quality.pop("heading_reference")
    quality["heading_reference"] = rep
    return dataclasses.replace(result, model=fold_heading_offset(result.model, card.a_deg), quality=quality)
