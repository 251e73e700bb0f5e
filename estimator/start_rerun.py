"""The filter's start run again under the GNSS yaw: what `ins` records of its first seconds, and the heading it starts
the re-run from.

Without a trusted magnetometer calibration the filter starts under the raw magnetometer's heading (tens of degrees
off with a vehicle's iron), and the GNSS velocities of the first turn pull against it: the gyro biases take up the
disagreement, and when the GNSS yaw bank becomes valid and the monitor has rejected the magnetometer, the alignment
(heading_confirmation.HeadingConfirmation.aligned) rightly sends them back to their start-up values. The first turn
then teaches nothing, and the vertical gyro bias it would have given is left to the turns after it
(docs/gnss.md "The start run again under the GNSS yaw"). Instead, the samples and fixes since the first
sample are kept (a bounded buffer) and, at that alignment, the filter is started again from its first sample with
the bank's yaw carried back to that sample through the gyro, the magnetometer rejected from the start, and the
samples and fixes replayed: the first turn then teaches the biases against a heading the bank has found. The
re-run is the forward-backward idea of an offline smoother applied once, forwards: the same filter over the same
data from a better start (Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems,
2nd ed., §14.3 on initialisation by re-processing stored data).

`StartRecording` keeps the events in call order and says when it has grown past its bound; `start_heading` works out
the yaw step and the yaw's start-up covariance with the gyro biases and scale factors: the carried-back yaw's error
is the bank's plus what the start-up gyro errors turned it by over the interval, ∫C dt·δb_g + ∫C diag(ω) dt·δs_g
(the kernel's δθ̇ = −C δb_g − C diag(ω) δs_g, ins_core.transition_matrix), so the filter propagated over the same
interval comes back to the bank's variance, uncorrelated with those errors.
"""

from __future__ import annotations

import copy
import math
from typing import NamedTuple

import numpy as np

from ahrsd.core.gravity import EARTH_RATE_RAD_S

from .heading_monitor import wrap_pi


class StartRecording:
    """The samples and fixes offered to the filter since its first sample, in call order, up to `max_s` seconds of
    samples; past that (or when `stop`ped) it keeps nothing more and frees what it had."""

    def __init__(self, max_s: float) -> None:
        self._max_s = float(max_s)
        self.events: list[tuple[bool, object]] | None = []   # (is_sample, sample or fix)
        self._t0_s = math.nan

    @property
    def on(self) -> bool:
        return self.events is not None

    def add_sample(self, sample) -> None:
        if self.events is None:
            return
        t = float(sample.t_s)
        if self._t0_s != self._t0_s:
            self._t0_s = t
        elif t - self._t0_s > self._max_s:
            self.stop()
            return
        self.events.append((True, sample))

    def add_fix(self, fix) -> None:
        if self.events is not None:
            self.events.append((False, fix))

    def stop(self) -> None:
        self.events = None

    def take(self) -> list[tuple[bool, object]]:
        """The events kept (the recording ends)."""
        events = self.events or []
        self.events = None
        return events


class StartHeading(NamedTuple):
    """The re-run's start: the yaw step about down from the levelled magnetometer start, and the yaw's variance and
    its covariances with the gyro biases and scale factors (rad², rad²/s, rad)."""

    dyaw_rad: float
    yaw_var_rad2: float
    yaw_gyro_bias_cov: np.ndarray
    yaw_gyro_scale_cov: np.ndarray


def start_heading(q0_wxyz, samples, t_end_s: float, gsf_yaw_rad: float, gsf_var_rad2: float, lat_rad: float,
                  gyro_bias_rad_s, gyro_bias_var, gyro_scale_var) -> StartHeading:
    """The yaw step that puts the start attitude q0 (body → NED, the first sample's) where the GNSS yaw bank's yaw at
    t_end (the last sample the filter had stepped at the alignment) says it was: the body's rotation over the samples
    up to t_end (gyro less the start-up bias and the Earth's rotation, rectangular as the kernel's mechanisation, the
    rate of the sample before each interval) turns q0 to a yaw ψ̂; the step is ψ_bank − ψ̂ (a turn about down changes
    the yaw by its angle whatever the tilt). gyro_bias_var, gyro_scale_var: the start-up variances (3,) of the gyro
    biases and scale factors."""
    w, x, y, z = (float(v) for v in q0_wxyz)
    b = [float(v) for v in gyro_bias_rad_s]
    ce, se = math.cos(lat_rad), math.sin(lat_rad)
    earth = (EARTH_RATE_RAD_S * ce, 0.0, -EARTH_RATE_RAD_S * se)
    a_bias = [0.0, 0.0, 0.0]       # ∫ C[2, j] dt
    a_scale = [0.0, 0.0, 0.0]      # ∫ C[2, j] ω_j dt
    prev = None
    for s in samples:
        t = float(s.t_s)
        if t > t_end_s:
            break
        g = s.gyro_rad_s.tolist()
        if prev is not None:
            dt = t - prev[0]
            if dt > 0.0:
                # C_bn's last row (down), the Earth's rate in the body
                c20, c21, c22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
                c00, c01, c02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
                c10, c11, c12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
                eb = (c00 * earth[0] + c10 * earth[1] + c20 * earth[2],
                      c01 * earth[0] + c11 * earth[1] + c21 * earth[2],
                      c02 * earth[0] + c12 * earth[1] + c22 * earth[2])
                wr = [prev[1][i] - b[i] for i in range(3)]
                for i, c in enumerate((c20, c21, c22)):
                    a_bias[i] += c * dt
                    a_scale[i] += c * wr[i] * dt
                rx, ry, rz = ((wr[i] - eb[i]) * dt for i in range(3))
                ang = math.sqrt(rx * rx + ry * ry + rz * rz)
                if ang > 0.0:
                    k = math.sin(0.5 * ang) / ang
                    dw, dx, dy, dz = math.cos(0.5 * ang), rx * k, ry * k, rz * k
                    w, x, y, z = (w * dw - x * dx - y * dy - z * dz, w * dx + x * dw + y * dz - z * dy,
                                  w * dy - x * dz + y * dw + z * dx, w * dz + x * dy - y * dx + z * dw)
                    n = math.sqrt(w * w + x * x + y * y + z * z)
                    w, x, y, z = w / n, x / n, y / n, z / n
        prev = (t, g)
    yaw_now = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    bias_cov = np.asarray(a_bias) * np.asarray(gyro_bias_var, dtype=float)
    scale_cov = np.asarray(a_scale) * np.asarray(gyro_scale_var, dtype=float)
    var = float(gsf_var_rad2) + float(np.dot(a_bias, bias_cov)) + float(np.dot(a_scale, scale_cov))
    return StartHeading(wrap_pi(gsf_yaw_rad - yaw_now), var, bias_cov, scale_cov)


def keep_iron(learned_iron):
    """A copy of the learned iron in use (iron_in_use.IronInUse) as it is at the first sample kept."""
    return copy.deepcopy(learned_iron)


def put_back_iron(learned_iron, kept) -> None:
    """The learned iron in use back to `kept` (from `keep_iron`), in place: its learner stays the same object (the
    heading checks hold it for the filter's life). None: nothing kept, nothing changed."""
    if kept is None:
        return
    kept = copy.deepcopy(kept)
    learner = learned_iron.learner
    vars(learner).update(vars(kept.learner))
    kept.learner = learner
    vars(learned_iron).update(vars(kept))


__all__ = ["StartHeading", "StartRecording", "keep_iron", "put_back_iron", "start_heading"]
