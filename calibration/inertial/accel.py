"""Multi-position accelerometer calibration: the 12-parameter model of the ADIS16405
AHRS thesis (docs/calibration.md).

Model (our form of the thesis's): f = L · (f̃ − b − q ∘ f̃²), L lower triangular (scale on the diagonal,
three misalignments below it: the accelerometer's x axis defines the platform frame, so the rotation the
gravity norm cannot see is fixed), b the bias, q the quadratic nonlinearity. 3 + 3 + 3 + 3 = 12 parameters.

1. Linear LS: for each static position i, z_i = (g − |S_o,i|)·g = h_i·X_a with
   h_i = [S_oy S_oz, −S_ox S_oz, S_ox S_oy, S_ox, S_oy, S_oz, −S_ox², −S_oy², −S_oz², S_ox³, S_oy³, S_oz³]
   X_a = [α_yx, α_xy, α_xz, δS_bx, δS_by, δS_bz, δk_x, δk_y, δk_z, k_nx, k_ny, k_nz]
   (first order in the errors: S^P ≈ S_o + E·S_o + δS_b + K_nl·S_o², E lower triangular).
2. Exact nonlinear refinement on |f| = g with scipy least_squares (step 1 is first order only),
   from step 1.

Fewer positions support fewer terms: 'auto' fits 12 parameters with ≥ 12 distinct orientations, 9 (no
quadratic) with ≥ 9, 6 (bias + per-axis scale) with ≥ 6, and refuses below that.

Still periods are found automatically in a recording (`find_still_segments`); `GuidedSession` is the live,
operator-guided procedure (which face down next, stillness detection, coverage).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.core.gravity import normal_gravity_m_s2

from ..models import AccelModel


def local_gravity_m_s2(lat_deg: float | None, alt_m: float = 0.0) -> float:
    """Normal gravity at latitude/height (core.gravity); standard gravity when the latitude is unknown (an
    error of up to 0.3 % in the scale factors)."""
    if lat_deg is None:
        return STANDARD_GRAVITY_M_S2
    return normal_gravity_m_s2(lat_deg, alt_m)


# ---------------------------------------------------------------------------------------------- the fit


def regressors(s_o: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """(z, H) of the linear LS step (module doc, step 1) for positions s_o (N, 3) in m/s²."""
    x, y, z = s_o[:, 0], s_o[:, 1], s_o[:, 2]
    h = np.column_stack([y * z, -x * z, x * y, x, y, z, -x * x, -y * y, -z * z, x**3, y**3, z**3])
    return (g - np.linalg.norm(s_o, axis=1)) * g, h


def model_from_linear(x_a: np.ndarray) -> AccelModel:
    """AccelModel from X_a: S^P ≈ (I + E)·S_o + δS_b + K_nl·S_o², E = [[−δk_x,0,0],[α_xz,−δk_y,0],[−α_xy,α_yx,−δk_z]].
    In our form L·(S_o − b − q∘S_o²): L = I + E, b = −L⁻¹·δS_b, q = −L⁻¹·K_nl (first order)."""
    a_yx, a_xy, a_xz, bx, by, bz, kx, ky, kz, nx, ny, nz = x_a
    lower = np.array([[1 - kx, 0, 0], [a_xz, 1 - ky, 0], [-a_xy, a_yx, 1 - kz]])
    inv = np.linalg.inv(lower)
    return AccelModel(-inv @ np.array([bx, by, bz]), lower, -np.diag(inv) * np.array([nx, ny, nz]))


_LOWER = [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]


def _pack(model: AccelModel, terms: int) -> np.ndarray:
    p = [model.matrix[i, j] for i, j in _LOWER] + list(model.bias_m_s2)
    if terms == 12:
        p += list(model.quadratic)
    return np.array(p)


def _unpack(p: np.ndarray, terms: int) -> AccelModel:
    m = np.zeros((3, 3))
    if terms == 6:
        m[0, 0], m[1, 1], m[2, 2] = p[:3]
        return AccelModel(p[3:6], m)
    for v, (i, j) in zip(p[:6], _LOWER):
        m[i, j] = v
    q = p[9:12] if terms == 12 else np.zeros(3)
    return AccelModel(p[6:9], m, q)


def _residual(p: np.ndarray, s_o: np.ndarray, g: float, terms: int) -> np.ndarray:
    if terms == 6:
        m = p[:3]
        return np.linalg.norm(m * (s_o - p[3:6]), axis=1) - g
    m = np.zeros((3, 3))
    for v, (i, j) in zip(p[:6], _LOWER):
        m[i, j] = v
    u = s_o - p[6:9]
    if terms == 12:
        u = u - p[9:12] * s_o * s_o
    return np.linalg.norm(u @ m.T, axis=1) - g


@dataclass(frozen=True)
class AccelFitResult:
    model: AccelModel
    residual_rms_m_s2: float
    terms: int
    quality: dict = field(default_factory=dict)
    refused: str | None = None
    linear_model: AccelModel | None = None   # the thesis's linear LS solution (step 1)

    @property
    def ok(self) -> bool:
        return self.refused is None

    def to_json_dict(self) -> dict:
        from ..models import _jsonable

        return {
            "bias_m_s2": self.model.bias_m_s2.tolist(),
            "matrix": self.model.matrix.tolist(),
            "quadratic_s2_m": self.model.quadratic.tolist(),
            "residual_rms_m_s2": _jsonable(self.residual_rms_m_s2),
            "terms": self.terms,
            "quality": _jsonable(self.quality),
            "refused": self.refused,
        }


def distinct_orientations(s_o: np.ndarray, min_angle_deg: float = 10.0) -> int:
    """How many of the positions point gravity in directions at least `min_angle_deg` apart (greedy)."""
    u = s_o / np.linalg.norm(s_o, axis=1, keepdims=True)
    reps: list[np.ndarray] = []
    cos_lim = math.cos(math.radians(min_angle_deg))
    for v in u:
        if all(float(v @ r) < cos_lim for r in reps):
            reps.append(v)
    return len(reps)


FACES = {"+x up": (1, 0, 0), "-x up": (-1, 0, 0), "+y up": (0, 1, 0), "-y up": (0, -1, 0),
         "+z up": (0, 0, 1), "-z up": (0, 0, -1)}


def face_coverage(s_o: np.ndarray, max_angle_deg: float = 30.0) -> dict:
    """Which of the six faces (axis pointing up = reading +g) have a position within `max_angle_deg`."""
    u = s_o / np.linalg.norm(s_o, axis=1, keepdims=True)
    cos_lim = math.cos(math.radians(max_angle_deg))
    return {name: bool(np.any(u @ np.array(d, dtype=float) > cos_lim)) for name, d in FACES.items()}


def fit_accel(position_means_m_s2: np.ndarray, g_m_s2: float = STANDARD_GRAVITY_M_S2, terms: int | str = "auto",
              max_condition: float = 1e8, max_residual_m_s2: float = 0.02) -> AccelFitResult:
    """Fit the accelerometer model to the mean specific force of N static positions ((N, 3), m/s²).

    terms: 12 (thesis), 9 (no quadratic), 6 (bias + diagonal scale) or 'auto' (largest the number of
    distinct orientations supports). Refuses (with the reason) when the positions cannot support the
    model: too few distinct orientations, an ill-conditioned regression, or residuals above
    `max_residual_m_s2` (default 2 mg RMS, ~10× what the ADIS16405's noise and in-run bias leave on a
    10 s position mean: someone moved the unit during a 'still' period, or the wrong local gravity)."""
    s_o = np.asarray(position_means_m_s2, dtype=np.float64)
    s_o = s_o[np.all(np.isfinite(s_o), axis=1)]
    n_pos = s_o.shape[0]
    distinct = distinct_orientations(s_o) if n_pos else 0
    quality: dict = {"positions": n_pos, "distinct_orientations": distinct, "faces": face_coverage(s_o) if n_pos else {},
                     "g_m_s2": g_m_s2}
    if terms == "auto":
        terms = 12 if distinct >= 12 else 9 if distinct >= 9 else 6
    if terms not in (6, 9, 12):
        raise ValueError(f"terms must be 6, 9, 12 or 'auto', got {terms!r}")
    if distinct < terms:
        return AccelFitResult(AccelModel.identity(), math.nan, terms, quality,
                              f"{distinct} distinct orientations cannot determine {terms} parameters: "
                              f"record at least {terms} (turn the unit onto each face and the corners between); "
                              f"found {n_pos} still position{'s' if n_pos != 1 else ''}"
                              + (", faces up: " + (", ".join(k for k, v in quality["faces"].items() if v) or "none")
                                 if n_pos else ""))
    linear = _linear_step(s_o, g_m_s2, terms, quality, max_condition)
    if linear is None:
        return AccelFitResult(AccelModel.identity(), math.nan, terms, quality,
                              f"the positions do not separate the parameters (condition number "
                              f"{quality['condition_number']:.3g}): add orientations between the faces (corners)")
    return _nonlinear_step(s_o, g_m_s2, terms, quality, linear, max_residual_m_s2)


def _linear_step(s_o: np.ndarray, g_m_s2: float, terms: int, quality: dict, max_condition: float
                 ) -> AccelModel | None:
    """Step 1, the thesis's linear LS (12 parameters; with fewer, the columns dropped): the model, or None when
    the regression is ill-conditioned (condition number in `quality`)."""
    z, h = regressors(s_o, g_m_s2)
    cols = list(range(12)) if terms == 12 else list(range(9)) if terms == 9 else [3, 4, 5, 6, 7, 8]
    hs = h[:, cols]
    cond = float(np.linalg.cond(hs / np.linalg.norm(hs, axis=0)))
    quality["condition_number"] = cond
    if not np.isfinite(cond) or cond > max_condition:
        return None
    sol, *_ = np.linalg.lstsq(hs, z, rcond=None)
    x_a = np.zeros(12)
    x_a[cols] = sol
    linear = model_from_linear(x_a)
    quality["linear_residual_rms_m_s2"] = float(np.sqrt(np.mean(_residual(_pack(linear, 12), s_o, g_m_s2, 12) ** 2)))
    return linear


def _nonlinear_step(s_o: np.ndarray, g_m_s2: float, terms: int, quality: dict, linear: AccelModel,
                    max_residual_m_s2: float) -> AccelFitResult:
    """Step 2, the exact nonlinear LS on |f| = g from the linear model; its bias 1σ and residuals in `quality`;
    refused when the residual RMS is above `max_residual_m_s2`."""
    from scipy.optimize import least_squares

    n_pos = s_o.shape[0]
    if terms == 6:
        p0 = np.concatenate([np.diag(linear.matrix), linear.bias_m_s2])
    else:
        p0 = _pack(linear, terms)
    fit = least_squares(_residual, p0, args=(s_o, g_m_s2, terms), method="lm" if n_pos > len(p0) else "trf",
                        x_scale="jac")
    model = _unpack(fit.x, terms)
    r = _residual(fit.x, s_o, g_m_s2, terms)
    rms = float(np.sqrt(np.mean(r**2)))
    dof = max(n_pos - len(p0), 1)
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * float(r @ r) / dof
        sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
        quality["sigma_bias_m_s2"] = (sig[3:6] if terms == 6 else sig[6:9]).tolist()
    except np.linalg.LinAlgError:
        quality["sigma_bias_m_s2"] = [math.inf] * 3
    quality.update(residual_rms_m_s2=rms, residual_max_m_s2=float(np.max(np.abs(r))),
                   position_residuals_m_s2=r.tolist(), lm_status=int(fit.status))
    if rms > max_residual_m_s2:
        worst = int(np.argmax(np.abs(r)))
        mg = 1e3 / STANDARD_GRAVITY_M_S2
        return AccelFitResult(AccelModel.identity(), rms, terms, {**quality, "rejected_model": model.to_dict()},
                              f"residual {rms * mg:.1f} mg RMS is too large (limit {max_residual_m_s2 * mg:.1f} mg; "
                              f"the worst, position {worst + 1} of {n_pos}, is {r[worst] * mg:+.1f} mg off |f| = g): "
                              "a position was not still (hold each still; re-record that one), or the local "
                              "gravity is wrong (give --lat and --alt-m)", linear)
    return AccelFitResult(model, rms, terms, quality, None, linear)


# ---------------------------------------------------------------------------------------------- still periods


@dataclass(frozen=True)
class StillSegment:
    start: int            # sample index (inclusive) of the samples averaged (the period less `trim_s` each end)
    stop: int             # sample index (exclusive)
    mean_accel_m_s2: np.ndarray
    mean_gyro_rad_s: np.ndarray
    duration_s: float     # how long the unit was still (the whole period, before trimming)
    accel_std_m_s2: np.ndarray | None = None   # per-axis sample standard deviation over [start, stop)

    @property
    def samples(self) -> int:
        return self.stop - self.start

    @property
    def mean_noise_m_s2(self) -> float:
        """1σ white-noise error of `mean_accel_m_s2` (the norm over the axes of std/√n)."""
        if self.accel_std_m_s2 is None or self.samples < 2:
            return math.nan
        return float(np.linalg.norm(self.accel_std_m_s2) / math.sqrt(self.samples))


DEFAULT_MIN_STILL_S = 2.0   # shortest still period used as a position: a 2-s hold by hand or on a positioner


def still_periods(accel_m_s2: np.ndarray, gyro_rad_s: np.ndarray | None, rate_hz: float,
                  window_s: float = 0.5, max_gyro_rad_s: float = 0.02, accel_std_factor: float = 4.0,
                  trim_s: float = 0.25) -> list[StillSegment]:
    """Every still period of a recording, however short.

    A sliding window of `window_s` (stepped by a tenth of its length) is still when the accelerometer's std
    over it is within `accel_std_factor` of the quietest windows' (the noise floor), the gyro's mean rate is
    below `max_gyro_rad_s` and its std within the same factor of its own floor (so a rate table turning or
    starting to turn about the vertical, which the accelerometer cannot see, is not "still"), and its mean has not moved from the
    still window one length before it (a slow, smooth tilt is not still; a window after a slew has no still
    predecessor and is not penalised). A period spans its still windows, so its duration is the hold's own,
    to a step; the mean is taken over the period less `trim_s` at each end (the settling after a slew)."""
    acc = np.asarray(accel_m_s2, dtype=np.float64)
    w = max(2, int(round(window_s * rate_hz)))
    if acc.shape[0] < 2 * w:
        return []
    starts, still = _still_windows(acc, gyro_rad_s, w, max_gyro_rad_s, accel_std_factor)
    trim = int(round(trim_s * rate_hz))
    periods = []
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    for first, last in zip(edges[::2], edges[1::2] - 1):
        begin, end = int(starts[first]), int(starts[last]) + w
        start, stop = begin + trim, end - trim
        if stop - start < 2:
            start, stop = begin, end
        a = acc[start:stop]
        gm = np.zeros(3) if gyro_rad_s is None else np.asarray(gyro_rad_s[start:stop]).mean(axis=0)
        periods.append(StillSegment(start, stop, a.mean(axis=0), gm, (end - begin) / rate_hz, a.std(axis=0)))
    return periods


def _still_windows(acc: np.ndarray, gyro_rad_s: np.ndarray | None, w: int, max_gyro_rad_s: float,
                   accel_std_factor: float) -> tuple[np.ndarray, np.ndarray]:
    """The sliding windows of `w` samples (stepped by a tenth of w): their first samples, and which are still
    by `still_periods`' rule (noise floors, gyro, not moved from the still window one length before)."""
    step = max(1, w // 10)
    starts = np.arange(0, acc.shape[0] - w + 1, step)

    def window_sums(x):
        c = np.vstack([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
        return c[starts + w] - c[starts]

    centred = acc - acc.mean(axis=0)              # keeps the running sums of squares well conditioned
    mean = window_sums(centred) / w
    var = np.maximum(window_sums(centred * centred) / w - mean * mean, 0.0)
    a_std = np.sqrt(var.sum(axis=1))
    floor = max(float(np.percentile(a_std, 10)), 1e-6)
    still = a_std <= accel_std_factor * floor
    if gyro_rad_s is not None:   # the gyro quiet too: its mean near zero and its std at its own noise floor
        gyro = np.asarray(gyro_rad_s, dtype=np.float64)
        g_mean = window_sums(gyro) / w
        g_std = np.sqrt(np.maximum(window_sums(gyro * gyro) / w - g_mean * g_mean, 0.0).sum(axis=1))
        g_floor = max(float(np.percentile(g_std, 10)), 1e-9)
        still &= (np.linalg.norm(g_mean, axis=1) <= max_gyro_rad_s) & (g_std <= accel_std_factor * g_floor)
    lag = w // step                               # the window one length earlier
    moved = np.zeros_like(still)
    moved[lag:] = still[:-lag] & (np.linalg.norm(mean[lag:] - mean[:-lag], axis=1) > accel_std_factor * floor)
    return starts, still & ~moved


def find_still_segments(accel_m_s2: np.ndarray, gyro_rad_s: np.ndarray | None, rate_hz: float,
                        window_s: float = 0.5, min_still_s: float = DEFAULT_MIN_STILL_S,
                        max_gyro_rad_s: float = 0.02, accel_std_factor: float = 4.0,
                        trim_s: float = 0.25) -> list[StillSegment]:
    """The still periods (`still_periods`) that lasted at least `min_still_s`."""
    periods = still_periods(accel_m_s2, gyro_rad_s, rate_hz, window_s, max_gyro_rad_s, accel_std_factor, trim_s)
    return split_by_duration(periods, min_still_s, window_s)[0]


def split_by_duration(periods: list[StillSegment], min_still_s: float,
                      window_s: float = 0.5) -> tuple[list[StillSegment], list[StillSegment]]:
    """(the periods that lasted at least `min_still_s`, the shorter ones). A period's length is known to the
    detection's step, a tenth of `window_s` (a 2.0-s hold may measure 1.95 s), so that much is allowed."""
    shortest_s = min_still_s - window_s / 10 - 1e-9
    return [p for p in periods if p.duration_s >= shortest_s], [p for p in periods if p.duration_s < shortest_s]


def short_holds_refusal(periods: list[StillSegment], min_still_s: float) -> str:
    """Why no position came out of a recording's still periods, and what to do about it."""
    if not periods:
        return ("no still period found (the accelerometer never stayed within its noise for 0.5 s with the gyro "
                "quiet): hold the unit still in each position")
    longest = max(p.duration_s for p in periods)
    return (f"{len(periods)} still period{'s' if len(periods) != 1 else ''}, the longest {longest:.1f} s, all "
            f"shorter than --min-still-s {min_still_s:g}: hold each position at least {max(min_still_s, 2.0):g} s, "
            f"or lower --min-still-s (to {math.floor(longest * 10) / 10:g} to use these)")


def hold_cost(used: list[StillSegment], skipped: list[StillSegment], rate_hz: float,
              reference_hold_s: float = 10.0) -> dict:
    """What the holds' lengths cost the fit. Each position's mean carries the sensor's white noise over the
    samples averaged, σ/√n; the same sensor held `reference_hold_s` would carry σ/√(rate·T_ref) (in-run bias
    drift, which longer holds do not average away, comes on top of both). Also how many still periods were
    too short to use."""
    cost: dict = {"still_periods_skipped_short": len(skipped)}
    if skipped:
        cost["skipped_longest_s"] = max(q.duration_s for q in skipped)
    if not used:
        return cost
    noise = np.array([q.mean_noise_m_s2 for q in used])
    cost.update(hold_s_min=min(q.duration_s for q in used), hold_s_median=float(np.median([q.duration_s for q in used])),
                averaged_s_min=min(q.samples for q in used) / rate_hz,
                position_noise_m_s2_median=float(np.median(noise)), position_noise_m_s2_max=float(np.max(noise)))
    per_sample = np.median(noise * np.sqrt([q.samples for q in used]))   # σ of one sample (norm over axes)
    cost[f"position_noise_m_s2_{reference_hold_s:g}s_hold"] = float(per_sample / math.sqrt(rate_hz * reference_hold_s))
    return cost


# ---------------------------------------------------------------------------------------------- guided procedure

# The positions the guided procedure asks for: the six faces, then the eight corners (each with three axes
# tilted ~35° from vertical), 14 ≥ 12 distinct orientations (12 parameters need at least 12; more is better).
# Each is the direction the accelerometer reads +g along (the "up" direction in sensor axes).
_S = 1 / math.sqrt(3)
GUIDED_TARGETS: tuple[tuple[str, tuple[float, float, float]], ...] = (
    ("level, as mounted: Z axis pointing down", (0, 0, -1)),
    ("upside down: Z axis pointing up", (0, 0, 1)),
    ("on its side: Y axis pointing down", (0, -1, 0)),
    ("on the other side: Y axis pointing up", (0, 1, 0)),
    ("nose down: X axis pointing down", (-1, 0, 0)),
    ("nose up: X axis pointing up", (1, 0, 0)),
) + tuple(
    (f"on a corner: X {'up' if sx > 0 else 'down'}, Y {'up' if sy > 0 else 'down'}, Z {'up' if sz > 0 else 'down'} "
     "(each axis about 35° from level)", (sx * _S, sy * _S, sz * _S))
    for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)
)

# With face pairs (`calibrate accel --live --align-to-faces`), each face is held a second time, turned half round
# about the vertical on the surface: that reverses a surface tilt's component in the housing frame, and the mean
# of the two cancels it (calibration/inertial/accel_alignment.py).
GUIDED_TARGETS_FACE_PAIRS = tuple(
    t for face in GUIDED_TARGETS[:6] for t in (face, (f"{face[0]}, again, turned half round on the surface",
                                                     face[1]))) + GUIDED_TARGETS[6:]


@dataclass
class GuidedSession:
    """Operator-guided multi-position calibration, fed one sample at a time (live from the bus).

    `prompt` says which position to put the unit in next; `feed(sample)` returns a status line when
    something happens (still detected, position recorded, wrong position). Any target position counts when
    the unit is still in it (not only the one prompted), so the operator may go in any order. Targets that share
    a direction (GUIDED_TARGETS_FACE_PAIRS) are filled in turn, one per still period: the unit must move
    between them.
    """

    rate_hz: float
    still_s: float = 4.0
    tolerance_deg: float = 12.0
    max_gyro_rad_s: float = 0.02          # mean rate over a 0.25 s block above this = moving
    max_accel_change_m_s2: float = 0.05   # block mean moving this much from the previous block = moving
    targets: tuple = GUIDED_TARGETS
    recorded: dict = field(default_factory=dict)      # target index -> mean specific force (3,)
    _block_a: list = field(default_factory=list)
    _block_g: list = field(default_factory=list)
    _prev_block_mean: np.ndarray | None = None
    _sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _count: int = 0
    _announced: int | None = None   # the position last reported in this still period (say it once)

    @property
    def done(self) -> bool:
        return len(self.recorded) == len(self.targets)

    @property
    def prompt(self) -> str:
        for i, (text, _) in enumerate(self.targets):
            if i not in self.recorded:
                return f"position {len(self.recorded) + 1}/{len(self.targets)}: put the unit {text}, and hold it still"
        return "all positions recorded"

    def coverage(self) -> str:
        return (f"{len(self.recorded)}/{len(self.targets)} positions; faces: "
                + ", ".join(k for k, v in face_coverage(self.position_means()).items() if v) if self.recorded else
                f"0/{len(self.targets)} positions")

    def position_means(self) -> np.ndarray:
        return np.array([self.recorded[k] for k in sorted(self.recorded)]) if self.recorded else np.zeros((0, 3))

    def feed(self, sample) -> str | None:
        """Take one sample; once it completes a still period, that period recorded as the position it is in. The
        text to show the operator (recorded, already have, not a requested position), or None."""
        mean = self._still_period_mean(sample)
        return None if mean is None else self._record_position(mean)

    def _still_period_mean(self, sample) -> np.ndarray | None:
        """The mean specific force of a still period of `still_s` as it completes, else None. Stillness is judged
        on 0.25 s block means (per-sample noise at 819 SPS is ~10 mg, far above any useful per-sample threshold):
        the gyro mean must be small and the accelerometer mean must not move between blocks."""
        a, g = np.asarray(sample.accel_m_s2, dtype=float), np.asarray(sample.gyro_rad_s, dtype=float)
        # per sample (live at 819.2 SPS): math.isfinite on the values costs a tenth of np.isfinite on 3-vectors
        if not (all(map(math.isfinite, a.ravel().tolist())) and all(map(math.isfinite, g.ravel().tolist()))):
            return None
        self._block_a.append(a)
        self._block_g.append(g)
        n_block = max(2, int(round(0.25 * self.rate_hz)))
        if len(self._block_a) < n_block:
            return None
        block_mean = np.mean(self._block_a, axis=0)
        moving = np.linalg.norm(np.mean(self._block_g, axis=0)) > self.max_gyro_rad_s or (
            self._prev_block_mean is not None
            and np.linalg.norm(block_mean - self._prev_block_mean) > self.max_accel_change_m_s2)
        n = len(self._block_a)
        self._block_a.clear()
        self._block_g.clear()
        self._prev_block_mean = block_mean
        if moving:  # the still period must be continuous: start again
            self._sum[:] = 0.0
            self._count = 0
            self._announced = None
            return None
        self._sum += block_mean * n
        self._count += n
        if self._count < self.still_s * self.rate_hz:
            return None
        mean = self._sum / self._count
        self._sum = np.zeros(3)
        self._count = 0
        return mean

    def _record_position(self, mean: np.ndarray) -> str | None:
        """Record a still period's mean as the first requested position within `tolerance_deg` of its direction
        that is not recorded yet; each still period is reported once."""
        u = mean / np.linalg.norm(mean)
        cos_lim = math.cos(math.radians(self.tolerance_deg))
        matches = [i for i, (_, d) in enumerate(self.targets) if float(u @ np.array(d)) > cos_lim]
        if matches:
            if self._announced in matches:     # this still period has been recorded or reported already
                return None
            fresh = [i for i in matches if i not in self.recorded]
            if not fresh:
                self._announced = matches[0]
                return f"already have '{self.targets[matches[0]][0]}'; next: {self.prompt}"
            i = fresh[0]
            self.recorded[i] = mean
            self._announced = i
            return (f"recorded '{self.targets[i][0]}' ({self.coverage()})"
                    + ("" if self.done else f"; next: {self.prompt}"))
        if self._announced == -1:
            return None
        self._announced = -1
        return "still, but not in any of the requested positions; " + self.prompt

    def fit(self, g_m_s2: float = STANDARD_GRAVITY_M_S2, terms: int | str = "auto") -> AccelFitResult:
        return fit_accel(self.position_means(), g_m_s2, terms)
