"""The figure of a replay (`ahrsd replay ... --plot FILE.png`): roll, pitch and heading with their 1σ bands, the
estimator's flags as shaded spans, and, when the recording has truth, the error against it.

`ReplayTrace` collects the replay's tables as they stream past (ATTITUDE_COLUMNS, estimator/replay.py, and
NAV_COLUMNS after them for an aided run) and keeps at most `max_rows` of them by decimation, OR-ing the flags
over each group of rows dropped, so a flag that was up for one sample still shows. `replay_figure(trace, ...)`
draws it and returns the matplotlib figure; `plot_replay(trace, path, ...)` writes it to a file.

GNSS: the flags panel has a row for GNSS_AIDED / GNSS_OUTAGE / GNSS_REJECTED whenever they occur (the `ins`
estimator sets them). An aided run (the trace holds NAV_COLUMNS) adds a velocity panel (north, east, down, with
the GNSS fixes' velocities as points) and the track beside the time panels (north/east metres from the first
position, the fixes as points). `ReplayTrace.gnss` is the hook for further GNSS columns (`gnss_*`, one array
per name): each becomes a line in the GNSS panel, which is drawn only when there is something in it.
"""

from __future__ import annotations

import math

import numpy as np

from ahrsd.core.angles import wrap_pi
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.plotting import pyplot

from .replay import ATTITUDE_COLUMNS, NAV_COLUMNS
from .rotations import quat_to_euler

_COL = {name: i for i, name in enumerate(ATTITUDE_COLUMNS + NAV_COLUMNS)}
_KEPT = ("t_s", "roll_deg", "pitch_deg", "yaw_deg", "heading_true_deg", "sigma_roll_deg", "sigma_pitch_deg",
         "sigma_yaw_deg", "qw", "qx", "qy", "qz", "flags")
_KEPT_NAV = _KEPT[:-1] + NAV_COLUMNS + ("flags",)     # flags stay last: decimation ORs that column
_GNSS_FLAGS = EstimateFlags.GNSS_AIDED | EstimateFlags.GNSS_OUTAGE | EstimateFlags.GNSS_REJECTED
# flags panel rows, top to bottom, with a colour each (the GNSS ones last, the hook for the aided estimator)
_FLAG_ROWS = (
    (EstimateFlags.INITIALISING, "initialising", "tab:gray"),
    (EstimateFlags.AT_REST, "at rest", "tab:green"),
    (EstimateFlags.ACCEL_REJECTED, "accel rejected", "tab:orange"),
    (EstimateFlags.MAG_REJECTED, "mag rejected", "tab:red"),
    (EstimateFlags.MAG_UNAVAILABLE, "mag unavailable", "tab:purple"),
    (EstimateFlags.LARGE_DT | EstimateFlags.REINITIALISED, "time gap / reinit", "black"),
    (EstimateFlags.GNSS_AIDED, "GNSS aided", "tab:blue"),
    (EstimateFlags.GNSS_OUTAGE, "GNSS outage", "tab:brown"),
    (EstimateFlags.GNSS_REJECTED, "GNSS rejected", "tab:pink"),
)
# flags shaded behind the angle panels: the ones that say "do not trust this stretch as much"
_SHADED = ((EstimateFlags.INITIALISING, "tab:gray"), (EstimateFlags.MAG_REJECTED, "tab:red"),
           (EstimateFlags.ACCEL_REJECTED, "tab:orange"), (EstimateFlags.MAG_UNAVAILABLE, "tab:purple"))
# an angle whose σ is this large is not known (the daemon's "heading unknown" reads 180°): its error is no accuracy,
# and a heading band of ±90° or more, wrapped at 0/360°, would cover the panel with nothing to read in it
UNKNOWN_SIGMA_DEG = 90.0
TILT_BANDS_ONE_RTOL = 0.01    # roll's and pitch's σ this close on every row: one error band for both


class ReplayTrace:
    """The replay output for a figure, at most `max_rows` rows (decimated as it grows)."""

    def __init__(self, max_rows: int = 200_000):
        self.max_rows = max_rows
        self.stride = 1
        self._chunks: list[np.ndarray] = []
        self._rows = 0
        self._pending: np.ndarray | None = None   # rows not yet a whole stride
        self.true_north = False
        self.gnss: dict[str, np.ndarray] = {}       # hook: gnss_* columns, once replays carry them
        self.columns: tuple[str, ...] = _KEPT        # what table() holds: _KEPT_NAV once an aided table came

    @property
    def aided(self) -> bool:
        return self.columns is _KEPT_NAV

    def add(self, table: np.ndarray) -> None:
        """One table of replay output: ATTITUDE_COLUMNS, or ATTITUDE_COLUMNS + NAV_COLUMNS (+ the heading
        columns) for an aided run."""
        if self._rows == 0 and self._pending is None and table.shape[1] >= len(ATTITUDE_COLUMNS) + len(NAV_COLUMNS):
            self.columns = _KEPT_NAV
        kept = table[:, [_COL[c] for c in self.columns]]
        if self._pending is not None:
            kept = np.vstack([self._pending, kept])
            self._pending = None
        self._append(kept)

    def _append(self, rows: np.ndarray) -> None:
        n_whole = len(rows) // self.stride * self.stride
        if n_whole < len(rows):
            self._pending = rows[n_whole:]
        if n_whole:
            self._chunks.append(_decimate(rows[:n_whole], self.stride))
            self._rows += n_whole // self.stride
        while self._rows > self.max_rows:   # halve what is kept, double the stride
            kept = np.vstack(self._chunks)
            pairs = len(kept) // 2 * 2
            self._chunks = [_decimate(kept[:pairs], 2)] + ([kept[pairs:]] if pairs < len(kept) else [])
            self._rows = sum(len(c) for c in self._chunks)
            self.stride *= 2

    def table(self) -> np.ndarray:
        parts = list(self._chunks) + ([self._pending[:1]] if self._pending is not None else [])
        return np.vstack(parts) if parts else np.empty((0, len(self.columns)))


def _decimate(rows: np.ndarray, stride: int) -> np.ndarray:
    """Every `stride`-th row, with the flags OR-ed over the rows it stands for."""
    if stride == 1:
        return rows
    out = rows[::stride].copy()
    flags = rows[:, -1].astype(np.int64).reshape(-1, stride)
    out[:, -1] = np.bitwise_or.reduce(flags, axis=1)
    return out


_FLAG_NAMES = {flag: name for flag, name, _ in _FLAG_ROWS}


def _flag_rows(flags: np.ndarray, gnss_rows: bool) -> list[tuple]:
    """The flags panel's rows: each flag raised somewhere, and the GNSS rows whenever GNSS is in play."""
    return [r for r in _FLAG_ROWS if (flags & int(r[0])).any() or (gnss_rows and r[0] & _GNSS_FLAGS)]


def _flag_row_count(flags: np.ndarray, gnss_rows: bool) -> int:
    return max(len(_flag_rows(flags, gnss_rows)), 1)


# runs of a flag closer than this share of the time axis are drawn as one span: about a pixel of the figure, so
# a flag raised at every magnetometer update (one sample in 8-9) shows as the stretch it covers, not as
# thousands of sub-pixel slivers that antialiasing draws faint and sparse (and that cost memory to draw)
_SPAN_JOIN_FRACTION = 1e-3


def _spans(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """(start, width) of each run of `on`, runs less than `_SPAN_JOIN_FRACTION` of the time axis apart joined."""
    if not on.any():
        return []
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(np.int8), 0]))
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    starts, ends = edges[::2], edges[1::2] - 1          # first and last sample of each run
    join_s = _SPAN_JOIN_FRACTION * float(t[-1] - t[0]) if len(t) > 1 else 0.0
    keep = np.r_[True, t[starts[1:]] - t[ends[:-1]] - step >= join_s]   # a run that starts a new span
    first, last = starts[keep], np.r_[ends[np.flatnonzero(keep)[1:] - 1], ends[-1]]
    return [(float(t[a]), float(t[b] - t[a] + step)) for a, b in zip(first, last)]


def _break_wraps(t: np.ndarray, deg: np.ndarray, *more: np.ndarray, jump_deg: float = 180.0) -> list[np.ndarray]:
    """t, deg (and `more` arrays alike) with NaN inserted where the heading wraps (360 → 0), so neither the line
    nor its band crosses the panel."""
    cut = np.flatnonzero(np.abs(np.diff(deg)) > jump_deg) + 1
    return [np.insert(np.asarray(x, dtype=float), cut, np.nan) for x in (t, deg, *more)]


def _robust_limits(bands: list[np.ndarray], settled: np.ndarray, whole: list[np.ndarray] = (),
                   truth=None, min_span: float = 1.0) -> tuple[float, float]:
    """y limits (10 % margin) holding the settled rows' σ bands (0.5…99.5 percentiles: a start-up transient or
    the wide σ before the filter converged does not squash the rest of the trace), every settled value of `whole`
    (the estimate) and every value of `truth` (no transient there): a percentile cut the highest wave peaks of a
    heaving boat flat."""
    rows = settled if settled.any() else np.ones_like(settled, dtype=bool)
    v = np.concatenate([x[rows] for x in bands]) if bands else np.empty(0)
    v = v[np.isfinite(v)]
    w = np.concatenate([np.asarray(x)[rows] for x in whole] + ([np.asarray(truth)] if truth is not None else [])) \
        if len(whole) or truth is not None else np.empty(0)
    w = w[np.isfinite(w)]
    if not v.size and not w.size:
        return -1.0, 1.0
    lo, hi = np.percentile(v, [0.5, 99.5]) if v.size else (np.inf, -np.inf)
    if w.size:
        lo, hi = min(lo, float(w.min())), max(hi, float(w.max()))
    mid, half = (lo + hi) / 2, max(hi - lo, min_span) / 2 * 1.1
    return float(mid - half), float(mid + half)


def truth_errors_deg(q_est_wxyz: np.ndarray, q_truth_wxyz: np.ndarray) -> np.ndarray:
    """(n, 3) roll, pitch, heading error (estimate − truth, ZYX Euler, degrees; heading wrapped to ±180)."""
    est = quat_to_euler(q_est_wxyz)
    truth = quat_to_euler(q_truth_wxyz)
    return np.degrees(wrap_pi(est - truth))


def replay_title(recording_name: str, estimator_name: str, *, aided: bool, declination_rad: float,
                 position_deg: tuple | None, position_from_gnss: bool) -> str:
    """What the figure shows: the recording, the estimator that ran (the default when none was named), and the
    north the heading is referred to, with the declination and where it came from."""
    what = f"{recording_name} through {estimator_name}" + (" aided by GNSS" if aided else "")
    if position_deg is None:
        return what + ", heading to magnetic north (give --lat/--lon for true north)"
    where = "the first GNSS fix" if position_from_gnss else "--lat/--lon"
    return (what + f", heading to true north (declination {math.degrees(declination_rad):+.2f}° at {where} "
            f"{position_deg[0]:.5f}, {position_deg[1]:.5f})")


def plot_replay(trace: ReplayTrace, path, truth_q_wxyz: np.ndarray | None = None, truth_t_s: np.ndarray | None = None,
                title: str = "", fixes=()) -> None:
    """The figure (`replay_figure`), to `path` (PNG)."""
    plt = pyplot()
    fig = replay_figure(trace, truth_q_wxyz, truth_t_s, title, fixes)
    try:
        fig.savefig(path, dpi=90)
    finally:
        plt.close(fig)


EARTH_RADIUS_M = 6_371_008.8    # mean radius: the track is drawn in local metres (flat earth over a run)


def _local_ne_m(lat_deg, lon_deg, lat0_deg: float, lon0_deg: float) -> tuple[np.ndarray, np.ndarray]:
    north = np.radians(np.asarray(lat_deg, dtype=float) - lat0_deg) * EARTH_RADIUS_M
    east = np.radians(np.asarray(lon_deg, dtype=float) - lon0_deg) * EARTH_RADIUS_M * math.cos(math.radians(lat0_deg))
    return north, east


def replay_figure(trace: ReplayTrace, truth_q_wxyz: np.ndarray | None = None, truth_t_s: np.ndarray | None = None,
                  title: str = "", fixes=()):
    """The figure (a matplotlib Figure; the caller saves and closes it). truth_q_wxyz (m, 4) at truth_t_s (m,):
    the recording's truth attitude (body→NED, true north), interpolated to the kept rows by nearest sample.
    fixes: the GNSS fixes the run was aided with (core.gnss.GnssFix), drawn as points on the velocity and track
    panels of an aided trace.

    Panels, each found by its label: roll, pitch, heading; "error vs truth (°)" with truth; "velocity (m/s)" and
    the track ("north (m)" against "east (m)") for an aided run; the flags."""
    tab = trace.table()
    col = {name: i for i, name in enumerate(trace.columns)}
    t = tab[:, 0] - (tab[0, 0] if len(tab) else 0.0)
    roll, pitch, heading = tab[:, col["roll_deg"]], tab[:, col["pitch_deg"]], tab[:, col["heading_true_deg"]]
    s_roll, s_pitch, s_yaw = tab[:, col["sigma_roll_deg"]], tab[:, col["sigma_pitch_deg"]], tab[:, col["sigma_yaw_deg"]]
    flags = tab[:, -1].astype(np.int64)
    truth_err, truth_euler = _truth_series(tab, col, truth_q_wxyz, truth_t_s)
    gnss_rows = bool(flags.any() and (flags & int(_GNSS_FLAGS)).any()) or bool(trace.gnss)
    panels = ["roll", "pitch", "heading"] + (["error"] if truth_err is not None else []) + \
             (["velocity"] if trace.aided else []) + ["flags"] + (["gnss"] if trace.gnss else [])
    fig, axes, track_ax = _layout(trace, panels, _flag_row_count(flags, gnss_rows))
    settled = (flags & int(EstimateFlags.INITIALISING)) == 0
    ax = dict(zip(panels, axes))
    north = "true north" if trace.true_north else "magnetic north (no --lat/--lon)"
    truth = (None, None, None) if truth_euler is None else (truth_euler[:, 0], truth_euler[:, 1], truth_euler[:, 2])
    _angle_panel(ax["roll"], t, flags, settled, roll, s_roll, "roll (°)", truth[0], name_shading=True)
    _angle_panel(ax["pitch"], t, flags, settled, pitch, s_pitch, "pitch (°)", truth[1])
    if trace.true_north:
        _angle_panel(ax["heading"], t, flags, settled, heading, s_yaw, "true heading (°)", truth[2], wrap=True)
    else:
        _angle_panel(ax["heading"], t, flags, settled, tab[:, col["yaw_deg"]] % 360.0, s_yaw,
                     "magnetic heading (°)", truth[2], wrap=True)
    if truth_err is not None:
        _error_panel(ax["error"], t, truth_err, (s_roll, s_pitch, s_yaw), trace.true_north, settled)
    _flags_panel(ax["flags"], t, _flag_rows(flags, gnss_rows), flags)
    if trace.gnss:
        _gnss_panel(ax["gnss"], t, trace.gnss)
    if trace.aided:
        _navigation_panels(ax["velocity"], track_ax, tab, col, t, fixes)
    for a in axes[:-1]:
        a.tick_params(labelbottom=False)
    axes[-1].set_xlabel("time since the first sample (s)")
    fig.suptitle(title or f"replay (heading to {north})", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    return fig


def _truth_series(tab: np.ndarray, col: dict, truth_q_wxyz, truth_t_s):
    """(error against truth, truth's ZYX Euler angles), degrees, (n, 3) each with NaN where either attitude is
    missing; (None, None) without truth."""
    if truth_q_wxyz is None or not len(tab):
        return None, None
    quat = tab[:, [col["qw"], col["qx"], col["qy"], col["qz"]]]
    idx = np.clip(np.searchsorted(truth_t_s, tab[:, 0]), 0, len(truth_t_s) - 1)
    q_truth = truth_q_wxyz[idx]
    ok = np.isfinite(quat[:, 0]) & np.all(np.isfinite(q_truth), axis=1)
    truth_err = np.full((len(tab), 3), np.nan)
    truth_err[ok] = truth_errors_deg(quat[ok], q_truth[ok])
    truth_euler = np.full((len(tab), 3), np.nan)
    truth_euler[ok] = np.degrees(quat_to_euler(q_truth[ok]))
    return truth_err, truth_euler


def _layout(trace: ReplayTrace, panels: list[str], n_flag_rows: int):
    """(figure, the time panels' axes top to bottom, the track's axes or None): the time panels share the time
    axis; an aided run has the track beside them."""
    plt = pyplot()
    heights = {"roll": 2, "pitch": 2, "heading": 2, "error": 2.2, "velocity": 2,
               "flags": 0.35 + 0.3 * n_flag_rows, "gnss": 1.2}
    height_in = 1.15 * sum(heights[p] for p in panels) + 0.8
    if trace.aided:   # the track beside the time panels
        fig = plt.figure(figsize=(18, height_in))
        grid = fig.add_gridspec(len(panels), 2, width_ratios=(3.2, 1.4), height_ratios=[heights[p] for p in panels])
        axes = [fig.add_subplot(grid[0, 0])]
        axes += [fig.add_subplot(grid[k, 0], sharex=axes[0]) for k in range(1, len(panels))]
        return fig, axes, fig.add_subplot(grid[:, 1])
    fig, axes = plt.subplots(len(panels), 1, figsize=(13, height_in), sharex=True,
                             gridspec_kw={"height_ratios": [heights[p] for p in panels]})
    return fig, list(np.atleast_1d(axes)), None


def _angle_panel(a, t, flags, settled, value, sigma, label, truth_col=None, wrap=False, name_shading=False):
    """One angle with its ±1σ band and the truth (dashed), the distrusted stretches shaded; `wrap`: a heading
    (0–360°, or on its own scale while it stays within a half turn); `name_shading`: the shading's legend."""
    for flag, colour in _SHADED:
        for start, width in _spans(t, (flags & int(flag)) != 0):
            a.axvspan(start, start + width, color=colour, alpha=0.12, lw=0)
    unknown = np.asarray(sigma >= UNKNOWN_SIGMA_DEG) if wrap else np.zeros(len(t), dtype=bool)
    if unknown.any():   # no heading band where the heading is unknown: the panel says so instead
        sigma = np.where(unknown, np.nan, sigma)
        a.text(0.01, 0.97, f"heading unknown (σ ≥ {UNKNOWN_SIGMA_DEG:.0f}°, no band) on "
               f"{100.0 * float(np.mean(unknown)):.0f} % of the run", transform=a.transAxes, ha="left", va="top",
               fontsize=8, color="tab:red", gid="unknown heading")
    finite = value[np.isfinite(value) & settled]
    # a heading that stays within a half turn is drawn on its own scale (continuous across north)
    local = wrap and finite.size and np.ptp(np.unwrap(np.radians(finite))) < math.pi
    if local:
        centre = math.degrees(math.atan2(np.mean(np.sin(np.radians(finite))), np.mean(np.cos(np.radians(finite)))))
        value = centre + (value - centre + 180.0) % 360.0 - 180.0
        if truth_col is not None:
            truth_col = centre + (truth_col - centre + 180.0) % 360.0 - 180.0
        wrap = False
    if wrap:
        tb, vb, lo, hi = _break_wraps(t, value, value - sigma, value + sigma)
        a.fill_between(tb, lo, hi, color="tab:blue", alpha=0.25, lw=0, label="±1σ")
        a.plot(tb, vb, color="tab:blue", lw=1.0, label="estimate")
        a.set_ylim(0, 360)
        a.set_yticks([0, 90, 180, 270, 360])
    else:
        a.fill_between(t, value - sigma, value + sigma, color="tab:blue", alpha=0.25, lw=0, label="±1σ")
        a.plot(t, value, color="tab:blue", lw=1.0, label="estimate")
        a.set_ylim(*_robust_limits([value - sigma, value + sigma], settled, [value], truth_col))
    if truth_col is not None:
        tv = truth_col % 360.0 if wrap else truth_col
        a.plot(*(_break_wraps(t, tv) if wrap else (t, tv)), color="black", lw=0.8, ls="--", label="truth")
    for flag, colour in _SHADED:   # name the shading once, in the first panel
        if name_shading and (flags & int(flag)).any():
            a.axvspan(np.nan, np.nan, color=colour, alpha=0.25, lw=0, label=_FLAG_NAMES[flag])
    a.set_ylabel(label)
    a.grid(alpha=0.3)
    a.legend(loc="upper right", fontsize=8, ncol=7)


def _error_panel(a, t, truth_err, sigmas, true_north: bool, settled: np.ndarray) -> None:
    """Roll, pitch and heading error against truth, over their ±1σ bands (each in the legend). The RMS in the
    legend and the panel's scale come from the rows where the angle is known — the filter settled (not
    INITIALISING) and its σ below UNKNOWN_SIGMA_DEG — so an initialisation or an unknown heading (tens of degrees)
    neither sets the figure's headline nor squashes a tilt error of tenths of a degree flat; what it leaves off
    scale is said above the panel."""
    known_errors, off_scale = [], []
    roll_sigma, pitch_sigma = np.asarray(sigmas[0], dtype=float), np.asarray(sigmas[1], dtype=float)
    # within 1 % on every row the two bands cannot be told apart on the figure (mekf's differ by ~1e-5°)
    tilt_equal = bool(np.allclose(roll_sigma, pitch_sigma, rtol=TILT_BANDS_ONE_RTOL, atol=0.0, equal_nan=True))
    for k, (name, colour) in enumerate((("roll", "tab:blue"), ("pitch", "tab:green"), ("heading", "tab:red"))):
        e = truth_err[:, k]
        known = settled & (sigmas[k] < UNKNOWN_SIGMA_DEG) & np.isfinite(e)
        known_errors.append(e[known])
        a.plot(t, e, color=colour, lw=0.9, label=f"{name} ({_rms_words(t, e, known)})")
        # each band named in the legend: the three overlap into grey, and a reader must tell heading's from tilt's;
        # none where the angle is unknown (a ±180° band would cover the panel). Pitch's band equal to roll's (mekf
        # gives both the same σ) is one band named for both: two bands on one another read as a third colour
        if name == "pitch" and tilt_equal:
            continue
        band = np.where(np.asarray(sigmas[k]) >= UNKNOWN_SIGMA_DEG, np.nan, sigmas[k])
        both = name == "roll" and tilt_equal
        a.fill_between(t, -band, band, color="tab:cyan" if both else colour, alpha=0.10, lw=0,
                       label="roll ≈ pitch ±1σ" if both else f"{name} ±1σ")
    for start, width in _spans(t, ~settled):
        a.axvspan(start, start + width, color="tab:gray", alpha=0.12, lw=0)
    finite = np.concatenate(known_errors)
    if not finite.size:   # nothing known anywhere: the whole run sets the scale
        finite = truth_err[np.isfinite(truth_err)]
    if finite.size:   # the bulk, not a start-up transient, sets the scale
        span = max(float(np.percentile(np.abs(finite), 99)) * 1.3, 0.5)
        a.set_ylim(-span, span)
        for k, name in enumerate(("roll", "pitch", "heading")):
            e = truth_err[:, k]
            if (np.abs(e[np.isfinite(e)]) > span).any():
                off_scale.append(name)
    a.axhline(0, color="black", lw=0.5)
    a.set_ylabel("error vs truth (°)")
    a.grid(alpha=0.3)
    # one row under the panel, in the gap above the next: inside, it would hide the errors it names (a heading
    # error of tenths of a degree runs along the top of a scale set by the tilt's)
    a.legend(loc="upper right", bbox_to_anchor=(1.0, 0.0), fontsize=7, ncol=6, handlelength=1.5,
             columnspacing=1.0, borderaxespad=0.1, frameon=False)
    notes = []
    if off_scale:
        notes.append(f"{', '.join(off_scale)} error off scale while initialising or unknown (σ ≥ "
                     f"{UNKNOWN_SIGMA_DEG:.0f}°)")
    if not true_north:
        notes.append("heading error includes the declination: give --lat/--lon for true north")
    if notes:
        a.set_title("; ".join(notes), fontsize=8, loc="left")


def _rms_words(t: np.ndarray, e: np.ndarray, known: np.ndarray) -> str:
    """'RMS 0.11°', with where it was taken when not over the whole run: 'from 81 s' (a settled tail) or 'on 40 %
    of the run'; 'unknown throughout' when the angle never was."""
    if not known.any():
        return f"unknown throughout: σ ≥ {UNKNOWN_SIGMA_DEG:.0f}°"
    rms = math.sqrt(float(np.mean(e[known] ** 2)))
    drawn = np.isfinite(e)
    if known.sum() == drawn.sum():
        return f"RMS {rms:.2f}°"
    first = int(np.flatnonzero(known)[0])
    if known[first:].sum() == drawn[first:].sum():
        return f"RMS {rms:.2f}° from {t[first]:.0f} s"
    return f"RMS {rms:.2f}° on {100.0 * known.sum() / drawn.sum():.0f} % of the run"


def _flags_panel(a, t, rows: list[tuple], flags) -> None:
    """The flags as a timeline, one row per flag raised."""
    for k, (flag, name, colour) in enumerate(rows):
        a.broken_barh(_spans(t, (flags & int(flag)) != 0), (k - 0.4, 0.8), color=colour)
    a.set_yticks(range(len(rows)), [name for _, name, _ in rows], fontsize=8)
    a.set_ylim(-0.6, max(len(rows), 1) - 0.4)
    a.invert_yaxis()
    a.grid(axis="x", alpha=0.3)
    if not rows:
        a.text(0.5, 0.5, "no flags raised", transform=a.transAxes, ha="center", va="center", fontsize=9)
        a.set_yticks([])
    a.set_ylabel("flags")


def _gnss_panel(a, t, gnss: dict) -> None:
    """The trace's gnss_* columns (ReplayTrace.gnss), one line each."""
    for name, values in gnss.items():
        a.plot(t[: len(values)], values[: len(t)], lw=0.9, label=name)
    a.set_ylabel("GNSS")
    a.grid(alpha=0.3)
    a.legend(loc="upper right", fontsize=8)


def _navigation_panels(vel_ax, track_ax, tab: np.ndarray, col: dict, t: np.ndarray, fixes) -> None:
    """An aided run's velocity (estimate as lines, the GNSS fixes' velocities as points) and track."""
    t0 = tab[0, 0] if len(tab) else 0.0
    fixes = [f for f in fixes if f.t_s >= t0]
    for k, (name, colour) in enumerate((("north", "tab:blue"), ("east", "tab:orange"), ("down", "tab:green"))):
        vel_ax.plot(t, tab[:, col[NAV_COLUMNS[k]]], color=colour, lw=1.0, label=f"{name}")
        fv = [(f.t_s - t0, f.vel_ned_m_s[k]) for f in fixes if math.isfinite(f.vel_ned_m_s[k])]
        if fv:
            ft, v = np.array(fv).T
            vel_ax.plot(ft, v, ".", color=colour, ms=3, label="GNSS fixes" if k == 0 else None)
    vel_ax.set_ylabel("velocity (m/s)")
    vel_ax.grid(alpha=0.3)
    vel_ax.legend(loc="upper right", fontsize=8, ncol=4)

    lat, lon = tab[:, col["lat_deg"]], tab[:, col["lon_deg"]]
    # the position exists from the first fix the filter took (before it, the columns hold no position)
    aided_rows = np.flatnonzero(tab[:, -1].astype(np.int64) & int(EstimateFlags.GNSS_AIDED))
    ok = np.isfinite(lat) & np.isfinite(lon)
    ok[: aided_rows[0] if len(aided_rows) else len(ok)] = False
    with_position = [f for f in fixes if f.has_position]
    if ok.any():
        lat0, lon0 = float(lat[ok][0]), float(lon[ok][0])
    elif with_position:
        lat0, lon0 = with_position[0].lat_deg, with_position[0].lon_deg
    else:
        track_ax.text(0.5, 0.5, "no position", transform=track_ax.transAxes, ha="center", va="center")
        track_ax.set_xlabel("east (m)")
        track_ax.set_ylabel("north (m)")
        return
    n, e = _local_ne_m(lat[ok], lon[ok], lat0, lon0)
    track_ax.plot(e, n, color="tab:blue", lw=1.0, label="estimate")
    if with_position:
        fn, fe = _local_ne_m([f.lat_deg for f in with_position], [f.lon_deg for f in with_position], lat0, lon0)
        track_ax.plot(fe, fn, ".", color="black", ms=2, label="GNSS fixes")
    if len(n):
        track_ax.plot(e[:1], n[:1], "o", color="tab:green", label="start")
    track_ax.set_aspect("equal", adjustable="datalim")
    track_ax.set_xlabel("east (m)")
    track_ax.set_ylabel("north (m)")
    track_ax.set_title(f"track from {lat0:.5f}, {lon0:.5f}", fontsize=9)
    track_ax.grid(alpha=0.3)
    track_ax.legend(loc="best", fontsize=8)
