"""Gyroscope calibration: rate-table (12 g-independent parameters, after the ADIS16405 AHRS thesis;
docs/calibration.md) and bias only.

Model: ω = M · (ω̃ − b), M a full 3×3 (scale and misalignment, 9) and b the bias (3): a
self-consistent form of the thesis's 12 g-independent parameters (its linearised rows do not match
its printed misalignment matrix T_g^P). MEMS gyros have no
spinning mass, so the thesis drops the 27 g-dependent terms; the Earth rate (7.3e-5 rad/s) is below the
ADIS16405 bias stability and is ignored.

Rate-table fit: with reference rates ω_ref (the table's known rate about its axis, expressed in the sensor
frame) and the mean raw rates of steady segments, each component i is linear in row i of M and c = M·b:

    ω_ref,i = M_i · ω̃ − c_i            (linear least squares, 4 unknowns per row, stacked segments)

Static segments (ω_ref = 0) pin the bias; turning segments about each axis in both directions give M.
`steady_segments` finds the segments in a recording; `reference_rates_from_accel` turns a table rate
magnitude into vectors using gravity (the table axis is vertical); simulated recordings carry truth instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models import GyroModel


@dataclass(frozen=True)
class GyroFitResult:
    model: GyroModel
    residual_rms_rad_s: float
    method: str                      # 'rate-table' or 'bias-only'
    quality: dict = field(default_factory=dict)
    refused: str | None = None

    @property
    def ok(self) -> bool:
        return self.refused is None

    def to_json_dict(self) -> dict:
        from ..models import _jsonable

        return {
            "method": self.method,
            "bias_rad_s": self.model.bias_rad_s.tolist(),
            "matrix": self.model.matrix.tolist(),
            "residual_rms_rad_s": _jsonable(self.residual_rms_rad_s),
            "quality": _jsonable(self.quality),
            "refused": self.refused,
        }


def fit_bias_only(gyro_rad_s: np.ndarray, matrix: np.ndarray | None = None, max_rate_rad_s: float = 0.05) -> GyroFitResult:
    """Bias from a static recording: the mean raw rate (keeping `matrix`, default identity).
    Refuses when the mean rate is too large to be a bias (the unit was turning)."""
    g = np.asarray(gyro_rad_s, dtype=np.float64)
    g = g[np.all(np.isfinite(g), axis=1)]
    m = np.eye(3) if matrix is None else np.asarray(matrix, dtype=np.float64)
    quality = {"n_used": int(g.shape[0])}
    if g.shape[0] < 10:
        return GyroFitResult(GyroModel.identity(), math.nan, "bias-only", quality,
                             f"only {g.shape[0]} samples with finite gyro rates: record the unit still for a few "
                             "seconds or more")
    bias = g.mean(axis=0)
    std = g.std(axis=0)
    quality.update(std_rad_s=std.tolist(), sigma_bias_rad_s=(std / math.sqrt(g.shape[0])).tolist())
    if np.linalg.norm(bias) > max_rate_rad_s:
        return GyroFitResult(GyroModel.identity(), math.nan, "bias-only", quality,
                             f"mean rate {np.degrees(np.linalg.norm(bias)):.2f} °/s over {g.shape[0]} samples is "
                             f"more than the {np.degrees(max_rate_rad_s):.2f} °/s a bias can be: was the unit still? "
                             "Record it at rest (not handheld, engine off) and try again")
    return GyroFitResult(GyroModel(bias, m), float(np.sqrt(np.mean(std**2))), "bias-only", quality, None)


def regressors(raw_means: np.ndarray) -> np.ndarray:
    """Rows [ω̃_x, ω̃_y, ω̃_z, −1] of the per-component regression ω_ref,i = M_i·ω̃ − c_i."""
    return np.column_stack([raw_means, -np.ones(raw_means.shape[0])])


def fit_rate_table(raw_means_rad_s: np.ndarray, reference_rad_s: np.ndarray, weights: np.ndarray | None = None,
                   max_condition: float = 100.0, max_residual_rad_s: float = 0.01) -> GyroFitResult:
    """The 12-parameter fit from steady segments: mean raw rates (N, 3) and reference rates (N, 3)."""
    raw = np.asarray(raw_means_rad_s, dtype=np.float64)
    ref = np.asarray(reference_rad_s, dtype=np.float64)
    ok = np.all(np.isfinite(raw), axis=1) & np.all(np.isfinite(ref), axis=1)
    raw, ref = raw[ok], ref[ok]
    w = np.ones(raw.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)[ok]
    quality: dict = {"segments": int(raw.shape[0])}
    turning = np.linalg.norm(ref, axis=1) > 1e-6
    axes_seen = {int(np.argmax(np.abs(r))) * 2 + (0 if r[np.argmax(np.abs(r))] > 0 else 1) for r in ref[turning]}
    quality["axes_turned"] = sorted(f"{'+' if k % 2 == 0 else '-'}{'xyz'[k // 2]}" for k in axes_seen)
    quality["static_segments"] = int((~turning).sum())
    if raw.shape[0] < 4:
        return GyroFitResult(GyroModel.identity(), math.nan, "rate-table", quality,
                             f"only {raw.shape[0]} steady segments (constant rate for ≥ 2 s; turned: "
                             f"{', '.join(quality['axes_turned']) or 'none'}): record a still period and a "
                             "constant-rate turn about each of the three sensor axes, each held 3 s or more")
    h = regressors(raw)
    sw = np.sqrt(w)[:, None]
    # Not column-normalised: a column of pure noise (an axis never turned) must show as ill-conditioned.
    cond = float(np.linalg.cond(h * sw / np.sqrt(np.sum(w))))
    quality["condition_number"] = cond
    if not np.isfinite(cond) or cond > max_condition:
        return GyroFitResult(GyroModel.identity(), math.nan, "rate-table", quality,
                             f"the segments do not separate the 12 parameters (condition number {cond:.3g}): "
                             "turn the table about each of the three sensor axes "
                             f"(seen: {', '.join(quality['axes_turned']) or 'none'})")
    sol, *_ = np.linalg.lstsq(h * sw, ref * sw, rcond=None)   # (4, 3): column i = [M_i, c_i]
    m = sol[:3].T
    c = sol[3]
    try:
        bias = np.linalg.solve(m, c)
        model = GyroModel(bias, m)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return GyroFitResult(GyroModel.identity(), math.nan, "rate-table", quality,
                             f"the fitted scale matrix is singular ({exc}): turn the table about each sensor axis, "
                             f"in both directions (seen: {', '.join(quality['axes_turned']) or 'none'})")
    resid = model.apply(raw) - ref
    rms = float(np.sqrt(np.mean(resid**2)))
    quality.update(residual_rms_rad_s=rms, residual_max_rad_s=float(np.max(np.abs(resid))))
    if rms > max_residual_rad_s:
        return GyroFitResult(GyroModel.identity(), rms, "rate-table", {**quality, "rejected_model": model.to_dict()},
                             f"residual {math.degrees(rms):.3f} °/s RMS over {raw.shape[0]} segments is more than "
                             f"{math.degrees(max_residual_rad_s):.3f} °/s: check --table-rate-deg-s against the "
                             "table's rate, and hold each rate steady (no start/stop inside a segment)")
    return GyroFitResult(model, rms, "rate-table", quality, None)


# ---------------------------------------------------------------------------------------------- segments


@dataclass(frozen=True)
class SteadySegment:
    start: int
    stop: int
    mean_gyro_rad_s: np.ndarray
    mean_accel_m_s2: np.ndarray


def steady_segments(gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray, rate_hz: float, window_s: float = 0.5,
                    min_s: float = 2.0, max_rate_change_rad_s: float = 0.01, trim_s: float = 0.5) -> list[SteadySegment]:
    """Runs of windows whose mean rate stays within `max_rate_change_rad_s` of the previous window's (a table
    at constant rate, or still), at least `min_s` long, with `trim_s` cut off both ends."""
    g = np.asarray(gyro_rad_s, dtype=np.float64)
    a = np.asarray(accel_m_s2, dtype=np.float64)
    w = max(2, int(round(window_s * rate_hz)))
    nw = g.shape[0] // w
    if nw < 2:
        return []
    gm = g[: nw * w].reshape(nw, w, 3).mean(axis=1)
    steady = np.r_[False, np.linalg.norm(np.diff(gm, axis=0), axis=1) <= max_rate_change_rad_s]
    steady[0] = steady[1] if nw > 1 else False
    trim = int(round(trim_s * rate_hz))
    out = []
    k = 0
    while k < nw:
        if not steady[k]:
            k += 1
            continue
        j = k
        # Split a run when the rate drifts (a slow ramp is a chain of small steps).
        while j < nw and steady[j] and np.linalg.norm(gm[j] - gm[k]) <= 2 * max_rate_change_rad_s:
            j += 1
        start, stop = k * w + trim, j * w - trim
        if (stop - start) / rate_hz >= min_s:
            out.append(SteadySegment(start, stop, g[start:stop].mean(axis=0), a[start:stop].mean(axis=0)))
        k = max(j, k + 1)
    return out


def reference_rates_from_accel(segments: list[SteadySegment], table_rate_rad_s: float,
                               still_threshold_rad_s: float = 0.05) -> np.ndarray:
    """Reference rates for segments of a rate-table run whose axis is vertical: zero for still segments,
    else ±table_rate along the vertical (−specific force direction = down, in sensor axes), the sign taken
    from the raw gyro (scale errors are far too small to flip it)."""
    ref = np.zeros((len(segments), 3))
    for k, s in enumerate(segments):
        if np.linalg.norm(s.mean_gyro_rad_s) < still_threshold_rad_s:
            continue
        down = -s.mean_accel_m_s2 / np.linalg.norm(s.mean_accel_m_s2)
        sign = 1.0 if float(s.mean_gyro_rad_s @ down) > 0 else -1.0
        ref[k] = sign * abs(table_rate_rad_s) * down
    return ref


def reference_rates_from_truth(segments: list[SteadySegment], truth_rate_rad_s: np.ndarray) -> np.ndarray:
    """Reference rates for segments from a truth rate per sample (simulated recordings)."""
    return np.array([truth_rate_rad_s[s.start:s.stop].mean(axis=0) for s in segments]).reshape(-1, 3)


def body_rates_from_quaternions(t_s: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """Body-frame rates (n, 3) from body→NED truth quaternions (central differences; scipy, scalar last)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(np.column_stack([q_wxyz[:, 1:], q_wxyz[:, :1]]))
    dt = np.diff(t_s)
    rel = (r[:-1].inv() * r[1:]).as_rotvec() / dt[:, None]  # body rate between samples
    out = np.empty((len(t_s), 3))
    out[1:-1] = 0.5 * (rel[:-1] + rel[1:])
    out[0], out[-1] = rel[0], rel[-1]
    return out
