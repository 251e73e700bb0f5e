"""The thesis's magnetometer alignment step (the ADIS16405 AHRS thesis;
docs/calibration.md): the rotation C_m'^p that the
magnitude-only fits cannot see, from levelled turns about each platform axis.

With platform axis i vertical and the sensor turned about it, the field component along that axis is constant,
the vertical component of the Earth field (NED down component, H0·sin δ, sign by whether the axis points down
or up). Each sample of the magnitude-calibrated field H^m' gives one linear equation in row i of C_m'^p:

    H_down · s_i = [H_x^m', H_y^m', H_z^m'] · [C_i1, C_i2, C_i3]ᵀ        (s_i = +1 axis down, −1 axis up)

solved by least squares. Two axes suffice (the third row is their cross product); three over-determine it.
The noisy Ĉ is made a rotation either as the thesis does, Ĉ·chol(ĈᵀĈ)⁻¹ (upper Cholesky factor), or by the nearest
rotation in the Frobenius sense (SVD polar factor, the default: it spreads the error over all rows instead of
trusting the first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models import MagModel

AXES = "xyz"
MIN_TURN_DEG = 180.0     # a turn must sweep at least half a circle to fix the row
MAX_TILT_DEG = 5.0       # "levelled": the turn axis within 5° of the vertical (accelerometer check)
MIN_SAMPLES = 20


@dataclass(frozen=True)
class LevelTurn:
    """Samples of one levelled turn: platform `axis` ('x', 'y' or 'z') vertical, pointing 'down' or 'up'
    (None: decided from the accelerometer). mag_ut (n, 3) raw; accel_m_s2 (n, 3) optional."""

    axis: str
    mag_ut: np.ndarray
    accel_m_s2: np.ndarray | None = None
    pointing: str | None = None


@dataclass(frozen=True)
class AlignmentResult:
    rotation: np.ndarray | None          # C_m'^p (3×3 rotation) or None when refused
    raw_rows: np.ndarray | None          # Ĉ before orthogonalisation
    quality: dict = field(default_factory=dict)
    refused: str | None = None

    @property
    def ok(self) -> bool:
        return self.refused is None


def orthogonalise(c_hat: np.ndarray, method: str = "svd") -> np.ndarray:
    """Nearest rotation: 'svd' (polar factor U·Vᵀ) or 'cholesky' (the thesis: Ĉ·S⁻¹, S = chol(ĈᵀĈ) upper)."""
    if method == "svd":
        u, _, vt = np.linalg.svd(c_hat)
        r = u @ vt
        if np.linalg.det(r) < 0:  # a reflection is not a rotation
            u[:, -1] *= -1
            r = u @ vt
        return r
    if method == "cholesky":
        s_upper = np.linalg.cholesky(c_hat.T @ c_hat).T  # ĈᵀĈ = SᵀS, S upper triangular
        return c_hat @ np.linalg.inv(s_upper)
    raise ValueError(f"unknown orthogonalisation {method!r}: use 'svd' or 'cholesky'")


def _turn_span_deg(h: np.ndarray, row: np.ndarray) -> float:
    """How much of a circle the horizontal part of the field sweeps (deg): the largest gap tells."""
    row = row / np.linalg.norm(row)
    a = np.eye(3)[np.argmin(np.abs(row))]
    e1 = np.cross(row, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(row, e1)
    ang = np.sort(np.arctan2(h @ e2, h @ e1))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * math.pi]))
    return float(360.0 - math.degrees(gaps.max()))


def fit_alignment(turns: list[LevelTurn], magnitude_model: MagModel, down_ut: float, *,
                  orthogonalisation: str = "svd", max_tilt_deg: float = MAX_TILT_DEG,
                  min_turn_deg: float = MIN_TURN_DEG) -> AlignmentResult:
    """Rows of C_m'^p from levelled turns. `magnitude_model`: the three-step (or two-step) result without
    alignment; `down_ut`: the vertical component of the reference field (EarthField.down_ut, µT)."""
    quality: dict = {"turns": []}
    rows: dict[int, np.ndarray] = {}
    problems = []
    for turn in turns:
        if turn.axis not in AXES:
            raise ValueError(f"turn axis must be one of x, y, z, got {turn.axis!r}")
        i = AXES.index(turn.axis)
        info = {"axis": turn.axis}
        quality["turns"].append(info)
        row, problem = _turn_row(turn, magnitude_model, down_ut, max_tilt_deg, min_turn_deg, info)
        if problem is not None:
            problems.append(problem)
            continue
        rows[i] = row if i not in rows else 0.5 * (rows[i] + row)
    if len(rows) < 2:
        reason = "need levelled turns about at least two axes"
        if problems:
            reason += ": " + "; ".join(problems)
        return AlignmentResult(None, None, quality, reason)
    return _rotation_from_rows(rows, quality, problems, orthogonalisation)


def _turn_row(turn: LevelTurn, magnitude_model: MagModel, down_ut: float, max_tilt_deg: float,
              min_turn_deg: float, info: dict) -> tuple[np.ndarray | None, str | None]:
    """One row of C_m'^p from a levelled turn: the row r with r·h = ±(the reference's down component) over the
    magnitude-calibrated field h of the turn (least squares), or the reason the turn cannot give it (too few
    samples, not level, pointing unknown, a field that does not match the reference, too small a sweep). What
    the turn showed goes into `info`."""
    i = AXES.index(turn.axis)
    mag = np.asarray(turn.mag_ut, dtype=np.float64)
    good = np.all(np.isfinite(mag), axis=1)
    mag = mag[good]
    info["n"] = int(mag.shape[0])
    if mag.shape[0] < MIN_SAMPLES:
        return None, f"{turn.axis} turn: only {mag.shape[0]} samples (need {MIN_SAMPLES})"
    pointing = turn.pointing
    if turn.accel_m_s2 is not None:
        f = np.asarray(turn.accel_m_s2, dtype=np.float64)[good].mean(axis=0)
        # At rest the specific force points up: an axis pointing down reads −g.
        tilt = math.degrees(math.acos(min(1.0, abs(f[i]) / np.linalg.norm(f))))
        info["tilt_deg"] = tilt
        if pointing is None:
            pointing = "down" if f[i] < 0 else "up"
        if tilt > max_tilt_deg:
            return None, f"{turn.axis} turn not level: axis {tilt:.1f}° from vertical (max {max_tilt_deg}°)"
    if pointing not in ("down", "up"):
        return None, f"{turn.axis} turn: say whether the axis points down or up (no accelerometer data)"
    info["pointing"] = pointing
    h = magnitude_model.apply(mag)
    target = down_ut * (1.0 if pointing == "down" else -1.0)
    row, *_ = np.linalg.lstsq(h, np.full(h.shape[0], target), rcond=None)
    span = _turn_span_deg(h, row)
    info["turn_span_deg"] = span
    info["vertical_residual_rms_ut"] = float(np.sqrt(np.mean((h @ row - target) ** 2)))
    info["row_norm"] = float(np.linalg.norm(row))
    if abs(info["row_norm"] - 1.0) > 0.1:
        return None, (f"{turn.axis} turn: the calibrated field does not match the reference (row norm "
                      f"{info['row_norm']:.2f}, not 1): were the turns recorded with the same vehicle iron "
                      "as the magnitude calibration, and at the same site?")
    if span < min_turn_deg:
        return None, f"{turn.axis} turn swept only {span:.0f}° (need ≥ {min_turn_deg:.0f}°)"
    return row, None


def _rotation_from_rows(rows: dict[int, np.ndarray], quality: dict, problems: list[str],
                        orthogonalisation: str) -> AlignmentResult:
    """Ĉ from the rows found (with two, the third is their cross product: the rows of a rotation), refused when
    it is far from a rotation, else orthogonalised (`orthogonalise`)."""
    c_hat = np.zeros((3, 3))
    for i, r in rows.items():
        c_hat[i] = r
    if len(rows) == 2:
        missing = ({0, 1, 2} - set(rows)).pop()
        j, k = (missing + 1) % 3, (missing + 2) % 3
        c_hat[missing] = np.cross(c_hat[j], c_hat[k])  # rows of a rotation: r_i = r_j × r_k (cyclic)
        quality["third_row_from_cross_product"] = AXES[missing]
    quality["orthogonality_error"] = float(np.linalg.norm(c_hat @ c_hat.T - np.eye(3)))
    if quality["orthogonality_error"] > 0.2:
        return AlignmentResult(None, c_hat, quality,
                               f"the rows are far from a rotation (‖ĈĈᵀ − I‖ = {quality['orthogonality_error']:.2f}): "
                               "wrong reference field, wrong axis labels, or the turns were not level")
    rotation = orthogonalise(c_hat, orthogonalisation)
    quality["rotation_angle_deg"] = float(math.degrees(math.acos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))))
    if problems:
        quality["ignored"] = problems
    return AlignmentResult(rotation, c_hat, quality, None)


def segment_level_turns(gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray, mag_ut: np.ndarray, rate_hz: float,
                        min_rate_rad_s: float = 0.05, max_tilt_deg: float = MAX_TILT_DEG,
                        window_s: float = 0.5) -> list[LevelTurn]:
    """Find levelled turns in a recording (e.g. a rate-table run): windows where the sensor turns about one
    body axis that is vertical. Consecutive samples of the same axis and direction form one LevelTurn."""
    n = gyro_rad_s.shape[0]
    w = max(1, int(round(window_s * rate_hz)))
    nw = n // w
    if nw == 0:
        return []
    g = gyro_rad_s[: nw * w].reshape(nw, w, 3).mean(axis=1)
    a = accel_m_s2[: nw * w].reshape(nw, w, 3).mean(axis=1)
    labels = np.full(nw, -1)
    for k in range(nw):
        an = np.linalg.norm(a[k])
        if not an > 0:
            continue
        i = int(np.argmax(np.abs(a[k])))
        tilt = math.degrees(math.acos(min(1.0, abs(a[k, i]) / an)))
        rate = np.linalg.norm(g[k])
        # Turning about axis i, and that axis vertical.
        if tilt <= max_tilt_deg and rate >= min_rate_rad_s and abs(g[k, i]) >= 0.98 * rate:
            labels[k] = i * 2 + (0 if a[k, i] < 0 else 1)
    turns: dict[int, list[int]] = {}
    for k, lab in enumerate(labels):
        if lab >= 0:
            turns.setdefault(int(lab), []).append(k)
    out = []
    for lab, windows in sorted(turns.items()):
        idx = np.concatenate([np.arange(k * w, (k + 1) * w) for k in windows])
        out.append(LevelTurn(AXES[lab // 2], mag_ut[idx], accel_m_s2[idx], "down" if lab % 2 == 0 else "up"))
    return out
