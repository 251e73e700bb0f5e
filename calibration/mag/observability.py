"""What a set of magnetometer (and accelerometer) samples can and cannot determine.

A magnetometer fit reports a residual ("fitness"); a small residual says the model fits the samples, not that
the samples determine the model. On a vehicle that stays within ±10° of level, an ellipsoid fit leaves the
z hard iron and the z scale almost free: it fits beautifully and is wrong (bench/magcal.py and docs/magcal-vehicle.md show it). This module
reports, next to the residual:

- sphere coverage: the fraction of the 80 cells of the direction sphere hit by the centred samples (the
  cells of ArduPilot's geodesic grid, the same as the field session's completion mask: geodesic_grid.py);
- heading coverage: the fraction of 10° heading bins hit (for vehicles that turn but stay near level);
- tilt range from the accelerometer (roll/pitch extremes, largest tilt);
- condition number and 1σ of the parameters from a fit's Jacobian, and the parameters the data cannot
  determine;
- a refusal with a reason a person can act on when the data cannot support the requested model.

Everything is generic over (mag samples, accel samples) so every fit method can call it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.angles import down_in_body, roll_pitch_from_accel, tilt_compensated_heading_rad

from .geodesic_grid import N_SECTIONS, geodesic_sections

HEADING_BINS = 36           # 10° heading bins

# Support thresholds, chosen from simulated runs (bench/magcal.py): the sphere coverage a full tumble, ±30° and
# ±10° of tilt reach, and the tilt below which the attitude-independent fits fail.
MIN_SAMPLES = 50
MIN_SPREAD_UT = 5.0                 # without a reference: a still sensor spreads ~1 µT (noise), a quarter turn ≥ 20 µT
MIN_HEADING_COVERAGE = 0.75         # 27 of 36 bins: "turned through (nearly) a full circle"
MIN_SPHERE_COVERAGE_ELLIPSOID = 0.35
MIN_TILT_ELLIPSOID_DEG = 30.0       # below this the LS ellipsoid's z terms are a guess
MIN_TILT_FREE_DIP_DEG = 5.0         # free dip breaks down between ±5° and ±2° of tilt (simulated)
MIN_TILT_VERTICAL_COLUMN_DEG = 1.0  # below this the vertical soft-iron column is held at its prior

MODELS = ("sphere", "diagonal", "ellipsoid", "vertical", "vertical-free-dip")


# ------------------------------------------------------------------------------------------ attitude helpers


def lowpass(x: np.ndarray, t_s: np.ndarray, tau_s: float) -> np.ndarray:
    """Zero-phase first-order low-pass (forward and backward pass) of (n, k) samples with time constant
    tau_s; handles irregular sample times. tau_s <= 0 returns x unchanged."""
    x = np.asarray(x, dtype=np.float64)
    if tau_s <= 0 or x.shape[0] < 2:
        return x.copy()
    t = np.asarray(t_s, dtype=np.float64)
    dt = np.diff(t, prepend=t[0])
    steps = dt[1:]
    if steps.size and np.all(steps > 0) and np.ptp(steps) <= 1e-3 * np.median(steps):
        # uniform sampling (the usual case): the same filter in C
        from scipy.signal import lfilter

        a = 1.0 - math.exp(-float(np.median(steps)) / tau_s)
        x2 = x.reshape(x.shape[0], -1)
        zi = (1.0 - a) * x2[0]
        fwd, _ = lfilter([a], [1.0, a - 1.0], x2, axis=0, zi=zi[None, :])
        bwd, _ = lfilter([a], [1.0, a - 1.0], fwd[::-1], axis=0, zi=((1.0 - a) * fwd[-1])[None, :])
        return bwd[::-1].reshape(x.shape)
    alpha = 1.0 - np.exp(-np.clip(dt, 0.0, None) / tau_s)
    y = np.empty_like(x)

    def one_pass(src, a, out):
        acc = src[0].copy()
        for i in range(src.shape[0]):
            acc += a[i] * (src[i] - acc)
            out[i] = acc

    one_pass(x, alpha, y)
    back = np.empty_like(y)
    one_pass(y[::-1], np.concatenate(([0.0], alpha[:0:-1])), back)
    return back[::-1]


def tilt_statistics(roll_rad: np.ndarray, pitch_rad: np.ndarray) -> dict:
    """Roll/pitch extremes and the largest tilt (angle of body z from the vertical), degrees."""
    r, p = np.degrees(roll_rad), np.degrees(pitch_rad)
    d = down_in_body(roll_rad, pitch_rad)
    tilt = np.degrees(np.arccos(np.clip(d[:, 2], -1.0, 1.0)))
    return {
        "roll_min_deg": float(r.min()), "roll_max_deg": float(r.max()),
        "pitch_min_deg": float(p.min()), "pitch_max_deg": float(p.max()),
        "tilt_max_deg": float(tilt.max()), "tilt_rms_deg": float(np.sqrt(np.mean(tilt**2))),
    }


# ------------------------------------------------------------------------------------------------ coverage


def sphere_cells_hit(mag_ut: np.ndarray, centre_ut: np.ndarray | None = None) -> np.ndarray:
    """Boolean (80,) mask of the cells hit by the directions of (mag − centre). centre defaults to the
    algebraic sphere-fit centre (mean if that fails)."""
    m = np.asarray(mag_ut, dtype=np.float64)
    if centre_ut is None:
        centre_ut = algebraic_sphere_centre(m)
    u = m - np.asarray(centre_ut, dtype=np.float64)
    norms = np.linalg.norm(u, axis=1)
    u = u[norms > 0] / norms[norms > 0, None]
    hit = np.zeros(N_SECTIONS, dtype=bool)
    for start in range(0, u.shape[0], 20000):
        sections = geodesic_sections(u[start:start + 20000])
        hit[sections[sections >= 0]] = True
    return hit


def algebraic_sphere_centre(mag_ut: np.ndarray) -> np.ndarray:
    """Centre of the least-squares sphere |m − c|² = r² (linear in c and r² − |c|²); the mean when singular."""
    m = np.asarray(mag_ut, dtype=np.float64)
    a = np.column_stack((2.0 * m, np.ones(m.shape[0])))
    b = np.sum(m * m, axis=1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=1e-10)
    c = sol[:3]
    if not np.all(np.isfinite(c)) or np.linalg.norm(c - m.mean(axis=0)) > 10 * np.ptp(m, axis=0).max() + 1:
        return m.mean(axis=0)
    return c


def horizontal_circle_centre(mag_ut: np.ndarray) -> np.ndarray:
    """Centre (x, y) of the least-squares circle through the horizontal components (Kåsa fit)."""
    xy = np.asarray(mag_ut, dtype=np.float64)[:, :2]
    a = np.column_stack((2.0 * xy, np.ones(xy.shape[0])))
    sol, *_ = np.linalg.lstsq(a, np.sum(xy * xy, axis=1), rcond=1e-10)
    return sol[:2]


def fixed_radius_circle_centre(xy: np.ndarray, radius: float) -> np.ndarray:
    """Centre of the circle of a known radius through 2-D points (Gauss–Newton from several starts). Unlike
    a free circle fit, it stays meaningful on a short arc: a vehicle that went one way gives a short arc."""
    from scipy.optimize import least_squares

    p = np.asarray(xy, dtype=np.float64)
    mean = p.mean(axis=0)
    starts = [horizontal_circle_centre(np.column_stack((p, np.zeros(len(p)))))]
    starts += [mean + radius * np.array(d) for d in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    best = None
    for s0 in starts:
        if not np.all(np.isfinite(s0)):
            continue
        sol = least_squares(lambda c: np.linalg.norm(p - c, axis=1) - radius, s0, method="lm", max_nfev=100)
        if best is None or sol.cost < best.cost:
            best = sol
    return best.x


def heading_coverage(mag_ut: np.ndarray, roll_rad=None, pitch_rad=None, centre_ut=None,
                     horizontal_ut: float | None = None) -> float:
    """Fraction of 36 heading bins (10°) hit. Heading is the direction of the centred field, levelled with
    roll/pitch when given. Without a calibration this is approximate (soft iron bends angles by a few
    degrees) but good enough to tell "turned a full circle" from "went one way". With the expected
    horizontal intensity (WMM) the centre comes from a fixed-radius circle, which a short arc cannot fool."""
    m = np.asarray(mag_ut, dtype=np.float64)
    if centre_ut is None:
        if horizontal_ut is not None and horizontal_ut > 0:
            centre_xy = fixed_radius_circle_centre(m[:, :2], horizontal_ut)
        else:
            centre_xy = horizontal_circle_centre(m)
        centre_ut = np.append(centre_xy, np.median(m[:, 2]))
    v = m - np.asarray(centre_ut, dtype=np.float64)
    if roll_rad is not None and pitch_rad is not None:
        v = level_vectors(v, roll_rad, pitch_rad)
    psi = np.arctan2(-v[:, 1], v[:, 0])
    bins = np.floor((psi + math.pi) / (2 * math.pi) * HEADING_BINS).astype(int) % HEADING_BINS
    return float(np.unique(bins).size / HEADING_BINS)


def level_vectors(v_body: np.ndarray, roll_rad, pitch_rad) -> np.ndarray:
    """Rotate body vectors into the local level frame with roll and pitch only (Nourmohammadi & Sabet 2022, eq. 23:
    C2ᵀ(θ)·C3ᵀ(ϕ)·v). Heading is left out: the horizontal magnitude does not depend on it."""
    v = np.asarray(v_body, dtype=np.float64)
    r, p = np.asarray(roll_rad, dtype=np.float64), np.asarray(pitch_rad, dtype=np.float64)
    cr, sr, cp, sp = np.cos(r), np.sin(r), np.cos(p), np.sin(p)
    x = cp * v[:, 0] + sp * sr * v[:, 1] + sp * cr * v[:, 2]
    y = cr * v[:, 1] - sr * v[:, 2]
    z = -sp * v[:, 0] + cp * sr * v[:, 1] + cp * cr * v[:, 2]
    return np.column_stack((x, y, z))


# ------------------------------------------------------------------------------------ parameter uncertainty


def parameter_uncertainty(jacobian: np.ndarray, names: list[str], limits: dict[str, float] | None = None,
                          residual_scale: float = 1.0) -> dict:
    """1σ of each parameter from a least-squares Jacobian of *whitened* residuals (residual / its σ), the
    column-scaled condition number, and the parameters whose 1σ exceeds their limit (`limits[name]`, in the
    parameter's unit). `residual_scale` multiplies the covariance by (RMS whitened residual)² when the noise
    σ used for whitening was a guess."""
    j = np.asarray(jacobian, dtype=np.float64)
    scale = np.linalg.norm(j, axis=0)
    scale[scale == 0] = 1.0
    js = j / scale
    _, sv, vt = np.linalg.svd(js, full_matrices=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    # variance of each (scaled) parameter = Σ_i v_ik²/s_i²; a direction with a numerically zero singular value
    # (below 1e-8 of the largest: more than 10⁸ times weaker) means the parameter is not determined at all
    tiny = sv <= 1e-8 * sv[0]
    inv_s2 = 1.0 / np.where(tiny, 1.0, sv) ** 2
    w = vt**2
    var = np.where(tiny, 0.0, inv_s2) @ w
    var[np.any(tiny[:, None] & (w > 1e-12), axis=0)] = np.inf
    std = np.sqrt(var) / scale * residual_scale
    out_std = {n: float(s) for n, s in zip(names, std)}
    bad = []
    for n, s in out_std.items():
        lim = (limits or {}).get(n)
        if lim is not None and not s <= lim:
            bad.append(n)
    return {"condition_number": cond, "std": out_std, "undetermined": bad}


# -------------------------------------------------------------------------------------------- support check


@dataclass(frozen=True)
class DataSupport:
    """What the data can support. `refused` is None when `model` can be fitted, else a reason."""

    model: str
    n_samples: int
    sphere_coverage: float
    heading_coverage: float
    tilt: dict | None
    refused: str | None = None
    warnings: list = field(default_factory=list)
    undetermined: list = field(default_factory=list)

    def as_quality(self) -> dict:
        q = {"n_samples": self.n_samples, "sphere_coverage": round(self.sphere_coverage, 4),
             "heading_coverage": round(self.heading_coverage, 4), "support_model": self.model}
        if self.tilt is not None:
            q["tilt"] = {k: round(v, 3) for k, v in self.tilt.items()}
        if self.warnings:
            q["warnings"] = list(self.warnings)
        if self.undetermined:
            q["undetermined_by_data"] = list(self.undetermined)
        return q


def assess_support(mag_ut: np.ndarray, accel_m_s2: np.ndarray | None = None, model: str = "ellipsoid", *,
                   roll_rad=None, pitch_rad=None, centre_ut=None, reference_known: bool = True,
                   horizontal_ut: float | None = None) -> DataSupport:
    """Can (mag, accel) support `model`? Models:

    - "sphere": hard iron + radius. Needs a full heading circle; the vertical hard iron also needs tilt
      unless the field magnitude is known (`reference_known`).
    - "diagonal": the paper's axis-aligned sphere fit (backstepping_paper.py, eqs. 11–17): needs tilt in both axes.
    - "ellipsoid": attitude-independent full ellipsoid: needs ≥ 35 % sphere coverage and ≥ 30° tilt.
    - "vertical": back-stepping / vertical-channel fit with WMM (needs roll/pitch and a full heading circle;
      with < 1° tilt the vertical soft-iron column is reported as undetermined and held at its prior).
    - "vertical-free-dip": the same without a known inclination: also needs ≥ 5° tilt.

    horizontal_ut: the expected horizontal intensity (WMM), which makes the heading coverage robust on short arcs.
    """
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    m = np.asarray(mag_ut, dtype=np.float64)
    m = m[np.all(np.isfinite(m), axis=1)]
    n = int(m.shape[0])
    if n < MIN_SAMPLES:
        return DataSupport(model, n, 0.0, 0.0, None,
                           refused=f"only {n} usable magnetometer samples; at least {MIN_SAMPLES} are needed")
    if roll_rad is None and accel_m_s2 is not None:
        a = np.asarray(accel_m_s2, dtype=np.float64)
        ok = np.all(np.isfinite(a), axis=1)
        if ok.all():
            roll_rad, pitch_rad = roll_pitch_from_accel(a)
    tilt = tilt_statistics(roll_rad, pitch_rad) if roll_rad is not None else None
    spread = float(np.max(np.ptp(m, axis=0)))
    min_spread = 0.5 * horizontal_ut if horizontal_ut else MIN_SPREAD_UT
    if spread < min_spread:
        # a still (or one-heading) recording: the "directions" would only be noise around a meaningless centre
        return DataSupport(model, n, 0.0, 0.0, tilt, refused=(
            f"the field changed by only {spread:.1f} µT over the recording: the vehicle did not turn (one heading); turn it "
            f"through a full circle (at least {MIN_HEADING_COVERAGE * 360:.0f}°)"))
    cov = float(sphere_cells_hit(m, centre_ut).mean())
    hcov = heading_coverage(m, roll_rad, pitch_rad, horizontal_ut=horizontal_ut)
    tilt_max = tilt["tilt_max_deg"] if tilt else None
    warnings: list[str] = []
    undetermined: list[str] = []
    refused = _model_refusal(model, cov, hcov, tilt is not None, tilt_max, reference_known, warnings)
    if refused is None and model == "vertical" and tilt_max is not None and tilt_max < MIN_TILT_VERTICAL_COLUMN_DEG:
        undetermined += ["soft_iron vertical column (held at prior)", "yaw misalignment (coefficient A)"]
        warnings.append(f"largest tilt {tilt_max:.2f}°: how horizontal axes respond to the vertical field and "
                        "the yaw misalignment cannot be seen; the result is valid near level only, and a "
                        "heading reference is needed for the constant heading offset")
    return DataSupport(model, n, cov, hcov, tilt, refused, warnings, undetermined)


def _model_refusal(model: str, cov: float, hcov: float, has_tilt: bool, tilt_max: float | None,
                   reference_known: bool, warnings: list[str]) -> str | None:
    """Why data of this sphere coverage `cov`, heading coverage `hcov` and largest tilt cannot support `model`,
    or None (the diagonal fit's weak z terms are a warning, appended to `warnings`)."""
    turn_hint = (f"the data cover {hcov * 360:.0f}° of heading; turn the vehicle through a full circle "
                 f"(at least {MIN_HEADING_COVERAGE * 360:.0f}°)")
    if model in ("vertical", "vertical-free-dip", "sphere", "diagonal") and hcov < MIN_HEADING_COVERAGE \
            and cov < MIN_SPHERE_COVERAGE_ELLIPSOID:
        return turn_hint
    if model in ("vertical", "vertical-free-dip") and not has_tilt:
        return "this model needs roll and pitch (accelerometer or estimator) for every sample"
    if model == "vertical-free-dip" and tilt_max < MIN_TILT_FREE_DIP_DEG:
        return (f"largest tilt is {tilt_max:.1f}°: with no known inclination the vertical hard iron, the "
                f"vertical scale and the dip angle cannot be separated below ±{MIN_TILT_FREE_DIP_DEG:.0f}°; "
                "give the position (--lat/--lon) so the WMM inclination pins them, or tilt further")
    if model == "ellipsoid" and (cov < MIN_SPHERE_COVERAGE_ELLIPSOID or
                                 (tilt_max is not None and tilt_max < MIN_TILT_ELLIPSOID_DEG)):
        what = f"sphere coverage {cov * 100:.0f} %" + (f", largest tilt {tilt_max:.1f}°" if tilt_max is not None else "")
        return (f"{what}: an attitude-independent ellipsoid cannot determine the vertical hard iron and "
                "vertical scale from such data (it would show a small residual and be wrong by degrees); "
                "tumble the sensor, or use --method backstepping with the position for the WMM field")
    if model == "diagonal" and tilt_max is not None and tilt_max < MIN_TILT_ELLIPSOID_DEG:
        warnings.append(f"largest tilt {tilt_max:.1f}°: the sphere fit's z terms are weakly determined "
                        "(the back-stepping paper's §5, test 1: data without rotation about all axes give unrealistic coefficients)")
        return None
    if model == "sphere" and not reference_known and (tilt_max is not None and tilt_max < 10.0) \
            and cov < MIN_SPHERE_COVERAGE_ELLIPSOID:
        return ("the data are a level circle: the vertical hard iron and the radius trade off; give the "
                "field magnitude (position) or tilt the vehicle")
    return None


# ----------------------------------------------------------------------------- full model vs offsets only


def heading_change_deg(model_from, model_to, total_ut: float, vertical_ut: float, tilt_envelope_deg: float,
                       n_headings: int = 12) -> dict:
    """How much the heading changes between two magnetometer models, on the attitudes where the field-fit
    heading accuracy is predicted (vertical_channel.predicted_heading_std_deg's grid: every 360/n_headings° of
    heading, level and ±envelope in roll and in pitch). The raw field is the one `model_from` maps onto the
    reference field exactly. Returns the mean difference (a constant offset, deg) and the RMS of the
    heading-dependent rest (deg)."""
    from scipy.spatial.transform import Rotation

    hh = math.sqrt(max(total_ut**2 - vertical_ut**2, 0.0))
    t = math.radians(tilt_envelope_deg)
    atts = ((0.0, 0.0), (t, 0.0), (-t, 0.0), (0.0, t), (0.0, -t))
    psi = np.radians(np.arange(n_headings) * 360.0 / n_headings)
    roll = np.repeat([a[0] for a in atts], psi.size)
    pitch = np.repeat([a[1] for a in atts], psi.size)
    yaw = np.tile(psi, len(atts))
    body_to_ned = Rotation.from_euler("ZYX", np.column_stack((yaw, pitch, roll)))
    b = body_to_ned.inv().apply(np.array([hh, 0.0, vertical_ut]))
    raw = b @ np.linalg.inv(model_from.soft_iron).T + model_from.hard_iron_ut
    h_from = tilt_compensated_heading_rad(model_from.apply(raw), roll, pitch)
    h_to = tilt_compensated_heading_rad(model_to.apply(raw), roll, pitch)
    d = np.degrees(np.angle(np.exp(1j * (h_to - h_from))))
    mean = math.degrees(math.atan2(np.mean(np.sin(np.radians(d))), np.mean(np.cos(np.radians(d)))))
    rest = d - mean
    return {"mean_deg": float(mean), "heading_dependent_rms_deg": float(np.sqrt(np.mean(rest**2)))}


def compare_with_offsets(full_model, offsets_model, full_quality: dict, total_ut: float, vertical_ut: float) -> dict:
    """Does the full (vertical-channel) fit beat the offsets-only model (soft iron kept)?

    The full fit predicts its own heading error from its parameter covariance (`predicted_heading`: the
    heading-dependent 1σ within the data's tilt envelope). If the full model is right to within that, the
    offsets-only model is wrong by the heading change between the two. So the full model wins when its
    predicted 1σ is smaller than that change; otherwise the data cannot tell the soft iron in force from the
    fitted one, and the offsets-only model (which changes less) is kept."""
    pred = full_quality.get("predicted_heading") or {}
    sigma = float(pred.get("heading_dependent_std_deg", math.inf))
    envelope = float(pred.get("envelope_tilt_deg", 10.0))
    change = heading_change_deg(full_model, offsets_model, total_ut, vertical_ut, envelope)
    return {"full_heading_std_deg": sigma, "full_offset_std_deg": float(pred.get("offset_std_deg", math.inf)),
            "offsets_heading_change_deg": change["heading_dependent_rms_deg"],
            "offsets_offset_change_deg": change["mean_deg"], "envelope_tilt_deg": envelope,
            "use_full": bool(sigma < change["heading_dependent_rms_deg"])}
