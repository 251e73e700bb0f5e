"""A compass-swing table applied to a magnetometer fit: fit the deviation card to it and fold A into the model.

The table is the CSV `reference_deg,compass_deg` of `swing.load_swing_table` (compass = the heading the new
calibration gives). The card δψ = A + B sinψ + C cosψ + D sin2ψ + E cos2ψ (NGA Pub. 226, "Handbook of
Magnetic Compass Adjustment") is fitted to it; the constant A is folded into the soft iron (heading += A,
magnitude unchanged) and the whole card is kept in quality["heading_reference"]: MagModel has no terms for
B..E, so they are reported, not applied.
"""

from __future__ import annotations

import dataclasses

from . import swing
from .backstepping import fold_heading_offset
from .fit_types import MagFitResult

def apply_swing_table(result: MagFitResult, reference_deg, compass_deg, path) -> MagFitResult:
    """`result` with A folded into its model and the card in quality["heading_reference"] (an earlier
    heading_reference, from the recording's own column, moves to "heading_reference_column").

    Falls back to A alone when the headings cannot determine B..E; raises swing.SwingFitError when not even A
    can be fitted.
    """
    card, card_report = swing.fit_deviation_card(compass_deg, reference_deg)
    rep = {"source": "swing-table", "file": str(path), **card_report, "folded_offset_deg": card.a_deg}
    quality = dict(result.quality)
    if "heading_reference" in quality:
        quality["heading_reference_column"] = quality.pop("heading_reference")
    quality["heading_reference"] = rep
    return dataclasses.replace(result, model=fold_heading_offset(result.model, card.a_deg), quality=quality)
