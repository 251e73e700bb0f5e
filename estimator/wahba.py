"""Wahba's problem: the rotation that best maps body-frame vectors onto their reference-frame counterparts.

Wahba (1965, SIAM Review 7(3); Markley & Crassidis, "Fundamentals of Spacecraft Attitude Determination
and Control", 2014, ch. 5): find C minimising J(C) = ½ Σ kᵢ ‖rᵢ − C bᵢ‖², ‖rᵢ‖ = ‖bᵢ‖ = 1, Σ kᵢ = 1.

Every solver has one signature::

    solver(body_vectors (N, 3), reference_vectors (N, 3), weights (N,) | None) -> WahbaSolution

and returns the rotation **body → reference** (C_b^n when the reference is NED) as a scalar-first quaternion.
Vectors are normalised to unit length before solving (Wahba's problem is posed on unit vectors; it also
makes the thesis's formulas independent of the units of g and H0). ``weights`` are the inverse variances 1/σᵢ² (σᵢ in rad,
the direction noise of vector i); they set the loss weights kᵢ (normalised to Σ kᵢ = 1) and the scale of the
covariance. The algebraic methods (thesis, TRIAD) ignore weights when solving; the loss and covariance are
still evaluated with them so every method is judged on the same scale.

Methods (``SOLVERS``, by name):

* ``three-vector`` — the thesis's inversion ("version 1"): stack three vectors in each frame and
  invert the reference matrix, C_n^b = B N⁻¹. Given two vectors (m, f) the third is f × m, as the thesis does.
  Given more than three, the weighted least-squares generalisation C_n^b = B K Nᵀ (N K Nᵀ)⁻¹. The raw C is not
  orthonormal with noisy data; the thesis's C ← 1.5C − 0.5CCᵀC is iterated to convergence.
* ``thesis-v2`` — "version 2": B = [m, f×m, (f×m)×m], N likewise, C_n^b = B N⁻¹, then re-orthonormalised.
  Anchors on the first vector (the magnetometer in the thesis). After re-orthonormalisation it is exactly
  TRIAD anchored on the first vector (the column scales sin∠ cancel in the polar factor).
* ``triad-first`` / ``triad-second`` (``triad`` = ``triad-first``) — TRIAD with the first or second vector as
  the anchor; uses the first two vectors.
* ``svd`` — Markley (1988): C = U diag(1, 1, det U det V) Vᵀ from B = Σ kᵢ rᵢ bᵢᵀ = U S Vᵀ. The optimal solution.
* ``davenport`` — Davenport's q-method: the eigenvector of the largest eigenvalue of the 4×4 K matrix.
* ``quest`` — Shuster's QUEST: Newton iteration on K's characteristic polynomial from λ₀ = Σkᵢ, then the Gibbs
  vector; sequential 180° rotations of the reference frame avoid the singularity at 180°.

Quality (every method): ``loss`` = J(C) with kᵢ normalised to Σ kᵢ = 1 (0 for a perfect fit); ``covariance`` =
the 3×3 Cramér–Rao covariance of the small rotation error φ (C_true = exp([φ×]) C, φ in the reference frame),
(Σ wᵢ (I − ĉᵢ ĉᵢᵀ))⁻¹ with ĉᵢ = C bᵢ — in rad² when the weights are 1/σᵢ² in 1/rad².
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .rotations import dcm_to_quat, orthonormality_error, quat_to_dcm, quat_multiply, quat_normalize, reorthonormalize

# Below this |sin| of the angle between the two anchor vectors the problem has no unique solution.
_MIN_SIN_ANGLE = 1e-9


class WahbaError(ValueError):
    """Bad input: wrong shapes, non-finite values, zero-length or collinear vectors."""


@dataclass(frozen=True, slots=True)
class WahbaSolution:
    """Rotation body → reference and its quality.

    q_wxyz: unit quaternion, scalar first, w ≥ 0 (rotates body vectors into the reference frame).
    dcm: the orthonormal C (3, 3) of q_wxyz (C_b^n for an NED reference).
    loss: Wahba loss J (dimensionless, weights normalised to sum 1; 0 = perfect fit).
    covariance: (3, 3) covariance of the rotation error (rad² for weights = 1/σ² in 1/rad²); inf if unobservable.
    method: the solver's registry name.
    dcm_raw: the matrix the method produced before any re-orthonormalisation (thesis methods only: their raw
      C is not orthonormal with noisy data; `orthonormality_error(dcm_raw)` measures by how much).
    """

    q_wxyz: np.ndarray
    dcm: np.ndarray
    loss: float
    covariance: np.ndarray
    method: str
    dcm_raw: np.ndarray | None = None


# ------------------------------------------------------------------------------------------- helpers
def _unit_rows(v, norms):
    """The rows of v (N, 3) over their norms (N,): the unit vectors every solver works on."""
    return v / norms[:, None]


def _prepare(body_vectors, reference_vectors, weights, min_vectors: int = 2):
    b = np.asarray(body_vectors, dtype=np.float64)
    r = np.asarray(reference_vectors, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3 or r.shape != b.shape:
        raise WahbaError(f"need body and reference vectors of equal shape (N, 3); got {b.shape} and {r.shape}")
    n = b.shape[0]
    if n < min_vectors:
        raise WahbaError(f"this method needs at least {min_vectors} vector pairs, got {n}")
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (n,):
        raise WahbaError(f"need {n} weights, got shape {w.shape}")
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(r)) and np.all(np.isfinite(w))):
        raise WahbaError("vectors and weights must be finite")
    if np.any(w < 0) or not np.any(w > 0):
        raise WahbaError("weights must be non-negative and not all zero")
    nb = np.linalg.norm(b, axis=1)
    nr = np.linalg.norm(r, axis=1)
    if np.any(nb == 0) or np.any(nr == 0):
        raise WahbaError("zero-length vector")
    b = _unit_rows(b, nb)
    r = _unit_rows(r, nr)
    for v, frame in ((b, "body"), (r, "reference")):
        if np.max(np.linalg.norm(np.cross(v[0], v), axis=1)) < _MIN_SIN_ANGLE:
            raise WahbaError(f"{frame} vectors are collinear: the rotation about them is unobservable")
    return b, r, w


def wahba_loss(dcm, body_unit, reference_unit, weights) -> float:
    """J(C) = ½ Σ kᵢ ‖rᵢ − C bᵢ‖² with kᵢ = wᵢ / Σw (unit vectors)."""
    k = weights / np.sum(weights)
    resid = reference_unit - body_unit @ np.asarray(dcm).T
    return float(0.5 * np.sum(k * np.sum(resid * resid, axis=1)))


def attitude_covariance(dcm, body_unit, weights) -> np.ndarray:
    """(Σ wᵢ (I − ĉᵢĉᵢᵀ))⁻¹ with ĉᵢ = C bᵢ: covariance of the rotation error in the reference frame."""
    c = body_unit @ np.asarray(dcm).T
    info = np.sum(weights) * np.eye(3) - (c * weights[:, None]).T @ c
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.full((3, 3), np.inf)
    if not np.all(np.isfinite(cov)) or np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) <= 0:
        return np.full((3, 3), np.inf)
    return 0.5 * (cov + cov.T)


def _solution(method, dcm, b, r, w, dcm_raw=None) -> WahbaSolution:
    q = dcm_to_quat(dcm)
    c = quat_to_dcm(q)
    return WahbaSolution(q, c, wahba_loss(c, b, r, w), attitude_covariance(c, b, w), method, dcm_raw)


def profile_matrix(body_unit, reference_unit, weights) -> np.ndarray:
    """Attitude profile matrix B = Σ kᵢ rᵢ bᵢᵀ (maximise tr(C Bᵀ))."""
    return (reference_unit * weights[:, None]).T @ body_unit


def polar_reorthonormalize(c, tol: float = 1e-13, max_iterations: int = 50) -> np.ndarray:
    """Iterate C ← 1.5C − 0.5CCᵀC until orthonormal; the SVD polar factor if that does not converge."""
    for _ in range(max_iterations):
        if orthonormality_error(c) < tol:
            break
        c = reorthonormalize(c)
    if not (np.all(np.isfinite(c)) and orthonormality_error(c) < 1e-9):
        u, _, vt = np.linalg.svd(c)
        c = u @ vt
    if np.linalg.det(c) < 0:
        raise WahbaError("the vectors define a reflection, not a rotation (mismatched handedness)")
    return c


# ----------------------------------------------------------------------------------- thesis (versions 1, 2)
def thesis_matrix(v0, v1, version: int) -> np.ndarray:
    """The 3×3 matrix of column vectors the thesis builds from its two vectors (m, f) in one frame.

    version 1: [m, f, f×m]; version 2: [m, f×m, (f×m)×m].
    """
    a0, a1, a2 = np.asarray(v0, dtype=np.float64).tolist()
    b0, b1, b2 = np.asarray(v1, dtype=np.float64).tolist()
    return thesis_matrix_from_floats(a0, a1, a2, b0, b1, b2, version)


def thesis_matrix_from_floats(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float,
                              version: int) -> np.ndarray:
    """`thesis_matrix` on the components of v0 = (a0, a1, a2), v1 = (b0, b1, b2) (scalar maths: the thesis
    filter calls this every sample)."""
    c0, c1, c2 = b1 * a2 - b2 * a1, b2 * a0 - b0 * a2, b0 * a1 - b1 * a0  # v1 × v0 (f × m)
    if version == 1:
        return np.array(((a0, b0, c0), (a1, b1, c1), (a2, b2, c2)))
    if version == 2:
        d0, d1, d2 = c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0  # (f × m) × m
        return np.array(((a0, c0, d0), (a1, c1, d1), (a2, c2, d2)))
    raise ValueError("thesis Wahba version is 1 or 2")


def thesis_dcm_body_to_ref(body0, body1, reference_matrix_inverse, version: int) -> np.ndarray:
    """C_b^n = (B_b N_n⁻¹)ᵀ with the reference matrix inverse precomputed (it is constant)."""
    a0, a1, a2 = np.asarray(body0, dtype=np.float64).tolist()
    b0, b1, b2 = np.asarray(body1, dtype=np.float64).tolist()
    n_inv_t = np.asarray(reference_matrix_inverse, dtype=np.float64).T.tolist()
    return np.array(thesis_dcm_from_floats(a0, a1, a2, b0, b1, b2, n_inv_t, version))


def thesis_dcm_from_floats(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float, n_inv_t,
                           version: int):
    """`thesis_dcm_body_to_ref` in scalar maths (the thesis filter calls it every sample): body vectors
    v0 = (a0, a1, a2) (m), v1 = (b0, b1, b2) (f), `n_inv_t` = (N_n⁻¹)ᵀ as three rows; returns C_b^n = N_n⁻ᵀ B_bᵀ
    as three row tuples (not re-orthonormalised)."""
    c0, c1, c2 = b1 * a2 - b2 * a1, b2 * a0 - b0 * a2, b0 * a1 - b1 * a0  # f × m
    if version == 1:
        r0, r1, r2 = (a0, a1, a2), (b0, b1, b2), (c0, c1, c2)          # rows of B_bᵀ: m, f, f×m
    elif version == 2:
        d0, d1, d2 = c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0
        r0, r1, r2 = (a0, a1, a2), (c0, c1, c2), (d0, d1, d2)          # m, f×m, (f×m)×m
    else:
        raise ValueError("thesis Wahba version is 1 or 2")
    out = []
    for n0, n1, n2 in n_inv_t:
        out.append((n0 * r0[0] + n1 * r1[0] + n2 * r2[0],
                    n0 * r0[1] + n1 * r1[1] + n2 * r2[1],
                    n0 * r0[2] + n1 * r1[2] + n2 * r2[2]))
    return tuple(out)


def three_vector(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """Thesis version 1: invert the stacked reference vectors (two vectors: append f × m)."""
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    if len(b) == 2:
        raw = thesis_dcm_body_to_ref(b[0], b[1], np.linalg.inv(thesis_matrix(r[0], r[1], 1)), 1)
    else:
        # C_n^b N = B in the weighted least-squares sense: C_n^b = B K Nᵀ (N K Nᵀ)⁻¹, then transpose.
        nk = r.T * w
        try:
            cnb = (b.T * w) @ r @ np.linalg.inv(nk @ r)
        except np.linalg.LinAlgError as exc:
            raise WahbaError("reference vectors are coplanar: the three-vector inversion needs three "
                             "independent vectors (or exactly two)") from exc
        raw = cnb.T
    if not np.all(np.isfinite(raw)):
        raise WahbaError("singular reference matrix")
    return _solution("three-vector", polar_reorthonormalize(raw), b, r, w, dcm_raw=raw)


def thesis_v2(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """Thesis version 2 ([m, f×m, (f×m)×m]), anchored on the first vector; uses the first two vectors."""
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    raw = thesis_dcm_body_to_ref(b[0], b[1], np.linalg.inv(thesis_matrix(r[0], r[1], 2)), 2)
    return _solution("thesis-v2", polar_reorthonormalize(raw), b, r, w, dcm_raw=raw)


# ------------------------------------------------------------------------------------------------ TRIAD
def _triad_frame(anchor, other) -> np.ndarray:
    t2 = np.cross(anchor, other)
    t2 = t2 / np.linalg.norm(t2)
    return np.column_stack((anchor, t2, np.cross(anchor, t2)))


def _triad(body_vectors, reference_vectors, weights, anchor: int, name: str) -> WahbaSolution:
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    if np.linalg.norm(np.cross(b[0], b[1])) < _MIN_SIN_ANGLE or np.linalg.norm(np.cross(r[0], r[1])) < _MIN_SIN_ANGLE:
        raise WahbaError("TRIAD needs its first two vectors not collinear")
    other = 1 - anchor
    c = _triad_frame(r[anchor], r[other]) @ _triad_frame(b[anchor], b[other]).T
    return _solution(name, c, b, r, w)


def triad_first(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """TRIAD anchored on the first vector (matched exactly), second vector fixes the rotation about it."""
    return _triad(body_vectors, reference_vectors, weights, 0, "triad-first")


def triad_second(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """TRIAD anchored on the second vector."""
    return _triad(body_vectors, reference_vectors, weights, 1, "triad-second")


# ------------------------------------------------------------------------------------ optimal solvers
def svd(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """Markley's SVD solution (1988): the global minimiser of J."""
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    u, _, vt = np.linalg.svd(profile_matrix(b, r, w))
    d = np.linalg.det(u) * np.linalg.det(vt)
    c = (u * np.array([1.0, 1.0, d])) @ vt
    return _solution("svd", c, b, r, w)


def davenport_k(profile) -> np.ndarray:
    """Davenport's K (4×4, order w, x, y, z) with qᵀKq = tr(C(q) Bᵀ) for C(q) body → reference."""
    bm = np.asarray(profile)
    sigma = np.trace(bm)
    z = np.array([bm[2, 1] - bm[1, 2], bm[0, 2] - bm[2, 0], bm[1, 0] - bm[0, 1]])
    k = np.empty((4, 4))
    k[0, 0] = sigma
    k[0, 1:] = z
    k[1:, 0] = z
    k[1:, 1:] = bm + bm.T - sigma * np.eye(3)
    return k


def _davenport_dcm(b, r, w) -> np.ndarray:
    """C of the eigenvector of K's largest eigenvalue (unit vectors b, r; weights w)."""
    _, vecs = np.linalg.eigh(davenport_k(profile_matrix(b, r, w)))
    return quat_to_dcm(quat_normalize(vecs[:, -1]))


def davenport(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """Davenport's q-method: q = eigenvector of K's largest eigenvalue."""
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    return _solution("davenport", _davenport_dcm(b, r, w), b, r, w)


def davenport_q(body_vectors, reference_vectors, weights) -> np.ndarray:
    """`davenport(...).q_wxyz` bit for bit, and nothing else: for a caller that has already made sure its
    vectors are finite, non-zero and not collinear and its weights positive (a filter's initialisation,
    initial_attitude.py, once per start), so none of `_prepare`'s checks and neither the loss nor the
    covariance is computed. body_vectors, reference_vectors: (N, 3) float64; weights: (N,) float64."""
    b = _unit_rows(body_vectors, np.linalg.norm(body_vectors, axis=1))
    r = _unit_rows(reference_vectors, np.linalg.norm(reference_vectors, axis=1))
    return dcm_to_quat(_davenport_dcm(b, r, weights))


_FLIPS = (  # 180° rotations of the reference frame for QUEST's method of sequential rotations (Shuster 1981)
    (np.array([1.0, 0.0, 0.0, 0.0]), np.diag([1.0, 1.0, 1.0])),
    (np.array([0.0, 1.0, 0.0, 0.0]), np.diag([1.0, -1.0, -1.0])),
    (np.array([0.0, 0.0, 1.0, 0.0]), np.diag([-1.0, 1.0, -1.0])),
    (np.array([0.0, 0.0, 0.0, 1.0]), np.diag([-1.0, -1.0, 1.0])),
)


def _quest_lambda_max(bm, lam0: float) -> float:
    """Largest eigenvalue of K by Newton's method on the characteristic polynomial (Shuster & Oh 1981)."""
    s = bm + bm.T
    sigma = np.trace(bm)
    z = np.array([bm[2, 1] - bm[1, 2], bm[0, 2] - bm[2, 0], bm[1, 0] - bm[0, 1]])
    kappa = (s[1, 1] * s[2, 2] - s[1, 2] * s[2, 1] + s[0, 0] * s[2, 2] - s[0, 2] * s[2, 0]
             + s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0])  # tr(adj S)
    delta = np.linalg.det(s)
    a = sigma * sigma - kappa
    bb = sigma * sigma + z @ z
    c = delta + z @ s @ z
    d = z @ s @ s @ z
    lam = lam0
    for _ in range(50):
        f = lam**4 - (a + bb) * lam**2 - c * lam + (a * bb + c * sigma - d)
        fp = 4 * lam**3 - 2 * (a + bb) * lam - c
        if fp == 0:
            break
        step = f / fp
        lam -= step
        if abs(step) < 1e-15 * max(1.0, abs(lam)):
            break
    return lam


def _adjugate3(m) -> np.ndarray:
    """adj(m) by cofactors (exact for singular m, unlike det·inv)."""
    return np.array([
        [m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1], m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2], m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]],
        [m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2], m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0], m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]],
        [m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0], m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1], m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]],
    ])


def quest(body_vectors, reference_vectors, weights=None) -> WahbaSolution:
    """Shuster's QUEST with sequential rotations near 180°."""
    b, r, w = _prepare(body_vectors, reference_vectors, weights)
    lam0 = float(np.sum(w))
    k_original = davenport_k(profile_matrix(b, r, w))
    best_gain, best_q = -np.inf, None
    for q_flip, flip in _FLIPS:
        bm = profile_matrix(b, r @ flip.T, w)
        lam = _quest_lambda_max(bm, lam0)
        sigma = np.trace(bm)
        z = np.array([bm[2, 1] - bm[1, 2], bm[0, 2] - bm[2, 0], bm[1, 0] - bm[0, 1]])
        m = (lam + sigma) * np.eye(3) - (bm + bm.T)
        adj = _adjugate3(m)
        # q' ∝ [det m, adj(m) z] (the Gibbs-vector solution times det m, finite everywhere). It degrades where
        # the rotation in this frame is near 180° (det m → 0): Shuster's sequential rotations try the frame
        # rotated by 180° about each axis; we keep the candidate with the largest Wahba gain qᵀKq.
        q_rot = np.concatenate(([m[0] @ adj[:, 0]], adj @ z))
        norm = np.linalg.norm(q_rot)
        if not (np.isfinite(norm) and norm > 0):
            continue
        # r' = F r, so C' = F C and C = Fᵀ C': q = conj(q_flip) ⊗ q'.
        q = quat_multiply(q_flip * np.array([1.0, -1.0, -1.0, -1.0]), q_rot / norm)
        gain = q @ k_original @ q
        if gain > best_gain:
            best_gain, best_q = gain, q
        if gain >= lam - 1e-10 * lam0:  # attains λmax: this is the optimum, no need to try other frames
            break
    if best_q is None:
        raise WahbaError("QUEST failed in every rotated frame")
    q = best_q
    return _solution("quest", quat_to_dcm(quat_normalize(q)), b, r, w)


Solver = Callable[..., WahbaSolution]

SOLVERS: dict[str, Solver] = {
    "three-vector": three_vector,
    "thesis-v2": thesis_v2,
    "triad-first": triad_first,
    "triad-second": triad_second,
    "svd": svd,
    "davenport": davenport,
    "quest": quest,
}
ALIASES = {"thesis-v1": "three-vector", "triad": "triad-first", "markley": "svd", "q-method": "davenport"}


def get_solver(method: str) -> Solver:
    """The solver registered under `method` (or an alias)."""
    name = ALIASES.get(method, method)
    try:
        return SOLVERS[name]
    except KeyError:
        raise ValueError(f"unknown Wahba method {method!r}; choose one of {', '.join(SOLVERS)}") from None


def solve(body_vectors, reference_vectors, weights=None, method: str = "svd") -> WahbaSolution:
    """Solve Wahba's problem with the named method (default: SVD, the optimum)."""
    return get_solver(method)(body_vectors, reference_vectors, weights)


__all__ = [
    "WahbaError", "WahbaSolution", "SOLVERS", "ALIASES", "get_solver", "solve", "three_vector", "thesis_v2",
    "triad_first", "triad_second", "svd", "davenport", "quest", "thesis_matrix", "thesis_dcm_body_to_ref",
    "thesis_dcm_from_floats", "wahba_loss", "attitude_covariance", "profile_matrix", "davenport_k", "polar_reorthonormalize",
]
