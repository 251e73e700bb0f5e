"""ArduPilot's 80-section geodesic grid over the sphere and the MAG_CAL_PROGRESS completion mask built on it.

Same triangles, vertex order and sub-triangle numbering as ArduPilot's libraries/AP_Math/AP_GeodesicGrid.cpp,
so a ground station that draws our completion_mask draws the same cells it draws for an autopilot:
section = 4 · icosahedron_triangle + sub_triangle; sub-triangle 0 is the middle one.
"""

from __future__ import annotations

import math

import numpy as np

COMPLETION_MASK_BYTES = 10              # MAG_CAL_PROGRESS.completion_mask: 80 sections, one bit each

_G = (1.0 + math.sqrt(5.0)) / 2.0  # M_GOLDEN
_TRIANGLES_HALF = np.array(
    [
        [[-_G, 1, 0], [-1, 0, -_G], [-_G, -1, 0]],
        [[-1, 0, -_G], [-_G, -1, 0], [0, -_G, -1]],
        [[-_G, -1, 0], [0, -_G, -1], [0, -_G, 1]],
        [[-1, 0, -_G], [0, -_G, -1], [1, 0, -_G]],
        [[0, -_G, -1], [0, -_G, 1], [_G, -1, 0]],
        [[0, -_G, -1], [1, 0, -_G], [_G, -1, 0]],
        [[_G, -1, 0], [1, 0, -_G], [_G, 1, 0]],
        [[1, 0, -_G], [_G, 1, 0], [0, _G, -1]],
        [[1, 0, -_G], [0, _G, -1], [-1, 0, -_G]],
        [[0, _G, -1], [-_G, 1, 0], [-1, 0, -_G]],
    ],
    dtype=np.float64,
)
GEODESIC_TRIANGLES = np.concatenate([_TRIANGLES_HALF, -_TRIANGLES_HALF])          # (20, 3 vertices, 3)
GEODESIC_MID_TRIANGLES = np.stack(
    [
        (GEODESIC_TRIANGLES[:, 0] + GEODESIC_TRIANGLES[:, 1]) / 2,
        (GEODESIC_TRIANGLES[:, 1] + GEODESIC_TRIANGLES[:, 2]) / 2,
        (GEODESIC_TRIANGLES[:, 2] + GEODESIC_TRIANGLES[:, 0]) / 2,
    ],
    axis=1,
)
# Inverse of the matrix whose columns are the vertices: w = inv · v gives v's coefficients on the vertices.
_TRI_INV = np.linalg.inv(np.transpose(GEODESIC_TRIANGLES, (0, 2, 1)))
_MID_INV = np.linalg.inv(np.transpose(GEODESIC_MID_TRIANGLES, (0, 2, 1)))
N_SECTIONS = 80


def geodesic_sections(vectors: np.ndarray) -> np.ndarray:
    """AP_GeodesicGrid::section(v, inclusive=true) for each row of `vectors` (n, 3): 0..79, −1 for a zero
    or non-finite vector."""
    v = np.atleast_2d(np.asarray(vectors, dtype=np.float64))
    out = np.full(v.shape[0], -1, dtype=np.int64)
    good = np.all(np.isfinite(v), axis=1) & (np.linalg.norm(v, axis=1) > 0)
    if not np.any(good):
        return out
    vg = v[good]
    w = np.einsum("tij,nj->nti", _TRI_INV, vg)              # (n, 20, 3) coefficients on each triangle
    tri = np.argmax(w.min(axis=2) >= -1e-9 * np.linalg.norm(vg, axis=1)[:, None], axis=1)
    wm = np.einsum("nij,nj->ni", _MID_INV[tri], vg)          # coefficients on the middle triangle
    eps = 1e-12 * np.linalg.norm(vg, axis=1)               # relative, as above: a section is a direction
    sub = np.where(wm[:, 0] < -eps, 3, np.where(wm[:, 1] < -eps, 1, np.where(wm[:, 2] < -eps, 2, 0)))
    out[good] = 4 * tri + sub
    return out


_TRI_INV_ROWS = np.ascontiguousarray(_TRI_INV.reshape(60, 3))      # row 3·t + i: vertex i of triangle t


def geodesic_section(vector) -> int:
    """geodesic_sections of one vector (3,), the field session's per-sample call: the same rule on one matrix
    product, without the batch's (n, 20, 3) set-up."""
    v = np.asarray(vector, dtype=np.float64).reshape(3)
    x, y, z = v.tolist()
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return -1
    norm = math.sqrt(x * x + y * y + z * z)
    if not norm > 0:
        return -1
    inside = (_TRI_INV_ROWS @ v).reshape(20, 3).min(axis=1) >= -1e-9 * norm
    tri = int(np.argmax(inside))
    wm0, wm1, wm2 = (_MID_INV[tri] @ v).tolist()
    eps = 1e-12 * norm
    sub = 3 if wm0 < -eps else 1 if wm1 < -eps else 2 if wm2 < -eps else 0
    return 4 * tri + sub


def section_centres() -> np.ndarray:
    """Unit vector through the centroid of each of the 80 sections (80, 3)."""
    t, m = GEODESIC_TRIANGLES, GEODESIC_MID_TRIANGLES
    corners = [
        (m[:, 0], m[:, 1], m[:, 2]),
        (t[:, 0], m[:, 0], m[:, 2]),
        (m[:, 0], t[:, 1], m[:, 1]),
        (m[:, 2], m[:, 1], t[:, 2]),
    ]
    c = np.empty((20, 4, 3))
    for j, (a, b, cc) in enumerate(corners):
        c[:, j] = (a + b + cc) / 3
    c = c.reshape(80, 3)
    return c / np.linalg.norm(c, axis=1, keepdims=True)


def completion_mask_bytes(sections_hit: np.ndarray) -> bytes:
    """The 10-byte MAG_CAL_PROGRESS.completion_mask: bit (s % 8) of byte (s // 8) set for each section s
    (CompassCalibrator::update_completion_mask)."""
    mask = bytearray(COMPLETION_MASK_BYTES)
    for s in np.unique(np.asarray(sections_hit, dtype=np.int64)):
        if 0 <= s < N_SECTIONS:
            mask[s // 8] |= 1 << (s % 8)
    return bytes(mask)
