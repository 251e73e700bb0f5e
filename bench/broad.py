"""BROAD trials: loading, frame conversion and BROAD's own error metric (shared by the benchmarks and tests).

BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD—A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7), 2021, doi:10.3390/data6070072 (CC BY 4.0). Format and metric: the BROAD
repository's README (github.com/dlaidig/broad).

The truth is IMU → ENU referenced to *magnetic* north; ahrsd estimates IMU → NED, so every estimate is
converted with q_enu = [0, 1/√2, 1/√2, 0] ⊗ q_ned and heading is magnetic (no declination).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ahrsd.estimator.rotations import quat_multiply

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("AHRSD_SHARED", REPO.parent / "shared"))
BROAD_DIR = SHARED / "data" / "broad"

_S = 1.0 / np.sqrt(2.0)
Q_NED_TO_ENU = np.array([0.0, _S, _S, 0.0])  # data README: NED → ENU rotation, scalar first


@dataclass(frozen=True)
class BroadTrial:
    name: str
    rate_hz: float
    gyro_rad_s: np.ndarray    # (N, 3)
    accel_m_s2: np.ndarray    # (N, 3) specific force
    mag_ut: np.ndarray        # (N, 3)
    truth_q_enu: np.ndarray   # (N, 4) IMU → ENU(magnetic), scalar first, NaN where markers were lost
    movement: np.ndarray      # (N,) bool

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(len(self.gyro_rad_s)) / self.rate_hz

    @property
    def disturbed(self) -> bool:
        return "_disturbed_" in self.name


@dataclass(frozen=True)
class BroadErrors:
    """RMSE in degrees over movement-phase samples with valid truth (BROAD's metric)."""

    total_deg: float
    heading_deg: float
    inclination_deg: float


def trial_paths(broad_dir: Path | None = None, names: list[str] | None = None) -> list[Path]:
    """The trial files, sorted; `names` filters by prefix or substring (e.g. "01", "magnet")."""
    paths = sorted(Path(broad_dir or BROAD_DIR).glob("*.npz"))
    if names:
        paths = [p for p in paths if any(p.stem.startswith(n) or n in p.stem for n in names)]
    return paths


def load_trial(path: Path, max_samples: int | None = None) -> BroadTrial:
    d = np.load(path)
    sl = slice(0, max_samples)
    return BroadTrial(
        name=Path(path).stem,
        rate_hz=float(d["sampling_rate_hz"]),
        gyro_rad_s=np.ascontiguousarray(d["gyro_rad_s"][sl], dtype=np.float64),
        accel_m_s2=np.ascontiguousarray(d["accel_m_s2"][sl], dtype=np.float64),
        mag_ut=np.ascontiguousarray(d["mag_ut"][sl], dtype=np.float64),
        truth_q_enu=np.asarray(d["truth_quat_wxyz"][sl], dtype=np.float64),
        movement=np.asarray(d["movement"][sl], dtype=bool),
    )


def ned_to_enu(q_ned_wxyz: np.ndarray) -> np.ndarray:
    """IMU→NED quaternions (N, 4) → IMU→ENU quaternions (N, 4)."""
    return quat_multiply(Q_NED_TO_ENU, q_ned_wxyz)


def broad_errors(q_est_enu: np.ndarray, trial: BroadTrial) -> BroadErrors:
    """BROAD's metric: q_err = q_est ⊗ conj(q_truth); total 2·acos|w|, heading 2·atan|z/w|,
    inclination 2·acos√(w²+z²); RMSE over movement samples whose truth is not NaN."""
    truth = trial.truth_q_enu
    conj = truth * np.array([1.0, -1.0, -1.0, -1.0])
    err = quat_multiply(q_est_enu, conj)
    err /= np.linalg.norm(err, axis=1, keepdims=True)
    w = np.abs(err[:, 0])
    z = err[:, 3]
    total = 2.0 * np.arccos(np.clip(w, -1.0, 1.0))
    heading = 2.0 * np.arctan(np.abs(z / np.where(w == 0.0, 1e-300, w)))
    incl = 2.0 * np.arccos(np.clip(np.sqrt(err[:, 0] ** 2 + z**2), -1.0, 1.0))
    valid = trial.movement & np.all(np.isfinite(truth), axis=1)

    def rmse(e):
        return float(np.degrees(np.sqrt(np.mean(e[valid] ** 2))))

    return BroadErrors(rmse(total), rmse(heading), rmse(incl))


def error_series_deg(q_est_enu: np.ndarray, trial: BroadTrial) -> np.ndarray:
    """Per-sample total error in degrees (NaN where truth is missing), for plotting and diagnosis."""
    conj = trial.truth_q_enu * np.array([1.0, -1.0, -1.0, -1.0])
    err = quat_multiply(q_est_enu, conj)
    err /= np.linalg.norm(err, axis=1, keepdims=True)
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(err[:, 0]), 0.0, 1.0)))
