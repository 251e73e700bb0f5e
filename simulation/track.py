"""Where the vehicle is: its NED velocity integrated into geodetic position on a spherical Earth.

    L̇ = V_N/(R+h),   λ̇ = V_E/((R+h) cos L),   ḣ = −V_D          Groves 2nd ed. §5.4, R = R0 = 6 378 137 m

from the site at t = 0. The three rates are integrated one after the other (h needs only V_D, L needs h, λ needs
L and h) on a fixed grid of `STEP_S` with 3-point Gauss–Legendre quadrature per step (exact for polynomials of
degree 5), and read between grid nodes by cubic Hermite interpolation with the exact rates at the nodes, so the
position at any time is accurate to far below a millimetre and does not depend on which times are asked for (a
stream cut into blocks of any size, at any rate, gets the same track). The grid is built lazily in fixed
chunks; only a few chunks are kept, and an evicted chunk is rebuilt from its stored start state, so an endless
stream needs bounded memory.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable

import numpy as np

from ahrsd.core.gravity import EARTH_RADIUS_M
from ahrsd.simulation.value_key import value_key

STEP_S = 0.05                     # grid step: velocity features are ≥ 1 s long, so Hermite error ≪ 1 µm
CHUNK_STEPS = 12_000              # 600 s per chunk
KEPT_CHUNKS = 4
SHARED_CHUNKS = 16                # chunks kept for other tracks of the same vehicle from the same place
_GAUSS_X = np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])       # Gauss–Legendre nodes on [-1, 1]
_GAUSS_W = np.array([5.0, 8.0, 5.0]) / 9.0


def _hermite(y0, y1, d0, d1, h, u):
    """Cubic Hermite on one step of length h, at the fraction u ∈ [0, 1] (value and slope at both ends)."""
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * y0 + (u3 - 2 * u2 + u) * h * d0 + (-2 * u3 + 3 * u2) * y1
            + (u3 - u2) * h * d1)


# chunks by what they are a function of (GeodeticTrack._shared_key), oldest first: every stream of the same vehicle
# from the same site integrates the same track (a test opens one per seed)
_SHARED: OrderedDict = OrderedDict()
_SHARED_LOCK = threading.Lock()


class GeodeticTrack:
    """Geodetic position (lat/lon in degrees, height in m) of a vehicle whose NED velocity is
    `velocity_ned_m_s(t)`, starting at (lat0_deg, lon0_deg, alt0_m) at t = 0. `position(t)` works for any t ≥ 0
    in any order. The integral is kept as an offset from the start, so a vehicle at rest is exactly at the site."""

    def __init__(self, velocity_ned_m_s: Callable[[np.ndarray], np.ndarray], lat0_deg: float, lon0_deg: float,
                 alt0_m: float):
        self._velocity = velocity_ned_m_s
        self._lat0_deg, self._lon0_deg = float(lat0_deg), float(lon0_deg)
        self._lat0 = np.radians(self._lat0_deg)
        self._start_states = [np.array([0.0, 0.0, float(alt0_m)])]    # (Δlat rad, Δlon rad, h m)
        self._chunks: dict[int, tuple[np.ndarray, np.ndarray]] = {}   # j -> (states (M+1,3), rates (M+1,3))

    def _rates(self, v, lat, h):
        r = EARTH_RADIUS_M + h
        return np.column_stack([v[:, 0] / r, v[:, 1] / (r * np.cos(lat)), -v[:, 2]])   # eq. 17

    def _build(self, j: int):
        """Chunk j from its start state (requires the start state, i.e. chunk j−1 built once): integrated, or taken
        from a track built before from the same start by a vehicle whose state has the same value (`_shared`)."""
        key = self._shared_key(j)
        with _SHARED_LOCK:                     # streams may be read from several threads
            built = _SHARED.get(key) if key is not None else None
            if built is not None:
                _SHARED.move_to_end(key)
        if built is None:
            built = self._integrate(j)
            if key is not None:
                with _SHARED_LOCK:
                    _SHARED[key] = built
                    while len(_SHARED) > SHARED_CHUNKS:
                        _SHARED.popitem(last=False)
        states, rates = built
        if len(self._start_states) == j + 1:
            self._start_states.append(states[-1].copy())
        if len(self._chunks) >= KEPT_CHUNKS:
            self._chunks.pop(next(iter(self._chunks)))   # the oldest built
        self._chunks[j] = (states, rates)

    def _shared_key(self, j: int):
        """What chunk j is a function of: the velocity's object by value and its function (a bound method; anything
        else is not shared), the start and the grid. None: not shared."""
        velocity = self._velocity
        owner, func = getattr(velocity, "__self__", None), getattr(velocity, "__func__", None)
        if owner is None or func is None:
            return None
        owner_key = value_key(owner)
        if owner_key is None:
            return None
        return (func, owner_key, self._lat0_deg, self._lat0.tobytes(), self._start_states[j].tobytes(), j, STEP_S,
                CHUNK_STEPS, EARTH_RADIUS_M)

    def _integrate(self, j: int):
        """Integrate chunk j from its start state: (states (M+1,3), rates (M+1,3)), read-only."""
        m, h_step = CHUNK_STEPS, STEP_S
        k = j * m + np.arange(m + 1)
        t_nodes = k * h_step
        t_gauss = (t_nodes[:-1, None] + 0.5 * h_step * (1.0 + _GAUSS_X)[None, :]).ravel()
        v_nodes = self._velocity(t_nodes)
        v_gauss = self._velocity(t_gauss).reshape(m, 3, 3)
        lat0, lon0, h0 = self._start_states[j]
        u = 0.5 * (1.0 + _GAUSS_X)[None, :]
        half = 0.5 * h_step

        def integrate(y0, rate_nodes, rate_gauss):
            """Nodes of y = y0 + ∫ rate, and y at the Gauss points by Hermite from the nodes."""
            steps = half * (rate_gauss * _GAUSS_W[None, :]).sum(axis=1)
            y = y0 + np.concatenate(([0.0], np.cumsum(steps)))
            y_g = _hermite(y[:-1, None], y[1:, None], rate_nodes[:-1, None], rate_nodes[1:, None], h_step, u)
            return y, y_g

        hgt, hgt_g = integrate(h0, -v_nodes[:, 2], -v_gauss[:, :, 2])
        r_nodes, r_gauss = EARTH_RADIUS_M + hgt, EARTH_RADIUS_M + hgt_g
        dlat, dlat_g = integrate(lat0, v_nodes[:, 0] / r_nodes, v_gauss[:, :, 0] / r_gauss)
        lat, lat_g = self._lat0 + dlat, self._lat0 + dlat_g
        dlon, _ = integrate(lon0, v_nodes[:, 1] / (r_nodes * np.cos(lat)), v_gauss[:, :, 1] / (r_gauss * np.cos(lat_g)))
        states, rates = np.column_stack([dlat, dlon, hgt]), self._rates(v_nodes, lat, hgt)
        states.flags.writeable = rates.flags.writeable = False       # shared between tracks
        return states, rates

    def _chunk(self, j: int):
        if j not in self._chunks:
            for i in range(len(self._start_states) - 1, j):   # start states up to j
                self._build(i)
            self._build(j)
        return self._chunks[j]

    def position(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lat_deg, lon_deg, alt_m) arrays at the times `t_s` (s, ≥ 0)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if t.size and not (np.all(np.isfinite(t)) and t.min() >= 0.0):
            raise ValueError("track position needs finite times t ≥ 0")
        out = np.empty((len(t), 3))
        step = np.floor(t / STEP_S).astype(np.int64)
        chunk = step // CHUNK_STEPS
        for j in np.unique(chunk):
            sel = chunk == j
            states, rates = self._chunk(int(j))
            i = step[sel] - j * CHUNK_STEPS
            u = (t[sel] - step[sel] * STEP_S) / STEP_S
            out[sel] = _hermite(states[i], states[i + 1], rates[i], rates[i + 1], STEP_S, u[:, None])
        return self._lat0_deg + np.degrees(out[:, 0]), self._lon0_deg + np.degrees(out[:, 1]), out[:, 2]
