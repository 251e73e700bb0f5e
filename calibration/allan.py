"""Allan-variance noise analysis of a static recording (thesis §8.3–8.4, IEEE Std 952 conventions).

`allan_deviation(x, rate_hz)` computes the *overlapping* Allan deviation on log-spaced cluster sizes from
the cumulative sum in O(n) per τ (vectorised; hours of 100 Hz data take well under a second per axis).

`noise_parameters(taus, adev)` reads the curve the way the thesis does (§8.3), made robust:
  - white noise N (ARW for gyros, rad/s/√Hz = rad/√s; VRW for accelerometers, m/s²/√Hz): the slope −1/2
    line σ = N/√τ, read at τ = 1 s. The line is fitted (fixed slope, in log space) to every τ where the
    local slope is within ±0.15 of −1/2 and the curve is well above the flat floor, after removing the
    floor (the model's constant term) in variance; without such a region the model's τ⁻¹ term is used.
  - bias instability B: the flat region; B = σ_flat / 0.664 (IEEE Std 952: flicker noise gives
    σ = √(2 ln2/π)·B ≈ 0.664·B). The flat level is read from a smooth model σ²(τ) = 3Q²/τ² + N²/τ + F
    [+ s·GM(τ; Tc)] + K²τ/3 fitted to the whole curve by non-negative least squares, so one noisy long-τ
    point does not decide it (the raw curve minimum is reported beside it). A first-order Gauss–Markov
    bias (a bump instead of a floor, as in the simulator) is detected and reported as its σ and Tc
    (gauss_markov_sigma, gauss_markov_tau_s); the IEEE reading of such a bump is 0.617/0.664 = 0.93 σ.
  - rate random walk K (slope +1/2, σ = K·√(τ/3), read at τ = 3 s) and quantization Q (slope −1,
    σ = √3·Q/τ) when the fit finds them (else None).

`kalman_tuning(...)` turns the results into the thesis's filter noise (§8.4, eq. 6-1/6-2):
Q = diag((3·ARW)², (3·ARW/10)²) [rad²/s], R = diag(σ_mag², σ_accel²) from the output standard deviation.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.6643, IEEE Std 952-1997 Table B.1
Q_INFLATION = 3.0          # thesis §8.4 eq. 5-8: diagonal Q inflated ×3 for correlated axes
BIAS_DRIVE_FRACTION = 0.1  # thesis eq. 6-1: bias-driving noise = ARW/10


def cluster_sizes(n_samples: int, points_per_octave: int = 4, max_fraction: float = 0.25) -> np.ndarray:
    """Log-spaced cluster sizes m (samples) from 1 to max_fraction·n (unique integers)."""
    m_max = max(1, int(n_samples * max_fraction))
    count = int(math.floor(math.log2(m_max) * points_per_octave)) + 1
    m = np.unique(np.round(2.0 ** (np.arange(count) / points_per_octave)).astype(np.int64))
    return m[m <= m_max]


def allan_deviation(x: np.ndarray, rate_hz: float, m: np.ndarray | None = None,
                    points_per_octave: int = 4, overlap_stride: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of rate samples `x` ((n,) or (n, k) columns) sampled at `rate_hz`.

    Returns (taus_s (j,), adev (j,) or (j, k), n_terms (j,)): n_terms is the number of overlapping
    differences behind each point (for confidence: relative error ≈ 1/√(2·(n/m − 1)) at worst).
    overlap_stride: > 0 takes cluster starts every max(1, stride·m) samples instead of every sample (faster
    on very long records, e.g. 1/8: −40 % time on 4 h at 100 Hz, but the long-τ points then scatter up to
    ~15 % more). Default 0: every sample, the textbook fully overlapping form.
    """
    x = np.asarray(x, dtype=np.float64)
    squeeze = x.ndim == 1
    if squeeze:
        x = x[:, None]
    n = x.shape[0]
    if n < 8:
        raise ValueError(f"Allan variance needs at least 8 samples, got {n}")
    if not np.all(np.isfinite(x)):
        raise ValueError("Allan variance input contains non-finite samples")
    dt = 1.0 / float(rate_hz)
    m = cluster_sizes(n, points_per_octave) if m is None else np.asarray(m, dtype=np.int64)
    # theta_k = sum of the first k samples (times dt): cluster averages are differences of theta.
    x = x - x.mean(axis=0)  # removes the mean: improves the cumulative sum's conditioning, not the result
    theta = np.zeros((n + 1, x.shape[1]))
    np.cumsum(x, axis=0, out=theta[1:])
    theta *= dt
    adev = np.empty((len(m), x.shape[1]))
    n_terms = np.empty(len(m), dtype=np.int64)
    buf = np.empty((n, x.shape[1]))
    for i, mi in enumerate(m):
        step = max(1, int(overlap_stride * mi))
        hi, mid, lo = theta[2 * mi::step], theta[mi:-mi:step], theta[:-2 * mi:step]
        k = lo.shape[0]
        d = buf[:k]  # θ[j+2m] − 2θ[j+m] + θ[j], in place (no temporaries: hours of data stay fast)
        np.subtract(hi[:k], mid[:k], out=d)
        np.subtract(d, mid[:k], out=d)
        np.add(d, lo, out=d)
        tau = mi * dt
        n_terms[i] = k
        adev[i] = np.sqrt(np.einsum("ij,ij->j", d, d) / (2.0 * tau * tau * k))
    taus = m * dt
    return taus, (adev[:, 0] if squeeze else adev), n_terms


@dataclass(frozen=True)
class NoiseParameters:
    """Noise of one sensor axis read off its Allan deviation. Units: u = the sample unit (rad/s, m/s², µT).

    white_noise: u/√Hz (= u·√s; ARW rad/√s, VRW m/s/√s); bias_instability: u; rate_random_walk: u/√s;
    quantization: u·s; tau_bias_instability_s: where the flat minimum is; flags: what was not seen.
    """

    white_noise: float
    bias_instability: float | None
    rate_random_walk: float | None
    quantization: float | None
    tau_bias_instability_s: float | None
    curve_minimum: float
    tau_curve_minimum_s: float
    std: float
    gauss_markov_sigma: float | None = None
    gauss_markov_tau_s: float | None = None
    flags: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["flags"] = list(self.flags)
        return d


def gauss_markov_avar(taus: np.ndarray, corr_time_s: float) -> np.ndarray:
    """Allan variance of a unit-variance first-order Gauss–Markov process with correlation time Tc:
    σ²(τ) = (2Tc/τ)·[1 − Tc/(2τ)·(3 − 4e^(−τ/Tc) + e^(−2τ/Tc))]  (IEEE Std 952 Annex C / El-Sheimy 2008)."""
    x = np.asarray(taus, dtype=np.float64) / corr_time_s
    small = x < 1e-3  # series limit avoids cancellation: σ² ≈ x·(1 − x/3)·... → x for tiny x... use Taylor
    out = np.empty_like(x)
    xs = x[~small]
    out[~small] = (2.0 / xs) * (1.0 - (3.0 - 4.0 * np.exp(-xs) + np.exp(-2.0 * xs)) / (2.0 * xs))
    xt = x[small]
    out[small] = (2.0 / 3.0) * xt - (1.0 / 2.0) * xt**2  # Taylor: (2/x)[x/3 − x²/4 + …]... = 2x/3 − x²/2
    return out


@dataclass(frozen=True)
class _CurveModel:
    """σ²(τ) = 3Q²/τ² + N²/τ + F + Σ_j s_j·GM(τ; Tc_j) + K²τ/3, every coefficient ≥ 0 (NNLS)."""

    quant_var: float      # 3Q² coefficient of τ⁻²
    white_var: float      # N²
    flat_var: float       # F (flicker floor, = (0.664 B)² for pure flicker noise)
    gm_var: np.ndarray    # s_j: variances of the Gauss–Markov components
    gm_tc: np.ndarray     # their correlation times Tc_j (s)
    rrw_var: float        # K²/3 coefficient of τ

    def bias_component(self, taus: np.ndarray) -> np.ndarray:
        """Allan variance of the bias-instability part (flicker floor + Gauss–Markov terms)."""
        out = np.full_like(np.asarray(taus, dtype=np.float64), self.flat_var)
        for s, tc in zip(self.gm_var, self.gm_tc):
            if s > 0:
                out = out + s * gauss_markov_avar(taus, tc)
        return out

    def avar(self, taus: np.ndarray) -> np.ndarray:
        t = np.asarray(taus, dtype=np.float64)
        return self.quant_var / t**2 + self.white_var / t + self.bias_component(t) + self.rrw_var * t


GM_SELECTION_RATIO = 6.0  # keep the Gauss–Markov term only if it cuts the weighted residual² this much


def _model_fit(taus: np.ndarray, adev: np.ndarray, n_terms: np.ndarray, rate_hz: float) -> _CurveModel:
    """Weighted NNLS fit of σ² = 3Q²/τ² + N²/τ + F + s·GM(τ; Tc) + K²τ/3 to one Allan curve.

    The bias-instability part is a flicker floor F, plus — only when the curve needs it — one Gauss–Markov
    term (the exponentially correlated bias most simulators and some sensors have: a bump on the curve,
    no flat floor). Tc is searched on a log grid (8 per octave, from 10·τ_min — shorter ones would mimic
    white noise — to the longest τ); the other coefficients are linear (NNLS) for each Tc. The GM term is
    kept only if it cuts the weighted residual² by `GM_SELECTION_RATIO` (measured: pure flicker noise gains
    at most ×3.6 from it by fitting long-τ scatter, which would inflate the reading; a real GM bump gains
    ×20 or more). Points are weighted by 1/σ² (relative error) times the √ of the number of independent
    clusters, so many-cluster short-τ and few-cluster long-τ points count fairly.
    """
    from scipy.optimize import nnls

    avar = adev**2
    m = np.maximum(np.round(taus * rate_hz), 1.0)
    independent = np.maximum(np.asarray(n_terms) / m, 1.0)
    w = np.sqrt(independent) / avar

    def solve(cols):
        basis = np.column_stack(cols) * w[:, None]
        scale = np.max(np.abs(basis), axis=0)
        scale[scale == 0] = 1.0
        coef, resid = nnls(basis / scale, avar * w, maxiter=200)
        return coef / scale, resid**2

    fixed = [taus**-2.0, taus**-1.0, np.ones_like(taus)]
    base, base_r2 = solve(fixed + [taus])
    tc_min = max(10.0 * taus[0], 1.0 / rate_hz)
    best = None
    for tc in np.geomspace(tc_min, taus[-1], max(2, int(8 * math.log2(taus[-1] / tc_min)) + 1)):
        coef, r2 = solve(fixed + [gauss_markov_avar(taus, tc), taus])
        if best is None or r2 < best[1]:
            best = (coef, r2, tc)
    coef, r2, tc = best
    if coef[3] > 0 and base_r2 >= GM_SELECTION_RATIO * r2:
        return _CurveModel(float(coef[0]), float(coef[1]), float(coef[2]), np.array([coef[3]]), np.array([tc]),
                           float(coef[4]))
    return _CurveModel(float(base[0]), float(base[1]), float(base[2]), np.zeros(0), np.zeros(0), float(base[3]))


def noise_parameters(taus: np.ndarray, adev: np.ndarray, n_terms: np.ndarray, rate_hz: float,
                     std: float = math.nan) -> NoiseParameters:
    """Read white noise, bias instability, rate random walk and quantization from one Allan curve."""
    taus = np.asarray(taus, dtype=np.float64)
    adev = np.asarray(adev, dtype=np.float64)
    flags: list[str] = []
    model = _model_fit(taus, adev, np.asarray(n_terms), rate_hz)

    # White noise: fixed-slope −1/2 line through the points where the curve has that slope, after
    # removing the model's other terms in variance (they lift the line by a few %).
    logt, logs = np.log(taus), np.log(adev)
    slope = np.gradient(logs, logt)
    others = model.avar(taus) - model.white_var / taus
    on_line = (np.abs(slope + 0.5) < 0.15) & (adev**2 > 4.0 * others)
    if np.count_nonzero(on_line) >= 2:
        white_part = np.sqrt(np.maximum(adev[on_line] ** 2 - others[on_line], 1e-300))
        white = float(np.exp(np.mean(np.log(white_part) + 0.5 * logt[on_line])))
    elif model.white_var > 0:
        white = math.sqrt(model.white_var)
        flags.append("white noise from the model fit (no clean slope −1/2 region)")
    else:
        white = float(adev[0] * math.sqrt(taus[0]))
        flags.append("white noise from the shortest τ (no slope −1/2 region)")

    # Bias instability: the top of the bias part of the curve (flat for flicker noise), / 0.664.
    grid = np.geomspace(taus[0], taus[-1], 512)
    bias_curve = np.sqrt(np.maximum(model.bias_component(grid), 0.0))
    k = int(np.argmax(bias_curve))
    bias_instability = tau_bi = None
    gm_sigma = gm_tau = None
    if bias_curve[k] > 0:
        bias_instability = float(bias_curve[k] / FLICKER_FACTOR)
        tau_bi = float(grid[k])
        if k == len(grid) - 1:
            flags.append("bias instability still rising at the longest τ: record longer")
    else:
        flags.append("no bias instability visible above the white noise (record longer)")
    if np.any(model.gm_var > 0):
        gm_total = float(np.sum(model.gm_var))
        gm_sigma = math.sqrt(gm_total)
        gm_tau = float(np.exp(np.sum(model.gm_var * np.log(model.gm_tc)) / gm_total))
    rrw = math.sqrt(3.0 * model.rrw_var) if model.rrw_var > 0 else None
    quant = math.sqrt(model.quant_var / 3.0) if model.quant_var > 0 else None
    j = int(np.argmin(adev))
    return NoiseParameters(
        white_noise=white,
        bias_instability=bias_instability,
        rate_random_walk=rrw,
        quantization=quant,
        tau_bias_instability_s=tau_bi,
        curve_minimum=float(adev[j]),
        tau_curve_minimum_s=float(taus[j]),
        std=float(std),
        gauss_markov_sigma=gm_sigma,
        gauss_markov_tau_s=gm_tau,
        flags=tuple(flags),
    )


AXES = ("x", "y", "z")
SENSOR_UNITS = {"gyro": "rad/s", "accel": "m/s^2", "mag": "uT"}


@dataclass(frozen=True)
class AllanResult:
    """Per sensor ('gyro', 'accel', 'mag') and axis: the curve and the noise parameters."""

    rate_hz: float
    duration_s: float
    taus_s: np.ndarray
    adev: dict            # sensor -> (j, 3)
    parameters: dict      # sensor -> {axis: NoiseParameters}

    def to_json_dict(self) -> dict:
        """The public `ahrsd calibrate allan --json` keys: per sensor and axis `white_noise` and
        `bias_instability` (plus the other parameters), and the thesis's Kalman tuning."""
        out: dict = {"rate_hz": self.rate_hz, "duration_s": self.duration_s}
        for sensor, axes in self.parameters.items():
            out[sensor] = {"unit": SENSOR_UNITS[sensor], **{ax: p.to_dict() for ax, p in axes.items()}}
        out["kalman"] = kalman_tuning(self)
        return out


def analyse_static(t_s: np.ndarray, gyro_rad_s=None, accel_m_s2=None, mag_ut=None,
                   points_per_octave: int = 4) -> AllanResult:
    """Allan analysis of every sensor given ((n, 3) arrays) from one static recording."""
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.shape[0] < 16:
        raise ValueError(f"recording too short for an Allan analysis ({t_s.shape[0]} samples)")
    dt = float(np.median(np.diff(t_s)))
    if not dt > 0:
        raise ValueError("sample times do not increase")
    rate = 1.0 / dt
    adevs, params = {}, {}
    taus = None
    for sensor, data in (("gyro", gyro_rad_s), ("accel", accel_m_s2), ("mag", mag_ut)):
        if data is None:
            continue
        data = np.asarray(data, dtype=np.float64)
        good = np.all(np.isfinite(data), axis=1)
        if not np.all(good):
            # Fill the few invalid samples with the mean (each is one sample of a long record).
            data = np.where(good[:, None], data, np.nanmean(np.where(good[:, None], data, np.nan), axis=0))
        taus, adev, n_terms = allan_deviation(data, rate, points_per_octave=points_per_octave)
        adevs[sensor] = adev
        std = data.std(axis=0)
        params[sensor] = {ax: noise_parameters(taus, adev[:, i], n_terms, rate, std[i]) for i, ax in enumerate(AXES)}
    if taus is None:
        raise ValueError("no sensor data given")
    return AllanResult(rate, float(t_s[-1] - t_s[0] + dt), taus, adevs, params)


def kalman_tuning(result: AllanResult) -> dict:
    """The thesis's Kalman Q and R (§8.4, eq. 6-1/6-2) in SI units.

    Q (6): gyro white noise (3·ARW)² then bias-driving noise (3·ARW/10)², rad²/s (continuous-time density).
    R (6): magnetometer variance (µT²) then accelerometer variance ((m/s²)²), from the output std (thesis
    §11.4: "the first three numbers are the magnetometer standard deviations, the next three the
    accelerometer's").
    """
    out: dict = {"source": "thesis eq. 5-8, 6-1, 6-2"}
    gyro = result.parameters.get("gyro")
    if gyro:
        arw = [gyro[ax].white_noise for ax in AXES]
        out["gyro_arw_rad_sqrt_s"] = arw
        out["Q_diag"] = [(Q_INFLATION * v) ** 2 for v in arw] + [
            (Q_INFLATION * BIAS_DRIVE_FRACTION * v) ** 2 for v in arw
        ]
        out["Q_units"] = "rad^2/s"
        bi = [gyro[ax].bias_instability for ax in AXES]
        out["gyro_bias_instability_rad_s"] = bi
    mag, acc = result.parameters.get("mag"), result.parameters.get("accel")
    if mag and acc:
        out["R_diag"] = [mag[ax].std**2 for ax in AXES] + [acc[ax].std**2 for ax in AXES]
        out["R_units"] = ["uT^2"] * 3 + ["(m/s^2)^2"] * 3
    if acc:
        out["accel_vrw_m_s2_sqrt_hz"] = [acc[ax].white_noise for ax in AXES]
    if mag:
        out["mag_white_noise_ut_sqrt_hz"] = [mag[ax].white_noise for ax in AXES]
    return out


NOISE_FILE_NAME = "noise.json"


def save_noise_parameters(result: AllanResult, path: Path | str) -> Path:
    """Write the noise parameters and Kalman tuning as JSON (atomically) for the estimator to load."""
    from .store import _write_atomic

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": "ahrsd-noise", "version": 1, **result.to_json_dict()}
    _write_atomic(path, (json.dumps(_finite(doc), indent=2, sort_keys=True) + "\n").encode())
    return path


def load_noise_parameters(path: Path | str) -> dict:
    """Read a noise.json written by `save_noise_parameters` (raises ValueError on a foreign file)."""
    doc = json.loads(Path(path).read_text())
    if not isinstance(doc, dict) or doc.get("format") != "ahrsd-noise" or doc.get("version") != 1:
        raise ValueError(f"{path}: not an ahrsd noise-parameter file (version 1)")
    return doc


def _finite(obj):
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj
