"""Allan-variance noise analysis of a static recording (IEEE Std 952-1997 conventions; NIST SP 1065
for the estimators and confidence intervals; the analysis the ADIS16405 AHRS thesis runs).

The recording is consumed a chunk at a time (`StaticAllanAnalysis.add`, or `analyse_chunks` over a chunked
reader): per sensor a streaming overlapping Allan deviation (adev.py), so a day at 819.2 SPS needs no
more memory than a chunk. Each axis' curve is then read by a significance test that keeps only the noise terms
the curve shows (terms.py), and the Kalman tuning is derived from those terms (kalman.py).

Per sensor and axis (u = the sample unit: rad/s, m/s², µT):
  white_noise N (u/√Hz: ARW, VRW), quantization Q (u·s), bias_instability B (u, IEEE reading min σ/0.664
  where the flicker floor dominates) with tau_bias_instability_s, rate_random_walk K (u/√s), rate_ramp R
  (u/s), gauss_markov_sigma/gauss_markov_tau_s — each None when the curve does not show it;
  terms: the kept terms with value, 1σ uncertainty and τ range; not_seen: for the others, the 2σ upper bound
  and the recording length that would show a term that large; flags: the same in words.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .adev import ONE_SIGMA, AllanCurve, StreamingAllan, confidence_interval, edf_overlapping
from .correlation import SampleCorrelation, shortest_fit_tau_s
from .kalman import kalman_tuning
from .resolution import MIN_NOISE_LSB
from .terms import (
    TERMS,
    ModelFit,
    TermEstimate,
    flicker_reading,
    not_seen_report,
    octave_points,
    select_terms,
    term_estimates,
)
from ..report import sig_figs

AXES = ("x", "y", "z")
SENSORS = ("gyro", "accel", "mag")
SENSOR_UNITS = {"gyro": "rad/s", "accel": "m/s^2", "mag": "uT"}
MIN_SAMPLES = 16
CONFIDENCE_LEVEL = ONE_SIGMA   # the band: 1σ two-sided χ² interval


@dataclass(frozen=True)
class NoiseParameters:
    """Noise of one sensor axis read off its Allan deviation (units in the module doc)."""

    white_noise: float | None
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
    rate_ramp: float | None = None
    terms: dict = field(default_factory=dict)       # name -> TermEstimate, the terms the curve shows
    not_seen: dict = field(default_factory=dict)    # name -> {"upper_bound", "recording_needed_s", "note"}
    fit: ModelFit | None = None                     # the fitted model (for plots; not serialised)
    too_short_need_s: float | None = None           # recording too short to read any term: the length that would
    noise_lsb: float | None = None                  # noise below MIN_NOISE_LSB of the output's step: no term read

    def to_dict(self) -> dict:
        d = {name: getattr(self, name) for name in (
            "white_noise", "bias_instability", "rate_random_walk", "quantization", "tau_bias_instability_s",
            "curve_minimum", "tau_curve_minimum_s", "std", "gauss_markov_sigma", "gauss_markov_tau_s",
            "rate_ramp")}
        d["flags"] = list(self.flags)
        d["noise_lsb"] = self.noise_lsb
        d["terms"] = {name: (self.terms[name].to_dict() if name in self.terms else None) for name in TERMS}
        d["not_seen"] = dict(self.not_seen)
        for name, est in self.terms.items():
            d[f"{name}_uncertainty"] = est.uncertainty
        return d


def _no_terms_read(curve: AllanCurve, axis: int, std: float, reason: str,
                   too_short_need_s: float | None = None, noise_lsb: float | None = None) -> NoiseParameters:
    """An axis of which no term can be read: the curve's minimum, the standard deviation and the reason."""
    j = int(np.argmin(curve.adev[:, axis]))
    return NoiseParameters(None, None, None, None, None, float(curve.adev[j, axis]), float(curve.taus_s[j]),
                           float(std), flags=(reason,), too_short_need_s=too_short_need_s, noise_lsb=noise_lsb)


def read_axis(curve: AllanCurve, axis: int, std: float, rate_hz: float, correlation_samples: int = 1,
              white_deficit_s: float = 0.0, samples_to_tell: int = 0, noise_lsb: float = math.inf,
              white_deficit_sd_s: float = 0.0, not_seen_bounds: bool = True) -> NoiseParameters:
    """Decide the terms of one axis' curve and read their values. correlation_samples: how many samples apart
    the samples stop being correlated (correlation): the fit uses only the τ beyond a few of those, where
    the filter lowers white noise to N²·(1/τ − D/τ²), D = white_deficit_s ± white_deficit_sd_s (1σ, carried by
    the fit: terms). samples_to_tell > 0: the samples are
    correlated but the record is too short to tell over how many (correlation): no term is read.
    noise_lsb: the output's σ per sample in its LSB; below MIN_NOISE_LSB no term is read
    (resolution). not_seen_bounds=False leaves out the terms not seen (`not_seen` and their flags stay empty):
    for a caller that reads only the terms seen, since their profile bounds cost as much as the fit."""
    pts = octave_points(curve, axis)
    min_tau_s = shortest_fit_tau_s(correlation_samples, rate_hz)
    unreadable = _unreadable(curve, axis, std, rate_hz, pts, min_tau_s, correlation_samples, samples_to_tell,
                             noise_lsb)
    if unreadable is not None:
        return unreadable
    short_note = []
    if min_tau_s > 0:
        keep = pts.taus >= min_tau_s
        pts = type(pts)(pts.taus[keep], pts.avar[keep], pts.level_n[keep], pts.level_m[keep], pts.record_s,
                        white_deficit_s, white_deficit_sd_s)
        short_note = [f"τ < {sig_figs(min_tau_s)} s not fitted: the samples are correlated over {correlation_samples} "
                      "samples (the sensor's filter), which bends the curve there"]
    if len(pts.taus) < 3 or not np.all(pts.avar > 0):
        return _no_terms_read(curve, axis, std, "constant signal or too few cluster sizes: no noise terms read")
    return _terms_read(curve, axis, std, rate_hz, pts, short_note, not_seen_bounds)


def _unreadable(curve: AllanCurve, axis: int, std: float, rate_hz: float, pts, min_tau_s: float,
                correlation_samples: int, samples_to_tell: int, noise_lsb: float) -> NoiseParameters | None:
    """The axis' result when the record cannot support any term (and says why), else None."""
    if noise_lsb < MIN_NOISE_LSB:
        # The output holds a handful of values: its Allan deviation is that of a staircase, not the sensor's noise.
        return _no_terms_read(curve, axis, std, (
            f"output resolution too coarse: the output's noise is {noise_lsb:.2f} LSB per sample (below "
            f"{MIN_NOISE_LSB} LSB it is a staircase of a few values and its noise is the rounding's); "
            f"record with a shorter filter (a smaller SENS_AVG N): no noise terms read"), noise_lsb=noise_lsb)
    if samples_to_tell > 0:
        # Every τ may lie within the filter's correlation, where a fit reads the filter as a Gauss–Markov term
        # and calls white noise "not seen" whatever the recording length, which a longer record would refute.
        need_s = samples_to_tell / rate_hz
        return _no_terms_read(curve, axis, std, (
            f"recording too short: neighbouring samples are correlated (the sensor's filter), and "
            f"{sig_figs(curve.record_s)} s of samples cannot tell over how many; record about "
            f"{math.ceil(need_s / curve.record_s):.0f}× longer (≥ {need_s:.0f} s): no noise terms read"), need_s)
    if min_tau_s > 0 and np.count_nonzero(pts.taus >= min_tau_s) < 3:
        # Below min_tau_s the sensor's filter bends the curve (a fit there reads the filter as a Gauss–Markov
        # term and calls white noise "not seen"), and three cluster sizes are the fewest a term can be read from.
        # The longest cluster grows with the record, so a record this many times longer reaches 4·min_tau_s.
        longer = 4.0 * min_tau_s / pts.taus[-1]
        return _no_terms_read(curve, axis, std, (
            f"recording too short: the samples are correlated over {correlation_samples} samples (the sensor's "
            f"filter), so only τ ≥ {sig_figs(min_tau_s)} s can be fitted, and it has fewer than 3 cluster sizes there; "
            f"record about {sig_figs(longer, 2)}× longer (≥ {longer * pts.record_s:.0f} s): no noise terms read"),
            longer * pts.record_s)
    return None


def _terms_read(curve: AllanCurve, axis: int, std: float, rate_hz: float, pts, short_note: list[str],
                not_seen_bounds: bool = True) -> NoiseParameters:
    """Fit the terms the points support (select_terms) and read their values; each term not seen is flagged
    with its upper bound and why."""
    fit = select_terms(pts)
    terms: dict[str, TermEstimate] = term_estimates(fit, pts)
    flags, not_seen = [], {}
    for name in TERMS:
        if name not in terms and not_seen_bounds:
            report = not_seen_report(fit, pts, name, rate_hz)
            not_seen[name] = report
            bound = report.get("upper_bound")
            bound_text = "" if bound is None else f" (≤ {sig_figs(bound)} at 2σ)"
            flags.append(f"{name.replace('_', ' ')} not seen{bound_text}: {report['note']}")
    flags = short_note + flags
    bias = flicker_reading(fit, pts)
    if "flicker" in terms and bias is None:    # kept but no τ left beside the shortest: not readable
        del terms["flicker"]
    adev = curve.adev[:, axis]
    j = int(np.argmin(adev))
    gm = terms.get("gauss_markov")
    return NoiseParameters(
        white_noise=terms["white"].value if "white" in terms else None,
        bias_instability=None if bias is None else bias[0],
        rate_random_walk=terms["rate_random_walk"].value if "rate_random_walk" in terms else None,
        quantization=terms["quantization"].value if "quantization" in terms else None,
        tau_bias_instability_s=None if bias is None else bias[1],
        curve_minimum=float(adev[j]),
        tau_curve_minimum_s=float(curve.taus_s[j]),
        std=float(std),
        gauss_markov_sigma=None if gm is None else gm.value,
        gauss_markov_tau_s=None if gm is None else gm.corr_time_s,
        flags=tuple(flags),
        rate_ramp=terms["rate_ramp"].value if "rate_ramp" in terms else None,
        terms=terms,
        not_seen=not_seen,
        fit=fit,
    )


@dataclass(frozen=True)
class AllanResult:
    """Per sensor ('gyro', 'accel', 'mag') and axis: the curve, its confidence band and the noise parameters."""

    rate_hz: float
    duration_s: float
    taus_s: np.ndarray
    adev: dict            # sensor -> (j, 3)
    parameters: dict      # sensor -> {axis: NoiseParameters}
    adev_lower: dict = field(default_factory=dict)   # sensor -> (j, 3), CONFIDENCE_LEVEL band
    adev_upper: dict = field(default_factory=dict)
    clusters: np.ndarray | None = None               # independent clusters T/τ behind each point
    samples: int = 0
    replaced_samples: dict = field(default_factory=dict)   # sensor -> non-finite samples replaced by the mean

    def to_json_dict(self) -> dict:
        """The public `ahrsd calibrate allan --json` keys: per sensor and axis `white_noise` and
        `bias_instability` (plus the other parameters), the Kalman tuning, and the curves with their band."""
        out: dict = {"rate_hz": self.rate_hz, "duration_s": self.duration_s, "samples": self.samples}
        for sensor, axes in self.parameters.items():
            out[sensor] = {"unit": SENSOR_UNITS[sensor], **{ax: p.to_dict() for ax, p in axes.items()}}
            out[sensor]["replaced_samples"] = self.replaced_samples.get(sensor, 0)
        out["kalman"] = kalman_tuning(self)
        curves: dict = {"taus_s": self.taus_s.tolist(), "confidence_level": CONFIDENCE_LEVEL,
                        "clusters": None if self.clusters is None else self.clusters.tolist()}
        for sensor, adev in self.adev.items():
            curves[sensor] = {
                ax: {"adev": adev[:, i].tolist(),
                     "lower": self.adev_lower[sensor][:, i].tolist() if sensor in self.adev_lower else None,
                     "upper": self.adev_upper[sensor][:, i].tolist() if sensor in self.adev_upper else None}
                for i, ax in enumerate(AXES)}
        out["curves"] = curves
        return out


class StaticAllanAnalysis:
    """Feed a static recording chunk by chunk (`add`), then `result()`. Memory: one chunk plus O(log n)."""

    def __init__(self):
        self._start: list[tuple] = []      # chunks held until MIN_SAMPLES give the sample rate
        self._rate_hz: float | None = None
        self._allan: dict[str, StreamingAllan] = {}
        self._sum: dict[str, np.ndarray] = {}
        self._sum_sq: dict[str, np.ndarray] = {}
        self._ref: dict[str, np.ndarray] = {}
        self._replaced: dict[str, int] = {}
        self._correlation: dict[str, SampleCorrelation] = {}
        self._n = 0
        self._t0 = self._t_last = math.nan

    def add(self, t_s, gyro_rad_s=None, accel_m_s2=None, mag_ut=None) -> None:
        chunk = (np.asarray(t_s, dtype=np.float64), gyro_rad_s, accel_m_s2, mag_ut)
        if self._rate_hz is None:
            self._start.append(chunk)
            if sum(len(c[0]) for c in self._start) < MIN_SAMPLES:
                return
            t = np.concatenate([c[0] for c in self._start])
            dt = float(np.median(np.diff(t)))
            if not dt > 0:
                raise ValueError("sample times do not increase")
            self._rate_hz = 1.0 / dt
            self._t0 = float(t[0])
            held, self._start = self._start, []
            for c in held:
                self._take(*c)
            return
        self._take(*chunk)

    def _take(self, t_s, gyro, accel, mag) -> None:
        if len(t_s) == 0:
            return
        self._n += len(t_s)
        self._t_last = float(t_s[-1])
        for sensor, data in zip(SENSORS, (gyro, accel, mag)):
            if data is None:
                continue
            data = np.array(data, dtype=np.float64, copy=True).reshape(len(t_s), 3)
            bad = ~np.isfinite(data)
            if sensor not in self._allan:
                self._allan[sensor] = StreamingAllan(self._rate_hz, 3)
                self._ref[sensor] = np.where(np.isfinite(data[0]), data[0], 0.0)
                self._sum[sensor] = np.zeros(3)
                self._sum_sq[sensor] = np.zeros(3)
                self._replaced[sensor] = 0
                self._correlation[sensor] = SampleCorrelation()
            if bad.any():
                # A few invalid samples of a long record: replaced by the mean so far (one sample each).
                n_before = self._allan[sensor].n_samples
                mean = self._ref[sensor] + (self._sum[sensor] / n_before if n_before else 0.0)
                data = np.where(bad, mean, data)
                self._replaced[sensor] += int(np.count_nonzero(bad.any(axis=1)))
            self._allan[sensor].add(data)
            self._correlation[sensor].add(data)
            d = data - self._ref[sensor]
            self._sum[sensor] += d.sum(axis=0)
            self._sum_sq[sensor] += np.einsum("ij,ij->j", d, d)

    def result(self, not_seen_bounds: bool = True) -> AllanResult:
        """The analysis of what was added; not_seen_bounds as in read_axis."""
        if self._rate_hz is None:
            n = sum(len(c[0]) for c in self._start)
            raise ValueError(f"recording too short for an Allan analysis ({n} samples)")
        if not self._allan:
            raise ValueError("no sensor data given")
        adevs, params, lower, upper = {}, {}, {}, {}
        curve = None
        for sensor, acc in self._allan.items():
            curve = acc.curve()
            n = acc.n_samples
            std = np.sqrt(np.maximum(self._sum_sq[sensor] / n - (self._sum[sensor] / n) ** 2, 0.0))
            correlation = self._correlation[sensor]
            lengths, deficits = correlation.lengths(), correlation.deficits_s(self._rate_hz)
            deficit_sds = correlation.deficit_sds_s(self._rate_hz)
            to_tell, noise_lsb = correlation.samples_to_tell(), correlation.noise_lsb()
            axes = {ax: read_axis(curve, i, std[i], self._rate_hz, int(lengths[i]), float(deficits[i]), int(to_tell[i]),
                                  float(noise_lsb[i]), float(deficit_sds[i]), not_seen_bounds)
                    for i, ax in enumerate(AXES)}
            lo, hi = np.empty_like(curve.adev), np.empty_like(curve.adev)
            for i, ax in enumerate(AXES):
                fit = axes[ax].fit
                edf = (fit.edf(curve.taus_s, curve.level_n, curve.level_m) if fit is not None
                       else np.array([edf_overlapping(0, n + 1.0, m) for n, m in zip(curve.level_n, curve.level_m)]))
                lo[:, i], hi[:, i] = confidence_interval(curve.adev[:, i], edf, CONFIDENCE_LEVEL)
            adevs[sensor], params[sensor], lower[sensor], upper[sensor] = curve.adev, axes, lo, hi
        duration = self._t_last - self._t0 + 1.0 / self._rate_hz
        return AllanResult(self._rate_hz, duration, curve.taus_s, adevs, params, lower, upper, curve.clusters,
                           self._n, dict(self._replaced))


def analyse_chunks(chunks) -> AllanResult:
    """Allan analysis of a recording given as chunks with t_s, gyro_rad_s, accel_m_s2, mag_ut (e.g.
    drivers.recording.iter_recording_chunks), read once, a chunk at a time."""
    acc = StaticAllanAnalysis()
    for c in chunks:
        acc.add(c.t_s, c.gyro_rad_s, c.accel_m_s2, c.mag_ut)
    return acc.result()


def analyse_static(t_s: np.ndarray, gyro_rad_s=None, accel_m_s2=None, mag_ut=None, *,
                   not_seen_bounds: bool = True) -> AllanResult:
    """Allan analysis of every sensor given ((n, 3) arrays) from one static recording in memory; not_seen_bounds
    as in read_axis."""
    t_s = np.asarray(t_s, dtype=np.float64)
    if t_s.shape[0] < MIN_SAMPLES:
        raise ValueError(f"recording too short for an Allan analysis ({t_s.shape[0]} samples)")
    acc = StaticAllanAnalysis()
    acc.add(t_s, gyro_rad_s, accel_m_s2, mag_ut)
    return acc.result(not_seen_bounds)


_REPORT_NAMES = {"gyro": ("ARW", "rad/s/√Hz", "rad/s"), "accel": ("VRW", "m/s²/√Hz", "m/s²"),
                 "mag": ("white", "µT/√Hz", "µT")}


# What an operator compares with a data sheet: white noise in the data sheet's units (value per rad/s/√Hz etc.)
_SUMMARY_UNITS = {"gyro": ("ARW", "°/√h", math.degrees(1.0) * 60.0), "accel": ("VRW", "m/s/√h", 60.0),
                  "mag": ("white noise", "µT/√Hz", 1.0)}
_BIAS_UNITS = {"gyro": ("°/h", math.degrees(1.0) * 3600.0), "accel": ("mg", 1e3 / 9.80665), "mag": ("µT", 1.0)}


def summary(result: AllanResult) -> list[str]:
    """The lead of the report: per sensor the white noise and bias instability of each axis in data-sheet
    units (or that it was not seen and what the filter assumes instead), and where the filter tuning comes from."""
    lines = []
    assumed = {a["key"]: a for a in kalman_tuning(result)["assumed"]}
    for sensor, axes in result.parameters.items():
        name, unit, scale = _SUMMARY_UNITS[sensor]
        bias_unit, bias_scale = _BIAS_UNITS[sensor]
        white = "  ".join(f"{ax} " + (_unread(p) if p.white_noise is None else f"{sig_figs(p.white_noise * scale)}")
                          for ax, p in axes.items())
        bias = "  ".join(f"{ax} " + (_unread(p) if p.bias_instability is None
                                     else f"{sig_figs(p.bias_instability * bias_scale)}") for ax, p in axes.items())
        lines.append(f"  {sensor:<5} {name} ({unit}): {white};  bias instability ({bias_unit}): {bias}")
    needs = [p.too_short_need_s for axes in result.parameters.values() for p in axes.values()
             if p.too_short_need_s is not None]
    if needs:
        lines.append(f"  recording too short for {len(needs)} axes: record ≥ {max(needs):.0f} s of the sensor at "
                     f"rest (details below)")
    coarse = [p for axes in result.parameters.values() for p in axes.values() if p.noise_lsb is not None]
    if coarse:
        lines.append(f"  output resolution too coarse for {len(coarse)} axes: their noise is below "
                     f"{MIN_NOISE_LSB} LSB; record with a smaller SENS_AVG N (details below)")
    if assumed:
        keys = sorted({key.rsplit(".", 1)[0] for key in assumed})
        lines.append(f"  not seen in this recording, the filter assumes instead: {', '.join(keys)} (details below)")
    return lines


def _unread(p: NoiseParameters) -> str:
    if p.noise_lsb is not None:
        return "below LSB"
    return "too short" if p.too_short_need_s is not None else "not seen"


def describe(result: AllanResult) -> list[str]:
    """The human report: per axis the terms seen (value ± 1σ, τ range) and what was not seen."""
    lines = []
    for sensor, axes in result.parameters.items():
        name, wu, bu = _REPORT_NAMES[sensor]
        lines.append(f"  {sensor}:")
        for ax, p in axes.items():
            white = "not seen" if p.white_noise is None else f"{p.white_noise:.3e} {wu}"
            bi = ("not seen" if p.bias_instability is None
                  else f"{p.bias_instability:.3e} {bu} (at τ≈{sig_figs(p.tau_bias_instability_s)} s)")
            lines.append(f"    {ax}: {name} {white}; bias instability {bi}")
            for term, est in p.terms.items():
                extra = f", Tc {sig_figs(est.corr_time_s)} s" if est.corr_time_s else ""
                lines.append(f"       {term}: {est.value:.3e} ± {est.uncertainty:.1e}{extra} "
                             f"(τ {sig_figs(est.tau_range_s[0])}…{sig_figs(est.tau_range_s[1])} s)")
            for flag in p.flags:
                lines.append(f"       note: {flag}")
    k = kalman_tuning(result)
    if "Q_diag" in k:
        lines.append("  Kalman Q = diag((3·N)², (3·w_b)²), rad²/s: " + "[" + ", ".join(f"{v:.3e}" for v in k["Q_diag"]) + "]")
    if "R_diag" in k:
        lines.append("  Kalman R = diag(σ_mag², σ_accel²), µT² then (m/s²)²: " + "[" + ", ".join(f"{v:.3e}" for v in k["R_diag"]) + "]")
    for a in k["assumed"]:
        lines.append(f"  assumed {a['key']} = {a['value']:.3e}: {a['source']}")
    return lines


NOISE_FILE_NAME = "noise.json"


def save_noise_parameters(result: AllanResult, path: Path | str) -> Path:
    """Write the noise parameters and Kalman tuning as JSON (atomically) for the estimator to load."""
    from ..atomic_file import write_atomic

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": "ahrsd-noise", "version": 1, **result.to_json_dict()}
    # readable by the operator (0644), as the calibration files the store writes
    write_atomic(path, (json.dumps(_finite(doc), indent=2, sort_keys=True) + "\n").encode(), mode=0o644)
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
