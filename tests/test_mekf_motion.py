"""`mekf` under motion it must not be fooled by: a hand shaking or moving the sensor about (sustained linear
acceleration that must not tilt the horizon). Truth trajectories are built here with scipy (position, attitude,
specific force = C_nᵇ (a − g)), never with the estimator's own rotation maths."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.core.sample import make_sample
from ahrsd.estimator.mekf import Mekf

G = 9.81
FIELD_NED = np.array([27.86, 0.0, 41.04])  # µT, magnetic north (the simulator's default site)
RATE_HZ = 200.0
REST_S, MOTION_S, AFTER_S = 10.0, 30.0, 5.0


def _attitude(t_s: np.ndarray) -> Rotation:
    """Body → NED: tilted (roll 10°, pitch −5°, heading 30°) and, from 8 s on (smoothly ramped in over 2 s), a
    hand's slow wobble: heading ±20° at 0.05 Hz, roll ±15° at 0.2 Hz, pitch ±10° at 0.13 Hz."""
    ramp = np.clip((t_s - (REST_S - 2.0)) / 2.0, 0.0, 1.0)
    env = 0.5 * (1.0 - np.cos(math.pi * ramp))
    yaw = math.radians(30.0) + env * math.radians(20.0) * np.sin(2 * math.pi * 0.05 * t_s)
    pitch = math.radians(-5.0) + env * math.radians(10.0) * np.sin(2 * math.pi * 0.13 * t_s + 1.0)
    roll = math.radians(10.0) + env * math.radians(15.0) * np.sin(2 * math.pi * 0.2 * t_s)
    return Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=-1))


def _imu(accel_along_axis_m_s2: np.ndarray, axis: np.ndarray, axis_in_body: bool, seed: int = 0):
    """Samples of the wobbling sensor with a linear acceleration of the given magnitude (per sample) along a
    fixed NED axis or a body axis. Gyro: the body rate at mid-interval (what the strapdown step integrates),
    from the scipy attitude by a central difference. Returns t, gyro, accel, mag, truth q (w, x, y, z)."""
    rng = np.random.default_rng(seed)
    n = int((REST_S + MOTION_S + AFTER_S) * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    r = _attitude(t)
    a_line = accel_along_axis_m_s2[:, None] * np.asarray(axis, dtype=float)[None, :]
    a_ned = r.apply(a_line) if axis_in_body else a_line
    f_body = r.inv().apply(a_ned - np.array([0.0, 0.0, G]))  # specific force: a − g, gravity down in NED
    h = 1e-4
    t_mid = t - 0.5 / RATE_HZ
    omega_body = (_attitude(t_mid - h).inv() * _attitude(t_mid + h)).as_rotvec() / (2 * h)
    gyro = omega_body + math.radians(0.1) * rng.standard_normal((n, 3))
    acc = f_body + 0.03 * rng.standard_normal((n, 3))
    mag = r.inv().apply(FIELD_NED) + 0.2 * rng.standard_normal((n, 3))
    q = r.as_quat()
    return t, gyro, acc, mag, np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def _shake(t_s: np.ndarray, freq_hz: float, amplitude_m_s2: float) -> np.ndarray:
    """Acceleration of x(t) = A (1 − cos 2πf s) during the motion (s = t − rest, A = amplitude / (2πf)²):
    position and velocity continuous, the velocity swings ±amplitude/(2πf) and returns to 0."""
    s = t_s - REST_S
    w = 2 * math.pi * freq_hz
    on = (s >= 0.0) & (s < MOTION_S)
    return np.where(on, amplitude_m_s2 * np.cos(w * s), 0.0)


def _moves(t_s: np.ndarray, accel_m_s2: float = 5.0, push_s: float = 0.4, pause_s: float = 0.2) -> np.ndarray:
    """A hand moving the sensor from place to place and back: +a for push_s, −a for push_s (1.6 m at 2 m/s
    peak for the defaults), a pause, then the same back. The acceleration is sustained for 0.4 s at a time."""
    s = t_s - REST_S
    period = 2 * (2 * push_s + pause_s)
    ph = np.mod(s, period)
    a = accel_m_s2
    prof = np.select(
        [ph < push_s, ph < 2 * push_s, ph < 2 * push_s + pause_s, ph < 3 * push_s + pause_s,
         ph < 4 * push_s + pause_s],
        [a, -a, 0.0, -a, a], 0.0)
    return np.where((s >= 0.0) & (s < MOTION_S), prof, 0.0)


def _tilt_error_deg(q_est: np.ndarray, q_truth: np.ndarray) -> np.ndarray:
    """Tilt part of the error rotation q_est ⊗ q_truth* (in NED): the angle between estimated and true vertical."""
    def rot(q):
        return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1))

    e = (rot(q_est) * rot(q_truth).inv()).as_rotvec()
    return np.degrees(np.hypot(e[:, 0], e[:, 1]))


def _run(t, g, a, m, truth, **params):
    q, _ = Mekf(**params).run_batch(t, g, a, m)
    moving = t >= REST_S
    err = _tilt_error_deg(q[moving], truth[moving])
    return float(np.sqrt(np.mean(err**2))), float(err.max())


# A filter that levels on the instantaneous specific force leans atan(5/9.81) = 27° toward each push; one that
# low-passes it (1.5 s) but trusts the result as white noise still leans 0.4–1° (measured without the
# adaptive noise: 1 Hz shake 0.17° RMS / 0.37° max, moves 0.57° / 1.06°; VQF 2.1.2: 0.11 / 0.29 and 0.37 / 0.80).
@pytest.mark.parametrize("freq_hz", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("axis, in_body", [([1.0, 0.0, 0.0], False), ([0.0, 1.0, 0.0], True)])
def test_shaking_at_1_to_3_hz_does_not_tilt_the_horizon(freq_hz, axis, in_body):
    """±5 m/s² along one axis (north, or the body's y axis as it wobbles) at 1–3 Hz for 30 s."""
    t = np.arange(int((REST_S + MOTION_S + AFTER_S) * RATE_HZ)) / RATE_HZ
    t, g, a, m, truth = _imu(_shake(t, freq_hz, 5.0), np.array(axis), in_body, seed=int(freq_hz))
    rms, worst = _run(t, g, a, m, truth)
    # measured 0.13° RMS / 0.19° max at 1 Hz, less at 2–3 Hz
    assert rms < 0.2 and worst < 0.3, (rms, worst)


def test_moving_the_sensor_about_does_not_tilt_the_horizon():
    """Bang-bang moves, ±5 m/s² sustained 0.4 s at a time, for 30 s."""
    t = np.arange(int((REST_S + MOTION_S + AFTER_S) * RATE_HZ)) / RATE_HZ
    t, g, a, m, truth = _imu(_moves(t), np.array([1.0, 0.0, 0.0]), False, seed=7)
    rms, worst = _run(t, g, a, m, truth)
    assert rms < 0.3 and worst < 0.5, (rms, worst)       # measured 0.18° / 0.25°



# ------------------------------------------------------------------------------------ attached magnet
def _turning_attitude(t_s: np.ndarray) -> Rotation:
    """At rest until 10 s, then turning at 30 °/s about down while rolling ±20° (0.1 Hz), pitching ±15°."""
    ramp = np.clip((t_s - REST_S) / 2.0, 0.0, 1.0)
    env = 0.5 * (1.0 - np.cos(math.pi * ramp))
    yaw = math.radians(30.0) + math.radians(30.0) * np.maximum(t_s - REST_S - 1.0, 0.0) * env
    roll = math.radians(5.0) + env * math.radians(20.0) * np.sin(2 * math.pi * 0.1 * t_s)
    pitch = env * math.radians(15.0) * np.sin(2 * math.pi * 0.07 * t_s + 1.0)
    return Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], axis=-1))


def _attached_magnet(offset_ut, attach_s=8.0, seconds=70.0, seed=0, detach_s=math.inf):
    """A calibrated sensor; from attach_s to detach_s a magnet is fixed to it: a constant field offset in the
    body frame."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    r = _turning_attitude(t)
    h = 1e-4
    t_mid = t - 0.5 / RATE_HZ
    omega = (_turning_attitude(t_mid - h).inv() * _turning_attitude(t_mid + h)).as_rotvec() / (2 * h)
    gyro = omega + math.radians(0.1) * rng.standard_normal((n, 3))
    acc = r.inv().apply([0.0, 0.0, -G]) + 0.03 * rng.standard_normal((n, 3))
    on = (t >= attach_s) & (t < detach_s)
    magnet = np.where(on[:, None], np.asarray(offset_ut, dtype=float)[None, :], 0.0)
    mag = r.inv().apply(FIELD_NED) + magnet + 0.2 * rng.standard_normal((n, 3))
    q = r.as_quat()
    return t, gyro, acc, mag, np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def _heading_error_deg(q_est, q_truth):
    def rot(q):
        return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1))

    return np.degrees((rot(q_est) * rot(q_truth).inv()).as_rotvec()[:, 2])


def _heading_rms_deg(q, truth, mask) -> float:
    return float(np.sqrt(np.mean(_heading_error_deg(q[mask], truth[mask]) ** 2)))


def test_an_attached_magnet_is_learned_and_adopted():
    """A 4.1 µT body-fixed offset ([3, −2, 2] µT: the field's magnitude changes by up to ±8 % and its dip by
    up to ±5° with orientation, inside the disturbance checks) attached at 8 s, then 60 s of turning. A filter
    that takes the field as it comes follows the magnet (measured 0.78° RMS, 1.5° max heading error with the
    offset estimate off, 0.83° after 40 s); the defaults learn the offset and use it once it explains why the
    field's norm and dip disagree with the reference: measured 0.28° RMS (the first seconds, before it is
    known), 0.04° after 40 s, the estimate within 0.17 µT."""
    b = np.array([3.0, -2.0, 2.0])
    t, g, a, m, truth = _attached_magnet(b)
    est = Mekf()
    q, _ = est.run_batch(t, g, a, m)
    assert _heading_rms_deg(q, truth, t >= REST_S) < 0.5
    assert _heading_rms_deg(q, truth, t >= 40.0) < 0.15
    np.testing.assert_allclose(est.field_offset_ut, b, atol=0.4)
    est.relearn_field_reference()           # a new calibration: the offset it absorbed is learned anew
    np.testing.assert_array_equal(est.field_offset_ut, 0.0)


def test_a_strong_attached_magnet_is_adopted_although_every_field_sample_is_rejected():
    """A 12 µT offset along the sensor's z axis: the magnitude is 13–25 % above the reference in every
    orientation, so the disturbance check rejects every sample and, without the offset, the heading is the
    gyro's alone (measured 2.0° RMS, 4.1° max for this turning motion with the offset estimate off). It is
    learned from the rejected field (a filter that learned only from fields matching the reference never
    would): measured 0.04° RMS, the estimate within 0.18 µT."""
    b = np.array([0.0, 0.0, 12.0])
    t, g, a, m, truth = _attached_magnet(b)
    est = Mekf()
    q, _ = est.run_batch(t, g, a, m)
    assert _heading_rms_deg(q, truth, t >= REST_S) < 0.2
    np.testing.assert_allclose(est.field_offset_ut, b, atol=0.3)
    q_off, _ = Mekf(mag_offset_tau_s=0.0).run_batch(t, g, a, m)
    assert _heading_rms_deg(q_off, truth, t >= REST_S) > 1.0    # the case is a real one


def test_a_removed_magnet_is_no_longer_subtracted():
    """The 6.7 µT magnet ([6, −3, 3] µT) attached at 8 s is taken off again at 45 s. The offset estimate
    still holds it (it is forgotten over mag_offset_tau_s = 60 s), but the raw field now agrees with the
    reference and the corrected one does not, so it is no longer used: after 50 s the heading error is what it
    is without the magnet (measured 0.14° RMS after 50 s and 0.22° while attached; 1.0° after 50 s for a filter
    that kept subtracting the offset until forgotten; 0.95° and 2.1° with the offset estimate off)."""
    b = np.array([6.0, -3.0, 3.0])
    t, g, a, m, truth = _attached_magnet(b, detach_s=45.0, seconds=90.0)
    est = Mekf()
    q, _ = est.run_batch(t, g, a, m)
    assert _heading_rms_deg(q, truth, (t >= 30.0) & (t < 45.0)) < 0.35    # adopted while attached
    assert _heading_rms_deg(q, truth, t >= 50.0) < 0.3


def _step_by_step(est, t, g, a, m):
    """Quaternions and flags of the one-sample hot path (`Mekf.step`, the daemon's path) over the samples."""
    q = np.full((len(t), 4), np.nan)
    flags = np.zeros(len(t), dtype=np.int64)
    for i in range(len(t)):
        view = est.step(make_sample(t[i], g[i], a[i], m[i]))
        if view.valid:
            q[i] = view.q_wxyz
        flags[i] = int(view.flags)
    return q, flags


def test_batch_and_one_sample_paths_are_the_same_filter_with_an_attached_magnet():
    """`run_batch` (mekf_run's compiled loop) and `step` (one compiled call per sample) run the attached-magnet
    offset stage the same way: bit for bit the same quaternions and flags while the offset is learned and then
    subtracted, and the same offset estimate. (A speed-up that moved the offset stage out of the step into the
    batch loop, or dropped it from one path, breaks this.)"""
    b = np.array([3.0, -2.0, 2.0])
    t, g, a, m, _ = _attached_magnet(b, seconds=50.0)
    batch = Mekf()
    q_batch, f_batch = batch.run_batch(t, g, a, m)
    one = Mekf()
    q_one, f_one = _step_by_step(one, t, g, a, m)
    np.testing.assert_array_equal(q_one, q_batch)
    np.testing.assert_array_equal(f_one, f_batch)
    np.testing.assert_array_equal(one.field_offset_ut, batch.field_offset_ut)
    sb, so = batch._buf["state"].copy(), one._buf["state"].copy()
    for name in ("tilt_push_rad", "heading_push_rad"):   # not tracked by the batch, bounded (test_mekf.py)
        assert sb["unmodelled"][name][0] >= so["unmodelled"][name][0], name
        sb["unmodelled"][name] = so["unmodelled"][name] = 0.0
    np.testing.assert_array_equal(so, sb)


@pytest.mark.parametrize("path", ["batch", "step"])
def test_the_offset_stage_runs_and_its_correction_is_used_on_both_paths(path):
    """The offset stage is not skipped on either path: the estimate learns the magnet, it is in use at the end
    (known, significant, and explaining the field's disagreement with the reference: the corrected field's
    running disagreement below mag_offset_explain_ratio times the raw one's), and the attitude differs from
    the same filter with the offset estimate off."""
    b = np.array([3.0, -2.0, 2.0])
    t, g, a, m, _ = _attached_magnet(b, seconds=50.0)

    def run(**params):
        est = Mekf(**params)
        q = est.run_batch(t, g, a, m)[0] if path == "batch" else _step_by_step(est, t, g, a, m)[0]
        return est, q

    est, q = run()
    np.testing.assert_allclose(est.field_offset_ut, b, atol=0.4)
    o = est._state["offset"]
    assert o["ready"]
    assert o["disagree_corrected"] < est.params.mag_offset_explain_ratio * o["disagree_raw"]
    off, q_off = run(mag_offset_tau_s=0.0)
    np.testing.assert_array_equal(off.field_offset_ut, 0.0)
    moving = t >= 20.0
    assert np.max(np.abs(q[moving] - q_off[moving])) > 1e-4
