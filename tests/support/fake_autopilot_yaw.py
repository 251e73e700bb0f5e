"""Fake autopilots for the restart tests: ArduPilot EKF3 and PX4 EKF2 as they fuse the yaw of our
VISION_POSITION_ESTIMATE, reduced to the two states that yaw fusion moves — the yaw and the z gyro bias (both
EKFs learn a persistent yaw innovation as gyro bias, which is what makes them overshoot after a step) — with
the observation noise, the innovation gate and the process noise of the real source, at their defaults:

ArduPilot (libraries/AP_VisualOdom/AP_VisualOdom_MAV.cpp, AP_NavEKF3/AP_NavEKF3_Measurements.cpp,
AP_NavEKF3_MagFusion.cpp, AP_NavEKF3_core.cpp, AP_NavEKF3.cpp):
* angErr = sqrt(roll var + pitch var + yaw var) of the VPE covariance (GCS_Common.cpp
  handle_common_vision_position_estimate_data since ArduPilot PR #32084, merged 2026-02; before it, in 4.6 and
  earlier, cbrt(roll var² + pitch var² + yaw var²): `ang_err_rule="cbrt"`), clamped to [VISO_YAW_M_NSE, 1.5 rad]
  (AP_VisualOdom_MAV.cpp handle_pose_estimate); yawAngErr = max(angErr, 5°) (AP_NavEKF3_Measurements.cpp
  writeExtNavData); R_YAW = max(yawAngErr, 0.05)² (AP_NavEKF3_MagFusion.cpp fuseEulerYaw). Nothing refuses a
  large variance: it only lowers the gain and widens the gate;
* the first sample aligns the yaw (alignYawAngle, variance max(yawAngErr, 0.01)²);
* fuseEulerYaw: innovation = EKF yaw − ours, varInnov = H·P·Hᵀ + R_YAW, yawTestRatio = innov² /
  (max(0.01·EK3_YAW_I_GATE, 1)² · varInnov); in flight a ratio > 1 is not fused; the state correction uses
  the innovation clipped to ±0.5 rad;
* the yaw source is that of the active EKF source set (EK3_SRCn_YAW; 6 = ExternalNav); MAV_CMD_SET_EKF_SOURCE_SET
  (42007, param1 = 1..3) changes the set (AP_NavEKF_Source::setPosVelYawSourceSet). While the yaw source is
  not ExternalNav our yaw is not used; a change of yaw source sets yaw_source_reset, and the next ExtNav yaw
  taken with the source on ExternalNav is applied by alignYawAngle (a reset), not fused
  (AP_NavEKF3_MagFusion.cpp, SelectMagFusion);
* covariance prediction every 12 ms (EKF_TARGET_DT): yaw += (dt·EK3_GYRO_P_NSE)², delta-angle bias +=
  (dt²·EK3_GBIAS_P_NSE)² (here as a rate bias in rad/s: (dt·EK3_GBIAS_P_NSE)²), defaults 0.015 rad/s and
  0.001 rad/s².

PX4 (src/modules/ekf2/EKF/aid_sources/external_vision/ev_control.cpp, ev_yaw_control.cpp):
* obs_var = max(our yaw variance, EKF2_EVA_NOISE, 0.01²) — the parameter enters as a variance; the gate is
  max(EKF2_HDG_GATE, 1) = 2.6 on sqrt(H·P·Hᵀ + obs_var); a rejected innovation is not fused in air;
* EV yaw fusion stops 0.4 s after the data stops; it starts, through that gate, once samples come < 0.2 s
  apart and > 1 s after its last fusion; while it runs, a changed reset_counter resets the yaw to ours
  (resetQuatStateYaw), and 5 s (EKF2_NOAID_TOUT) without a fused sample also resets it (5 resets a start);
* prediction every 10 ms with EKF2_GYR_NOISE 0.015 rad/s and EKF2_GYR_B_NOISE 0.001 rad/s².

Both fakes are in flight (gated) and assume a vehicle at rest (the gyros measure no rotation).
"""

from __future__ import annotations

import math

INITIAL_GYRO_BIAS_SIGMA_RAD_S = math.radians(2.5)


def wrap_pi(x: float) -> float:
    return math.remainder(x, 2 * math.pi)


class YawBiasFilter:
    """The yaw/gyro-bias part of an EKF: yaw (rad) driven by gyros whose z bias (rad/s) is a state."""

    def __init__(self, dt_s: float, gyro_noise_rad_s: float, gyro_bias_noise_rad_s2: float):
        self.dt_s = dt_s
        self.q_yaw = (dt_s * gyro_noise_rad_s) ** 2
        self.q_bias = (dt_s * gyro_bias_noise_rad_s2) ** 2
        self.yaw = 0.0
        self.bias = 0.0
        self.p = [[0.0, 0.0], [0.0, INITIAL_GYRO_BIAS_SIGMA_RAD_S ** 2]]
        self.t_s: float | None = None

    def reset_yaw(self, yaw_rad: float, var_rad2: float) -> None:
        self.yaw = yaw_rad
        self.p[0][0], self.p[0][1], self.p[1][0] = var_rad2, 0.0, 0.0

    def predict_to(self, t_s: float) -> None:
        if self.t_s is None:
            self.t_s = t_s
        dt = self.dt_s
        while self.t_s + dt <= t_s + 1e-9:
            self.t_s += dt
            # yaw_k+1 = yaw_k − bias·dt (the gyros read zero rotation): F = [[1, −dt], [0, 1]]
            self.yaw -= self.bias * dt
            (a, b), (c, d) = self.p
            a = a - dt * (b + c) + dt * dt * d + self.q_yaw
            b = b - dt * d
            d = d + self.q_bias
            self.p = [[a, b], [b, d]]

    def innovation(self, obs_rad: float) -> tuple[float, float]:
        """(EKF yaw − observation, its variance without R)."""
        return wrap_pi(self.yaw - obs_rad), self.p[0][0]

    def fuse(self, innov_rad: float, r_rad2: float, clip_rad: float = math.inf) -> None:
        (a, b), (_, d) = self.p
        s = a + r_rad2
        k_yaw, k_bias = a / s, b / s
        innov = max(-clip_rad, min(clip_rad, innov_rad))
        self.yaw -= k_yaw * innov
        self.bias -= k_bias * innov
        self.p = [[a - k_yaw * a, b - k_yaw * b], [b - k_yaw * b, d - k_bias * b]]


def vpe_angle_vars(msg) -> tuple[float, float, float]:
    c = msg.covariance
    return c[15], c[18], c[20]


EXTNAV_YAW_SOURCE = 6
MAV_CMD_SET_EKF_SOURCE_SET = 42007
MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED = 0, 2


class FakeEkf3:
    def __init__(self, viso_yaw_m_nse: float = 0.05, yaw_i_gate: float = 300.0,
                 src_yaw=(EXTNAV_YAW_SOURCE, 0, 0), src_posvel=((3, 3, 1, 3),) * 3, ang_err_rule: str = "sqrt"):
        if ang_err_rule not in ("sqrt", "cbrt"):
            raise ValueError(ang_err_rule)
        self.ang_err_rule = ang_err_rule
        self.src_yaw = src_yaw                  # EK3_SRC1_YAW, EK3_SRC2_YAW, EK3_SRC3_YAW
        self.src_posvel = src_posvel            # per set: EK3_SRCn_POSXY, _VELXY, _POSZ, _VELZ
        self.active_set = 0
        self.yaw_source_last = src_yaw[0]
        self.yaw_source_reset = False
        self.aligns = 0                         # alignYawAngle calls after the first
        self.viso_yaw_m_nse = viso_yaw_m_nse
        self.gate = max(0.01 * yaw_i_gate, 1.0)
        self.filter = YawBiasFilter(0.012, 1.5e-2, 1.0e-3)
        self.aligned = False
        self.rejected = 0
        self.fused = 0
        self.max_test_ratio = 0.0

    def r_yaw_rad2(self, roll_var: float, pitch_var: float, yaw_var: float) -> tuple[float, float]:
        """(R_YAW, yawAngErr) for a VPE with these variances."""
        if self.ang_err_rule == "sqrt":
            ang_err = math.sqrt(roll_var + pitch_var + yaw_var)
        else:
            ang_err = (roll_var ** 2 + pitch_var ** 2 + yaw_var ** 2) ** (1.0 / 3.0)
        ang_err = min(max(ang_err, self.viso_yaw_m_nse), 1.5)
        yaw_ang_err = max(ang_err, math.radians(5.0))
        return max(yaw_ang_err, 0.05) ** 2, yaw_ang_err

    def gate_deg(self, angle_vars=(0.0, 0.0, 0.0)) -> float:
        """The largest innovation fused now, deg."""
        r, _ = self.r_yaw_rad2(*angle_vars)
        return math.degrees(self.gate * math.sqrt(self.filter.p[0][0] + r))

    def param(self, name: str) -> float | None:
        """The EK3_SRCn_* parameters (None for any other name)."""
        if not (name.startswith("EK3_SRC") and name[7:8] in "123" and name[8:9] == "_"):
            return None
        n, axis = int(name[7]) - 1, name[9:]
        if axis == "YAW":
            return float(self.src_yaw[n])
        axes = ("POSXY", "VELXY", "POSZ", "VELZ")
        return float(self.src_posvel[n][axes.index(axis)]) if axis in axes else None

    def command_long(self, command: int, param1: float) -> int:
        """GCS_MAVLINK handling of MAV_CMD_SET_EKF_SOURCE_SET: the MAV_RESULT."""
        if command != MAV_CMD_SET_EKF_SOURCE_SET or param1 not in (1, 2, 3):
            return MAV_RESULT_DENIED
        self.active_set = int(param1) - 1
        return MAV_RESULT_ACCEPTED

    def feed(self, t_s: float, yaw_rad: float, reset_counter: int, angle_vars=(0.0, 0.0, 0.0)) -> None:
        # reset_counter: a position reset only (writeExtNavData posReset); it never touches the yaw
        r, yaw_ang_err = self.r_yaw_rad2(*angle_vars)
        self.filter.predict_to(t_s)
        yaw_source = self.src_yaw[self.active_set]
        if yaw_source != self.yaw_source_last:
            self.yaw_source_last = yaw_source
            self.yaw_source_reset = True
        if yaw_source != EXTNAV_YAW_SOURCE:
            self.yaw_source_reset = False       # consumed by realignYawGPS (a no-op here: not moving)
            return                              # our yaw is not used
        if self.aligned and self.yaw_source_reset:
            self.yaw_source_reset = False
            self.aligns += 1
            self.filter.reset_yaw(yaw_rad, max(yaw_ang_err, 1e-2) ** 2)   # alignYawAngle
            return
        if not self.aligned:
            self.filter.reset_yaw(yaw_rad, max(yaw_ang_err, 1e-2) ** 2)
            self.aligned = True
            return
        innov, p_yaw = self.filter.innovation(yaw_rad)
        ratio = innov * innov / (self.gate ** 2 * (p_yaw + r))
        self.max_test_ratio = max(self.max_test_ratio, ratio)
        if ratio > 1.0:
            self.rejected += 1
            return
        self.fused += 1
        self.filter.fuse(innov, r, clip_rad=0.5)

    def feed_message(self, t_s: float, msg) -> None:
        self.feed(t_s, msg.yaw, msg.reset_counter, vpe_angle_vars(msg))

    @property
    def yaw(self) -> float:
        return self.filter.yaw


class FakeEkf2:
    def __init__(self, eva_noise: float = 0.05, hdg_gate: float = 2.6, noaid_tout_s: float = 5.0):
        self.eva_noise = eva_noise
        self.gate = max(hdg_gate, 1.0)
        self.noaid_tout_s = noaid_tout_s
        self.filter = YawBiasFilter(0.010, 1.5e-2, 1.0e-3)
        self.yaw_align = False
        self.active = False
        self.last_data = -math.inf
        self.last_fuse = -math.inf
        self.counter: int | None = None
        self.resets = 0
        self.rejected = 0
        self.resets_available = 0

    def feed(self, t_s: float, yaw_rad: float, reset_counter: int, angle_vars=(0.0, 0.0, 0.0)) -> None:
        if self.active and t_s - self.last_data > 0.4:
            self.active = False                          # ev_control: "vision data stopped"
        ev_reset = self.counter is not None and reset_counter != self.counter
        self.counter = reset_counter
        interval_ok = t_s - self.last_data < 0.2
        self.last_data = t_s
        self.filter.predict_to(t_s)
        obs_var = max(angle_vars[2], self.eva_noise, 0.01 ** 2)
        if not self.yaw_align:                           # not aligned yet: reset to EV and start
            self.filter.reset_yaw(yaw_rad, obs_var)
            self.yaw_align = self.active = True
            self.last_fuse, self.resets_available = t_s, 5
            return
        innov, p_yaw = self.filter.innovation(yaw_rad)
        passes = innov * innov <= self.gate ** 2 * (p_yaw + obs_var)
        if self.active:
            if ev_reset:
                self.filter.reset_yaw(yaw_rad, obs_var)
                self.last_fuse = t_s
                self.resets += 1
            elif passes:
                self.filter.fuse(innov, obs_var)
                self.last_fuse = t_s
            else:
                self.rejected += 1
            if t_s - self.last_fuse > self.noaid_tout_s and self.resets_available > 0:
                self.filter.reset_yaw(yaw_rad, obs_var)  # "EV yaw fusion failing, resetting"
                self.last_fuse = t_s
                self.resets_available -= 1
                self.resets += 1
        elif interval_ok and t_s - self.last_fuse > 1.0:
            if passes:                                   # starting: fuseYaw through the gate
                self.filter.fuse(innov, obs_var)
                self.active, self.last_fuse, self.resets_available = True, t_s, 5
            else:
                self.rejected += 1

    def feed_message(self, t_s: float, msg) -> None:
        self.feed(t_s, msg.yaw, msg.reset_counter, vpe_angle_vars(msg))

    @property
    def yaw(self) -> float:
        return self.filter.yaw


def warm_up(autopilot, yaw_rad: float, seconds: float, t0_s: float = 0.0, *, reset_counter: int = 0,
            rate_hz: float = 30.0, angle_vars=(0.0, 0.0, 0.0)) -> float:
    """Feed a steady heading for `seconds` (the EKF reaches its steady-state gains); returns the end time."""
    n = int(seconds * rate_hz)
    for k in range(n):
        autopilot.feed(t0_s + k / rate_hz, yaw_rad, reset_counter, angle_vars)
    return t0_s + n / rate_hz
