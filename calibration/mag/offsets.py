"""Hard iron only, soft iron kept: the fit a field recalibration falls back to when the data cannot support
the full model (and the quick preliminary fit between the two steps of a session)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ahrsd.core.angles import down_in_body

from ..models import MagModel

if TYPE_CHECKING:  # pragma: no cover
    from ahrsd.core.wmm import EarthField


def fit_offsets_keep_soft_iron(
    raw_mag_ut: np.ndarray,
    soft_iron: np.ndarray,
    current_hard_iron_ut: np.ndarray,
    roll_rad: np.ndarray | None = None,
    pitch_rad: np.ndarray | None = None,
    reference: "EarthField | None" = None,
    prior_weight: float = 1e-3,
) -> tuple[MagModel, dict]:
    """Hard iron only, soft iron W kept: solve for c = W·h so that the corrected field u − c (u = W·raw)
    lies on a sphere and, when roll/pitch and the WMM field are known, its vertical component equals the
    WMM down component (the "vertical channel" that level data cannot give a sphere fit).

    Linear least squares in (c, k): sphere rows (u·c)/R + k/(2R) = |u|²/(2R) (k = R² − |c|²), down rows
    d·c = d·u − B_down (d = body direction of NED down). A weak prior keeps directions the data cannot
    determine at the current value instead of letting them run away. Returns (model, quality).
    """
    raw = np.asarray(raw_mag_ut, dtype=np.float64)
    w = np.asarray(soft_iron, dtype=np.float64)
    u = raw @ w.T
    c0 = w @ np.asarray(current_hard_iron_ut, dtype=np.float64)
    r_est = float(reference.total_ut) if reference is not None else float(np.mean(np.linalg.norm(u - c0, axis=1)))
    r_est = max(r_est, 1.0)
    rows = [np.column_stack([u / r_est, np.full(len(u), 1.0 / (2 * r_est))])]
    rhs = [np.sum(u * u, axis=1) / (2 * r_est)]
    used_vertical = False
    if reference is not None and roll_rad is not None and pitch_rad is not None:
        d = down_in_body(np.asarray(roll_rad, float), np.asarray(pitch_rad, float))
        rows.append(np.column_stack([d, np.zeros(len(d))]))
        rhs.append(np.sum(d * u, axis=1) - reference.down_ut)
        used_vertical = True
    # prior: c ≈ c0 (weight relative to the data rows), k free
    n = len(u)
    pw = prior_weight * math.sqrt(n)
    rows.append(np.column_stack([np.eye(3) * pw, np.zeros(3)]))
    rhs.append(c0 * pw)
    a = np.vstack(rows)
    b = np.concatenate(rhs)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    c = sol[:3]
    sv = np.linalg.svd(a[: -3, :3], compute_uv=False) if a.shape[0] > 3 else np.zeros(3)
    h = np.linalg.solve(w, c)
    model = MagModel(h, w)
    corrected = u - c
    radius = float(np.mean(np.linalg.norm(corrected, axis=1)))
    quality = {
        "n_used": int(n),
        "used_vertical_channel": used_vertical,
        "offset_condition": float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf,
        "radius_ut": radius,
    }
    return model, quality
