"""MAV_CMD_PREFLIGHT_CALIBRATION param1=1: gyro bias at rest (bias only; scale and misalignment kept).

The vehicle must be disarmed and still. The command is long-running: ACK IN_PROGRESS at once, then the final
ACK (ACCEPTED with the new calibration saved and applied, or FAILED with a STATUSTEXT saying why).
Calibrated = M·(raw − b); a residual mean rate r measured after the current calibration means the bias is
b + M⁻¹·r. The bias itself and its plausibility limit come from the offline bias-only fit
(calibration.gyro_cal.fit_bias_only), applied to the samples mapped back to raw sensor-frame rates.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ahrsd.calibration import GyroModel
from ahrsd.calibration.inertial.gyro import fit_bias_only
from ahrsd.core.angles import STANDARD_GRAVITY_M_S2
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.calibration_swap import CalibrationSwap
from ahrsd.daemon.commands import CommandAck
from ahrsd.daemon.health import Health
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outbound import Outbound
from ahrsd.daemon.sample_reader import SampleListeners

log = logging.getLogger(__name__)

DURATION_S = 2.0
# Rest test. ADIS16405 datasheet: gyro noise 0.9 °/s rms at full bandwidth; 3× that as the per-axis standard
# deviation limit. Accelerometer: |f| within 0.5 m/s² of g and steady.
MAX_GYRO_STD_RAD_S = math.radians(3 * 0.9)
MAX_ACCEL_NORM_ERR_M_S2 = 0.5
MAX_ACCEL_STD_M_S2 = 0.3


class GyroBiasCalibration:
    """Collects samples through a sample listener, then swaps the calibration (daemon.calibration_swap).
    `health.calibrating` says CALIBRATING meanwhile; `loop` schedules the finish and the give-up timer."""

    def __init__(self, ctx, sample_rate_hz: float, *, listeners: SampleListeners, loop, health: Health,
                 outbound: Outbound, autopilot: AutopilotState, swap: CalibrationSwap):
        self.ctx = ctx
        self.listeners = listeners
        self.loop = loop
        self.health = health
        self.outbound = outbound
        self.autopilot = autopilot
        self.swap = swap
        self.needed = max(16, int(DURATION_S * sample_rate_hz))
        self.n = 0
        self.g_sum = np.zeros(3)
        self.g_sq = np.zeros(3)
        self.a_norm_sum = 0.0
        self.a_norm_sq = 0.0
        self.gyro_rad_s: list[np.ndarray] = []   # calibrated, body frame
        self.done = False
        self._remove = None

    def start(self) -> CommandAck:
        # the estimate is not used, and the calibration is swapped after the samples (call_soon): the estimator may
        # step a run of samples before this listener (sample_reader.SampleListeners)
        self._remove = self.listeners.add(self.on_sample, in_place=True, steps_ahead=_always)
        # samples can stop (sensor failure): never leave the command IN_PROGRESS for ever
        self.loop.call_later(3 * DURATION_S + 2.0, self.cancel, "no samples from the sensor")
        self.health.calibrating = "gyro calibration"
        self.outbound.statustext(mavlink.MAV_SEVERITY_INFO, "ahrsd: gyro calibration started, keep still")
        return CommandAck(mavlink.MAV_RESULT_IN_PROGRESS, 0)

    def on_sample(self, sample, _estimate) -> None:
        if self.done:
            return
        g = sample.gyro_rad_s
        self.gyro_rad_s.append(g)
        self.g_sum += g
        self.g_sq += g * g
        a = math.sqrt(float(sample.accel_m_s2 @ sample.accel_m_s2))
        self.a_norm_sum += a
        self.a_norm_sq += a * a
        self.n += 1
        if self.n >= self.needed:
            self.done = True
            self.loop.call_soon(self._finish)

    def cancel(self, reason: str) -> None:
        if not self.done:
            self.done = True
            self._end(mavlink.MAV_RESULT_FAILED, f"ahrsd: gyro calibration failed: {reason}")

    def _finish(self) -> None:
        n = self.n
        mean = self.g_sum / n
        std = np.sqrt(np.maximum(self.g_sq / n - mean * mean, 0.0))
        a_mean = self.a_norm_sum / n
        a_std = math.sqrt(max(self.a_norm_sq / n - a_mean * a_mean, 0.0))
        if self.autopilot.armed:
            return self._end(mavlink.MAV_RESULT_FAILED, "ahrsd: gyro calibration failed: vehicle armed")
        if np.any(std > MAX_GYRO_STD_RAD_S) or a_std > MAX_ACCEL_STD_M_S2 or abs(a_mean - STANDARD_GRAVITY_M_S2) > MAX_ACCEL_NORM_ERR_M_S2:
            return self._end(mavlink.MAV_RESULT_FAILED, "ahrsd: gyro calibration failed: vehicle moved")
        cal = self.swap.pipeline.calibration
        model = cal.gyro
        # back to raw sensor-frame rates: body = mounting · sensor, calibrated = M·(raw − b)
        body = np.asarray(self.gyro_rad_s)
        mounting = self.swap.pipeline.mounting
        sensor = body if mounting is None else body @ mounting     # rows: mountingᵀ · g
        raw = model.bias_rad_s + np.linalg.solve(model.matrix, sensor.T).T
        fit = fit_bias_only(raw, model.matrix)
        if not fit.ok:
            return self._end(mavlink.MAV_RESULT_FAILED, "ahrsd: gyro calibration failed: bias implausibly large")
        new_bias = fit.model.bias_rad_s
        new_cal = cal.with_sensor("gyro", GyroModel(new_bias, model.matrix), method="preflight-rest",
                                  samples=n, residual_rms=float(np.linalg.norm(std)))
        try:
            self.swap.apply(new_cal, save=True, reason="gyro bias")
        except Exception as exc:  # noqa: BLE001 - report, don't crash
            log.exception("applying the gyro calibration failed")
            return self._end(mavlink.MAV_RESULT_FAILED, f"ahrsd: gyro calibration failed: {exc}")
        deg = np.degrees(new_bias)
        self._end(mavlink.MAV_RESULT_ACCEPTED,
                  f"ahrsd: gyro bias {deg[0]:.2f} {deg[1]:.2f} {deg[2]:.2f} deg/s saved")

    def _end(self, result: int, text: str) -> None:
        if self._remove:
            self._remove()
        self.health.calibrating = ""
        severity = mavlink.MAV_SEVERITY_INFO if result == mavlink.MAV_RESULT_ACCEPTED else mavlink.MAV_SEVERITY_WARNING
        self.outbound.statustext(severity, text)
        self.ctx.finish(result)


def _always() -> bool:
    return True
