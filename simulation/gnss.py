"""A simulated GNSS receiver: `GnssFix`es from a stream's truth, with noise, latency, lever arm, outages, glitches.

    block = simulate("boat", 300.0, rate_hz=200.0)
    fixes = simulate_gnss(block, rate_hz=5.0, seed=1, outages=[(100.0, 130.0)],
                          glitches=[GnssGlitch(200.0, "position_jump")])
    for item in in_arrival_order(block, fixes):   # ImuSample or GnssFix, in the order a filter receives them
        ...

Epochs are at whole multiples of 1/rate_hz on the IMU time base (a receiver solves on the top of its period).
Each fix is the antenna's position and velocity at its time of validity `t_s`, plus errors:

- position, per axis north/east/down: white noise plus a slow wander (first-order Gauss–Markov, correlation time
  `wander_tau_s`, i.e. a bounded random walk: multipath and atmosphere drift slowly); the two add up to the
  configured 1σ (`horizontal_m` on north and east, `vertical_m` on down), `wander_fraction` of the variance
  in the wander. The wander starts from its stationary distribution, so every fix has the full σ.
- velocity: white, `velocity_m_s` per axis (Doppler velocity is nearly white).
- reported accuracies: h_acc_m, v_acc_m, s_acc_m_s are the σ above unless set otherwise (a receiver's own
  estimate can be optimistic: set them lower to test that).
- latency: the fix arrives at `extra["t_rx_s"]` = t_s + latency_s (+ uniform jitter in [0, jitter_s)).
- lever arm r (body FRD, m): p_ant = p + C_b^n r, v_ant = v + C_b^n (ω_nb × r) with ω_nb the truth body rate
  w.r.t. NED (Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed.,
  ch. 14, lever arm; the transport-rate term ω_en × C_b^n r, < 1e-5 m/s for these vehicles, is left out).
- outages: windows of validity time with no fix (silent), or with NO_FIX solutions (`GnssOutage(...,
  reports_no_fix=True)`, what a u-blox receiver sends when it loses lock).
- glitches (`GnssGlitch`): a position jump (default 50 m), a velocity spike (5 m/s), NaN fields, or a time
  stamp going backwards (1 s), on the fix at or after `t_s` (or every fix for `duration_s`).

Every fix carries in `extra`: "t_rx_s" (arrival time), "glitch" (the kind, or None), and "truth" (a `GnssTruth`:
the antenna's true time of validity, position and velocity), so a test knows what was true. Geodetic positions
are on the simulator's spherical Earth (R0 = 6 378 137 m, simulation.track). Deterministic from `seed`.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from ahrsd.core.gnss import GnssFix, GnssFixType
from ahrsd.core.sample import ImuSample
from ahrsd.core.slot_init import slot_init
from ahrsd.core.gravity import EARTH_RADIUS_M
from ahrsd.simulation.stream import SensorBlock, SensorStream, Truth

GLITCH_KINDS = ("position_jump", "velocity_spike", "nan", "time_backwards")
_DEFAULT_MAGNITUDE = {"position_jump": 50.0, "velocity_spike": 5.0, "nan": 0.0, "time_backwards": 1.0}


@dataclass(frozen=True, slots=True)
class GnssErrors:
    """Receiver error model. Position σ are per axis and include the wander; all values 1σ, SI units."""

    horizontal_m: float = 1.5           # north and east position error, 1σ each
    vertical_m: float = 2.5             # down position error, 1σ
    wander_fraction: float = 0.5        # share of the position error variance that wanders slowly
    wander_tau_s: float = 300.0         # correlation time of the wander (first-order Gauss–Markov)
    velocity_m_s: float = 0.05          # velocity error per axis, 1σ, white
    h_acc_m: float | None = None        # reported horizontal accuracy; None: horizontal_m
    v_acc_m: float | None = None        # reported vertical accuracy; None: vertical_m
    s_acc_m_s: float | None = None      # reported speed accuracy; None: velocity_m_s
    num_sats: int = 12

    def __post_init__(self):
        for name in ("horizontal_m", "vertical_m", "velocity_m_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"GnssErrors.{name} must be finite and ≥ 0, got {v!r}")
        if not 0.0 <= self.wander_fraction <= 1.0:
            raise ValueError(f"GnssErrors.wander_fraction must be in [0, 1], got {self.wander_fraction!r}")
        if not (math.isfinite(self.wander_tau_s) and self.wander_tau_s > 0):
            raise ValueError(f"GnssErrors.wander_tau_s must be > 0, got {self.wander_tau_s!r}")
        for name in ("h_acc_m", "v_acc_m", "s_acc_m_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ValueError(f"GnssErrors.{name} must be None or > 0, got {v!r}")

    @property
    def reported(self) -> tuple[float, float, float]:
        """(h_acc_m, v_acc_m, s_acc_m_s) the receiver reports."""
        return (self.horizontal_m if self.h_acc_m is None else self.h_acc_m,
                self.vertical_m if self.v_acc_m is None else self.v_acc_m,
                self.velocity_m_s if self.s_acc_m_s is None else self.s_acc_m_s)


@dataclass(frozen=True, slots=True)
class GnssOutage:
    """No usable fix for validity times in [start_s, stop_s): silent, or NO_FIX solutions if reports_no_fix."""

    start_s: float
    stop_s: float
    reports_no_fix: bool = False

    def __post_init__(self):
        if not (math.isfinite(self.start_s) and math.isfinite(self.stop_s) and self.stop_s > self.start_s):
            raise ValueError(f"outage needs finite start_s < stop_s, got {self.start_s!r}, {self.stop_s!r}")


@dataclass(frozen=True, slots=True)
class GnssGlitch:
    """A bad fix (or a run of them) the receiver reports as good (fix type 3D, nominal accuracies).

    kind: "position_jump" (magnitude m, horizontal, towards direction_deg), "velocity_spike" (magnitude m/s,
    horizontal), "nan" (position and velocity NaN), "time_backwards" (t_s stamped magnitude s early, the data
    still those of the true epoch). Applies to the first fix with validity ≥ t_s, or to every fix with validity
    in [t_s, t_s + duration_s] when duration_s > 0. magnitude None: 50 m, 5 m/s, —, 1 s.
    """

    t_s: float
    kind: str
    magnitude: float | None = None
    duration_s: float = 0.0
    direction_deg: float = 45.0

    def __post_init__(self):
        if self.kind not in GLITCH_KINDS:
            raise ValueError(f"glitch kind must be one of {', '.join(GLITCH_KINDS)}, got {self.kind!r}")
        if not (math.isfinite(self.t_s) and math.isfinite(self.duration_s) and self.duration_s >= 0):
            raise ValueError(f"glitch needs a finite t_s and duration_s ≥ 0, got {self.t_s!r}, {self.duration_s!r}")
        if self.magnitude is not None and not math.isfinite(self.magnitude):
            raise ValueError(f"glitch magnitude must be finite, got {self.magnitude!r}")

    @property
    def size(self) -> float:
        return _DEFAULT_MAGNITUDE[self.kind] if self.magnitude is None else float(self.magnitude)


@slot_init       # built once per fix: the cheaper __init__ (core/slot_init.py)
@dataclass(frozen=True, slots=True)
class GnssTruth:
    """What a fix should have said: the antenna's true time of validity, position and NED velocity."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    vel_ned_m_s: np.ndarray


def _block_truth(block: SensorBlock) -> Callable[[np.ndarray], Truth]:
    """Truth between a block's samples: linear in position, velocity and rate, slerp in attitude."""
    from scipy.spatial.transform import Rotation, Slerp   # here, not at the top: simulation/scenarios.py says why

    t = block.t_s
    q = block.truth_q_wxyz
    if np.any(np.diff(t) <= 0):
        raise ValueError("Times must be in strictly increasing order.")     # Slerp's own check, on every sample

    def truth_at(ts):
        ts = np.atleast_1d(np.asarray(ts, dtype=float))
        if ts.size and (ts.min() < t[0] or ts.max() > t[-1]):
            raise ValueError(f"truth asked for outside the block's {t[0]:.3f}–{t[-1]:.3f} s")

        def lin(a):
            return np.column_stack([np.interp(ts, t, a[:, i]) for i in range(a.shape[1])])

        # Slerp over the samples that bracket the times asked for, not over the whole block: Slerp interpolates
        # between the two samples around a time (index searchsorted(t, ts) − 1, the first sample's time counting
        # in the first interval), each interval from its own two rotations, so the same intervals give the same
        # rotations, whatever other samples there are
        ind = np.searchsorted(t, ts) - 1
        ind[ts == t[0]] = 0
        keep = np.unique(np.concatenate([ind, ind + 1])) if ts.size else np.array([0, 1])
        qk = q[keep]
        qi = Slerp(t[keep], Rotation.from_quat(np.column_stack([qk[:, 1:], qk[:, 0]])))(ts).as_quat()
        return Truth(ts, np.column_stack([qi[:, 3], qi[:, :3]]), lin(block.truth_gyro_rad_s),
                     lin(block.truth_vel_ned_m_s), np.interp(ts, t, block.truth_lat_deg),
                     np.interp(ts, t, block.truth_lon_deg), np.interp(ts, t, block.truth_alt_m))

    return truth_at


@functools.lru_cache(maxsize=4096)
def _spawned(seed) -> tuple[np.random.SeedSequence, ...]:
    return tuple(np.random.SeedSequence(seed).spawn(4))


def _seed_children(seed) -> tuple[np.random.SeedSequence, ...]:
    """The four SeedSequences of the noise streams of `seed`, made once per seed (a test makes hundreds of simulators
    with a few seeds): a generator seeded from one only reads its state, so they can be shared."""
    try:
        return _spawned(seed)
    except TypeError:                     # not hashable (a list of ints)
        return tuple(np.random.SeedSequence(seed).spawn(4))


def _as_outage(o) -> GnssOutage:
    return o if isinstance(o, GnssOutage) else GnssOutage(*o)


class GnssSimulator:
    """A receiver producing fixes epoch by epoch from `truth_at(t) -> Truth` (e.g. `SensorStream.truth_at`).

    `fixes_until(t)` returns the fixes with time of validity ≤ t not yet returned; `arrivals_until(t)` those
    whose arrival time ≤ t (for delivering them in real time, e.g. as UBX over a pseudo-terminal). Use one or
    the other on a given simulator. Epochs start at the first multiple of 1/rate_hz ≥ start_s.
    """

    def __init__(self, truth_at: Callable[[np.ndarray], Truth], rate_hz: float = 5.0, seed: int = 0,
                 errors: GnssErrors | None = None, latency_s: float = 0.1, jitter_s: float = 0.0,
                 lever_arm_m=(0.0, 0.0, 0.0), outages=(), glitches=(), start_s: float = 0.0):
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 50):
            raise ValueError(f"rate_hz must be in (0, 50], got {rate_hz!r}")
        if not (math.isfinite(latency_s) and latency_s >= 0):
            raise ValueError(f"latency_s must be ≥ 0, got {latency_s!r}")
        if not (math.isfinite(jitter_s) and 0 <= jitter_s < 1.0 / rate_hz):
            raise ValueError(f"jitter_s must be in [0, 1/rate_hz) so fixes arrive in order, got {jitter_s!r}")
        self.lever_arm_m = np.asarray(lever_arm_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(self.lever_arm_m)):
            raise ValueError("lever_arm_m must be finite")
        self._truth_at = truth_at
        self.rate_hz = float(rate_hz)
        self.errors = errors if errors is not None else GnssErrors()
        self.latency_s = float(latency_s)
        self.jitter_s = float(jitter_s)
        self.outages = tuple(_as_outage(o) for o in outages)
        self.glitches = tuple(glitches)
        for g in self.glitches:
            if not isinstance(g, GnssGlitch):
                raise TypeError(f"glitches must be GnssGlitch, got {type(g).__name__}")
        self._k = math.ceil(start_s * self.rate_hz - 1e-9)     # next epoch index
        rngs = [np.random.default_rng(s) for s in _seed_children(seed)]
        self._rng_white, self._rng_wander, self._rng_vel, self._rng_jitter = rngs
        e = self.errors
        sigma = np.array([e.horizontal_m, e.horizontal_m, e.vertical_m])
        self._sigma_white = sigma * math.sqrt(1.0 - e.wander_fraction)
        self._sigma_wander = sigma * math.sqrt(e.wander_fraction)
        self._phi = math.exp(-1.0 / (self.rate_hz * e.wander_tau_s))
        self._wander = self._rng_wander.standard_normal(3) * self._sigma_wander   # stationary start
        self._pending: list[GnssFix] = []

    # ----------------------------------------------------------------------------------------- epochs
    def fixes_until(self, t_s: float) -> list[GnssFix]:
        """Fixes (time of validity order) for the epochs up to `t_s` not yet produced."""
        k_last = math.floor(t_s * self.rate_hz + 1e-9)
        out = self._pending + self._epochs(self._k, k_last)
        self._pending = []
        return out

    def arrivals_until(self, t_rx_s: float) -> list[GnssFix]:
        """Fixes that have arrived by `t_rx_s` (arrival order), not yet returned."""
        self._pending += self._epochs(self._k, math.floor((t_rx_s - self.latency_s) * self.rate_hz + 1e-9))
        n = 0
        while n < len(self._pending) and self._pending[n].extra["t_rx_s"] <= t_rx_s:
            n += 1
        out, self._pending = self._pending[:n], self._pending[n:]
        return out

    def _epochs(self, k0: int, k1: int) -> list[GnssFix]:
        if k1 < k0:
            return []
        self._k = k1 + 1
        t = np.arange(k0, k1 + 1) / self.rate_hz
        n = len(t)
        truth = self._truth_at(t)
        lat, lon, alt, vel = self._antenna(truth)
        e = self.errors
        h_acc, v_acc, s_acc = e.reported
        # every epoch's draws at once, outage or not, so the noise at an epoch does not depend on the outages; a
        # Generator gives the same numbers for one (n, 3) draw as for n draws of 3 (the same stream, in order)
        white = self._rng_white.standard_normal((n, 3)) * self._sigma_white
        innovation = self._rng_wander.standard_normal((n, 3)) * self._sigma_wander * math.sqrt(1 - self._phi**2)
        dv = self._rng_vel.standard_normal((n, 3)) * e.velocity_m_s
        t_rx = (t + self.latency_s + self._rng_jitter.uniform(0.0, self.jitter_s, n)).tolist()
        phi, (w0, w1, w2) = self._phi, self._wander.tolist()
        wander = []
        for i0, i1, i2 in innovation.tolist():      # the Gauss–Markov recursion, epoch by epoch (in floats: the
            w0, w1, w2 = phi * w0 + i0, phi * w1 + i1, phi * w2 + i2   # same IEEE products and sums as numpy's)
            wander.append((w0, w1, w2))
        self._wander = np.array([w0, w1, w2])
        d_all = white + np.array(wander)
        v_all = vel + dv
        hit = [(g, *self._glitch_epochs(g)) for g in self.glitches]
        # Python floats from here: the same IEEE operations as on numpy scalars, without their per-call cost
        t_list = t.tolist()
        lat_l, lon_l, alt_l = np.asarray(lat).tolist(), np.asarray(lon).tolist(), np.asarray(alt).tolist()
        d_list = d_all.tolist()
        # each fix's own copy of its row: the rows of one copy of the array (a row view per fix, no other fix's)
        vel_rows, v_rows = list(np.array(vel, dtype=float)), list(np.array(v_all, dtype=float))
        fixes = []
        for i, tk in enumerate(t_list):
            outage = next((o for o in self.outages if o.start_s <= tk < o.stop_s), None) if self.outages else None
            truth_i = GnssTruth(tk, lat_l[i], lon_l[i], alt_l[i], vel_rows[i])
            if outage is not None:
                if outage.reports_no_fix:
                    fixes.append(GnssFix(tk, math.nan, math.nan, math.nan, np.full(3, math.nan),
                                         fix_type=GnssFixType.NO_FIX, num_sats=2, source="simulated",
                                         extra={"t_rx_s": t_rx[i], "glitch": None, "truth": truth_i}))
                continue
            d_ned = d_list[i]
            v_meas = v_rows[i]
            t_stamp = tk
            glitch = None
            for g, first, last in hit:
                if not first <= k0 + i <= last:
                    continue
                glitch = g.kind
                u = np.array([math.cos(math.radians(g.direction_deg)), math.sin(math.radians(g.direction_deg)), 0.0])
                if g.kind == "position_jump":
                    d_ned = (np.array(d_ned) + g.size * u).tolist()
                elif g.kind == "velocity_spike":
                    v_meas = v_meas + g.size * u
                elif g.kind == "time_backwards":
                    t_stamp = tk - g.size
            d_n, d_e, d_d = d_ned
            r = EARTH_RADIUS_M + alt_l[i]
            lat_m = lat_l[i] + math.degrees(d_n / r)
            lon_m = lon_l[i] + math.degrees(d_e / (r * math.cos(math.radians(lat_l[i]))))
            alt_m = alt_l[i] - d_d
            if glitch == "nan":
                lat_m = lon_m = alt_m = math.nan
                v_meas = np.full(3, math.nan)
            fixes.append(GnssFix(t_stamp, lat_m, lon_m, alt_m, v_meas, h_acc_m=h_acc,
                                 v_acc_m=v_acc, s_acc_m_s=s_acc, fix_type=GnssFixType.FIX_3D, num_sats=e.num_sats,
                                 source="simulated", extra={"t_rx_s": t_rx[i], "glitch": glitch,
                                                            "truth": truth_i}))
        return fixes

    def _glitch_epochs(self, g: GnssGlitch) -> tuple[int, int]:
        """The first and last epoch index a glitch applies to."""
        first = math.ceil(g.t_s * self.rate_hz - 1e-9)
        return first, max(first, math.floor((g.t_s + g.duration_s) * self.rate_hz + 1e-9))

    def _antenna(self, truth: Truth):
        """The antenna's geodetic position and NED velocity from the IMU's truth and the lever arm."""
        lat, lon, alt, vel = truth.lat_deg, truth.lon_deg, truth.alt_m, truth.vel_ned_m_s
        if not np.any(self.lever_arm_m):
            return lat, lon, alt, vel
        from scipy.spatial.transform import Rotation

        q = truth.q_wxyz
        c_bn = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, 0]]))
        arm_ned = c_bn.apply(self.lever_arm_m)
        vel = vel + c_bn.apply(np.cross(truth.rate_rad_s, self.lever_arm_m))
        r = EARTH_RADIUS_M + alt
        return (lat + np.degrees(arm_ned[:, 0] / r), lon + np.degrees(arm_ned[:, 1] / (r * np.cos(np.radians(lat)))),
                alt - arm_ned[:, 2], vel)


def simulate_gnss(source: SensorBlock | SensorStream, rate_hz: float = 5.0, seed: int = 0, outages=(),
                  glitches=(), *, errors: GnssErrors | None = None, latency_s: float = 0.1, jitter_s: float = 0.0,
                  lever_arm_m=(0.0, 0.0, 0.0), start_s: float | None = None,
                  stop_s: float | None = None) -> list[GnssFix]:
    """The fixes a receiver would produce over a block's time span (truth interpolated between its samples) or
    over [start_s, stop_s] of a stream (exact truth; default: the samples the stream has emitted so far).
    Fixes are in time-of-validity order; see `GnssSimulator` for the parameters."""
    if isinstance(source, SensorBlock):
        if len(source) < 2:
            raise ValueError("simulate_gnss needs a block of at least 2 samples")
        truth_at = _block_truth(source)
        lo, hi = float(source.t_s[0]), float(source.t_s[-1])
    elif isinstance(source, SensorStream):
        truth_at = source.truth_at
        lo = source.start_s
        hi = source.start_s + (source.samples_emitted - 1) / source.rate_hz
        if stop_s is None and source.samples_emitted == 0:
            raise ValueError("simulate_gnss(stream): the stream has emitted nothing; pass stop_s")
    else:
        raise TypeError(f"source must be a SensorBlock or a SensorStream, got {type(source).__name__}")
    lo = lo if start_s is None else float(start_s)
    hi = hi if stop_s is None else float(stop_s)
    sim = GnssSimulator(truth_at, rate_hz, seed, errors, latency_s, jitter_s, lever_arm_m, outages, glitches,
                        start_s=lo)
    return sim.fixes_until(hi)


_END = object()     # an iterator's end (next's default)


def in_arrival_order(samples, fixes) -> Iterator[ImuSample | GnssFix]:
    """IMU samples (a SensorBlock or an iterable of ImuSample) and fixes merged in the order they arrive: a
    sample at its t_s, a fix at extra["t_rx_s"] (its t_s when absent); at equal times the fix comes first (a fix
    that has arrived by a sample's time is there for it, as estimator.fix_feed offers one by its time of
    validity)."""
    imu = iter(samples.samples() if isinstance(samples, SensorBlock) else samples)
    arrival = sorted(((f.extra.get("t_rx_s", f.t_s), i) for i, f in enumerate(fixes)))
    fixes = list(fixes)
    queue = [(t, fixes[i]) for t, i in arrival]
    # heapq.merge of the keys (t_s, 1, index, sample) and (t, 0, index, fix), written out for its two inputs: the
    # same comparisons in the same order, NaN times included ((t, 0/1) compares as the keys do: they differ at
    # the latest in that second place). The head stays with the input just advanced while its new key is below
    # the other's head; an input that ends leaves the rest of the other.
    n_fix, k = len(queue), 0
    s = next(imu, _END)
    if s is _END or not n_fix:
        yield from (f for _, f in queue) if s is _END else itertools.chain((s,), imu)
        return
    sample_next = (s.t_s, 1) < (queue[0][0], 0)
    while True:
        if sample_next:
            yield s
            s = next(imu, _END)
            if s is _END:
                yield from (f for _, f in queue[k:])
                return
            sample_next = (s.t_s, 1) < (queue[k][0], 0)
        else:
            yield queue[k][1]
            k += 1
            if k == n_fix:
                yield s
                yield from imu
                return
            sample_next = not (queue[k][0], 0) < (s.t_s, 1)
