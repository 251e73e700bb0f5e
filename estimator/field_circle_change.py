"""The iron moved: new levelled fields no longer sit on the circle fitted before (field_circle.py), and where the
new circle's centre is while the vehicle has not yet swept it.

A hard iron that moves (a battery, a winch, a load) moves the circle the levelled horizontal field sweeps by its
horizontal change Δ, and leaves its radius, the Earth's horizontal field H, as it was. The circle check's fit
forgets the old circle only over its window (300 s): where the vehicle keeps to a few headings after the move,
its centre follows the new iron only as the old fields are forgotten. This part finds the move and says where the
new centre is from the fields after it:

* **The change point** is Page's CUSUM (E. S. Page, "Continuous inspection schemes", Biometrika 41, 1954) on the
  squared standardised distance of each new field from the reference circle (the fit's at its last judgement while
  the CUSUM was at rest): z = e / √f, e the conic's residual (≈ 2r·δ for a field δ off the circle), f its variance
  from the magnetometer noise and the tilt σ times the vertical field (the fit's own floor) and the reference's
  uncertainty, or the reference fit's own residual variance where that is larger (what the circle leaves that the
  noise does not explain — on a banking plane a vertical hard iron the planar fit does not model, seen through
  the bank — is no change). Only fields in the heading sectors the reference fit covered count: beyond them
  its conic (with the ellipse terms) is an extrapolation, not evidence (a plane whose fit covered 6 sectors read
  fields 4.5 µT off its conic in the seventh). Each field counts as `period / correlation` of an independent one
  (the fit's rule: tilt errors and waves are correlated over seconds), so S ← max(0, S + w·(z² − k)). Under no
  change z² is at most χ²₁ (the floor is a floor: the fit's residual is below it on right calibrations,
  docs/estimator.md); a field off the circle by δ noise σ has E[z²] = 1 + δ². k is the log-likelihood ratio's
  per-sample reference for a variance ratio 1 + δ² at the design shift δ (3σ: "more than their noise allows"),
  k = (1 + δ²)·ln(1 + δ²)/δ², and the threshold h (`CircleChangeParams.threshold`) gives a stated in-control
  average run length of independent fields of χ²₁ (tests/test_field_circle_change.py computes it with the
  Brook–Evans Markov chain): nothing is tuned on a run.
  A second CUSUM, the same k and h, watches the levelled vertical field against the reference window's mean: a
  moved iron's vertical part shifts it at any heading, where the horizontal one sees only the part of the move
  along the field (a move across it, the part that turns the heading, shows in the circle only to second order
  until the vehicle turns). Its error: the noise, the horizontal field times the tilt σ, the reference's centre
  (the horizontal iron the fields show) times the tilt itself, or the window's own spread where larger. h is set
  for each so that either fires by chance no more often than one does at 1e4.
  The change is taken to start where both CUSUMs were last at zero (Page's estimate of the change time).
* **The centre on the known radius:** after the change the fields since it are fitted to a circle of the old
  radius about an unknown centre c (Gauss–Newton on |p − c| − r, each field's radial variance f/(2r)² weighted
  as above). One heading fixes c along that heading's radial direction only; with the prior c₀ ± r (the old
  centre, the whole circle as its spread) the unseen direction stays at the old centre with a σ of r, and the
  heading σ it gives is as large as the iron allows until the vehicle turns (a car's corner is enough: two
  headings 90° apart fix both axes). The fit's own full circle takes over once the restarted window covers the
  turns again (field_circle.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

_TWO_PI = 2.0 * math.pi


class LevelledField(NamedTuple):
    """One field as the circle check takes it (field_circle.FieldCircleCheck.add), levelled by the filter's roll and
    pitch."""

    t_s: float
    x_ut: float                 # levelled horizontal field, north-ish and east-ish of the body's heading
    y_ut: float
    var_ut2: float              # its horizontal error variance (noise, the vertical field turned by the tilt σ)
    weight: float               # as the fit counts it (period / correlation)
    tilt2_rad2: float           # roll² + pitch²
    z_ut: float                 # levelled vertical field
    iron_gain: float            # how much of a body-z iron shows in the levelled horizontal field
    var_z_ut2: float            # the vertical's error variance


def heading_sector(x_ut: float, y_ut: float, n_sectors: int) -> int:
    """Which of `n_sectors` equal heading sectors the levelled field (x, y) points into."""
    return int((math.atan2(y_ut, x_ut) % _TWO_PI) / _TWO_PI * n_sectors) % n_sectors

def reference_k(design_shift_sigma: float) -> float:
    """The CUSUM's reference per independent field for z² (χ²₁ under no change, 1 + δ² on average a field δ noise
    σ off the circle): the log-likelihood ratio's break-even of a variance ratio 1 + δ², (1 + δ²)·ln(1 + δ²)/δ²."""
    v = 1.0 + design_shift_sigma ** 2
    return v * math.log(v) / (v - 1.0)


@dataclass(frozen=True)
class CircleChangeParams:
    design_shift_sigma: float = 3.0
    """The shift of the fields off the circle, in their noise σ, the test is designed for (its k)."""
    threshold: float = 16.0
    """Page's h: with k from design_shift_sigma an in-control average run length of 2.1e4 independent fields of
    χ²₁ for each of the two CUSUMs (horizontal and vertical), so 1.06e4 for either (29 h of fields correlated over
    5 s) — the false-alarm rate the fit's χ² gate has, 1e-4 (tests/test_field_circle_change.py)."""
    max_fields: int = 3000
    """At most this many fields kept since the change (the fit's window at its rate)."""


class CircleChange:
    """`set_reference(theta, radius_ut, centre_ut, centre_sigma_ut, resid_var, sectors, z_mean_ut, z_var_ut2)` at
    each judgement of the fit (taken only while both CUSUMs are at rest); `see(field, vertical_ut)` for each
    LevelledField (vertical_ut the vertical iron earlier moves left): True
    when the change is found — `since` then holds the fields from its start. `reset()` forgets all (a new
    calibration, or the fit restarted)."""

    def __init__(self, params: CircleChangeParams | None = None):
        self.params = params or CircleChangeParams()
        self.k = reference_k(self.params.design_shift_sigma)
        self.reset()

    def reset(self) -> None:
        self.theta = None                 # the reference conic [β, γ, dx, dy, F]
        self.radius_ut = math.nan
        self.centre_ut = np.zeros(2)
        self.centre_sigma_ut = 0.0
        self.resid_var = 0.0              # the reference fit's residual variance per independent field (conic units)
        self.sectors = np.zeros(0, dtype=bool)   # the heading sectors it covered (field_circle.N_SECTORS)
        self.z_mean_ut = 0.0              # the mean levelled vertical field of its window
        self.z_var_ut2 = 0.0              # and its variance per field
        self.cusum = 0.0                  # the horizontal fields' CUSUM
        self.cusum_vertical = 0.0         # the vertical's
        self.since: list[tuple] = []      # the fields since the CUSUM last left zero

    @property
    def at_rest(self) -> bool:
        return self.cusum == 0.0 and self.cusum_vertical == 0.0

    def set_reference(self, theta, radius_ut: float, centre_ut, centre_sigma_ut: float, resid_var: float,
                      sectors, z_mean_ut: float, z_var_ut2: float) -> None:
        if not self.at_rest:
            return                        # the circle before the change stays the reference
        self.theta = np.asarray(theta, dtype=float).copy()
        self.radius_ut = float(radius_ut)
        self.centre_ut = np.asarray(centre_ut, dtype=float).copy()
        self.centre_sigma_ut = float(centre_sigma_ut)
        self.resid_var = float(resid_var)
        self.sectors = np.asarray(sectors, dtype=bool).copy()
        self.z_mean_ut = float(z_mean_ut)
        self.z_var_ut2 = float(z_var_ut2)

    def see(self, field: LevelledField, vertical_ut: float = 0.0) -> bool:
        if self.theta is None:
            return False
        x, y, w = field.x_ut, field.y_ut, field.weight
        # the vertical: a moved iron shifts the levelled vertical field by its vertical part at any heading (the
        # Earth's does not move); its error is the noise and the horizontal field turned by the tilt σ, and the
        # horizontal iron the fields show (the reference's centre) turned into the vertical by the tilt itself
        e_v = field.z_ut - self.z_mean_ut
        f_v = max(field.var_z_ut2 + float(self.centre_ut @ self.centre_ut) * field.tilt2_rad2, self.z_var_ut2)
        self.cusum_vertical = max(0.0, self.cusum_vertical + w * (e_v * e_v / f_v - self.k))
        if self.sectors[heading_sector(x, y, len(self.sectors))]:
            var_ut2 = field.var_ut2 + (vertical_ut * field.iron_gain) ** 2
            beta, gamma, dx, dy, f0 = self.theta
            e = beta * (x * x - y * y) + gamma * 2.0 * x * y + dx * x + dy * y + f0 + (x * x + y * y)
            f = max(4.0 * self.radius_ut ** 2 * (var_ut2 + self.centre_sigma_ut ** 2), self.resid_var)
            self.cusum = max(0.0, self.cusum + w * (e * e / f - self.k))
        if self.at_rest:
            self.since.clear()
            return False
        self._keep(field)
        return max(self.cusum, self.cusum_vertical) > self.params.threshold

    def _keep(self, field) -> None:
        self.since.append(field)
        if len(self.since) > self.params.max_fields:
            del self.since[0]


def centre_on_known_radius(fields, radius_ut: float, prior_centre_ut, vertical_ut: float = 0.0,
                           iterations: int = 5):
    """The centre of a circle of `radius_ut` the fields (CircleChange.see's) lie on, with the prior
    `prior_centre_ut` ± radius_ut per axis: Gauss–Newton on ρ = |p − c| − r, each field's ρ of variance var_ut2
    (plus the vertical iron `vertical_ut` seen through its tilt, gain·b_z) counted w times. Returns the centre
    (µT), its covariance (µT², scaled up by the residuals' own spread where they exceed the stated variance) and
    the number of fields."""
    a = np.asarray([(f.x_ut, f.y_ut, f.var_ut2 + (vertical_ut * f.iron_gain) ** 2, f.weight) for f in fields],
                   dtype=float).reshape(-1, 4)
    p, var, w = a[:, :2], a[:, 2], a[:, 3]
    c0 = np.asarray(prior_centre_ut, dtype=float)
    prior_info = np.eye(2) / radius_ut ** 2
    c = c0.copy()
    info = prior_info
    rho = np.zeros(len(a))
    wi = w / var
    for _ in range(iterations):
        d = p - c
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        n = d / dist[:, None]                     # ∂ρ/∂c = −n
        rho = dist - radius_ut
        info = prior_info + (n * wi[:, None]).T @ n
        grad = (n * (wi * rho)[:, None]).sum(axis=0) - prior_info @ (c - c0)
        c = c + np.linalg.solve(info, grad)
    cov = np.linalg.inv(info)
    if len(a):
        spread = float(np.sum(wi * rho * rho) / max(np.sum(w), 1e-12))
        cov = cov * max(1.0, spread)
    return c, cov, len(a)
