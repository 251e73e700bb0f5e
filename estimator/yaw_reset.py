"""What ins.Ins does to its state when the heading is found wrong: the yaw turned about down by a step (the state,
its history and the low-passed specific force), the biases a wrong yaw taught put back, the tilt re-levelled and
the horizontal accelerometer bias restarted after a pull-in through a wrong yaw.

The part owns no state of its own: it writes the kernel's state record, covariance and history it is built with
(the filter's own arrays, in place, as the kernel does), with the parameters in force and the biases to go back to
handed to each call (the heading confirmation keeps those, heading_confirmation.py). What else a reset restarts —
the velocity at the last fix, the magnetometer's error states, the bias-from-rotation window, the counts — is the
filter's to call (Ins._reset_yaw).
"""

from __future__ import annotations

import math

import numpy as np

from . import ins_core as core
from .heading_monitor import wrap_pi


class YawReset:
    """The state's resets after a wrong yaw (see the module docstring)."""

    def __init__(self, x, P: np.ndarray, hist: np.ndarray) -> None:
        self._x, self._P, self._hist = x, P, hist     # the kernel's state record, covariance and history rows

    def turn(self, p, dyaw_rad: float, var_rad2: float, gyro_bias_rad_s: np.ndarray,
             accel_bias_m_s2: np.ndarray) -> float:
        """Turn the attitude (and its history) about down by dyaw; yaw variance = var with its cross-covariances
        cleared; the tilt, which a wrong yaw has been pulling through the GNSS acceleration, gets a floor of its
        start-up uncertainty back (uncorrelated); the biases go back to the given ones (the last confirmed, the
        start-up ones before any) with at least their start-up uncertainty. Returns the step turned, wrapped (rad).
        `p`: the InsParams in force."""
        dyaw = wrap_pi(dyaw_rad)
        x, P = self._x, self._P
        dx = np.zeros(core.N_ERR)
        dx[core.E_YAW] = dyaw
        core._rotate_attitude(x["q"], 0.0, 0.0, dyaw)
        core._correct_history(self._hist, x, -math.inf, dx, 0.0, 0.0, 0.0)
        c, s = math.cos(dyaw), math.sin(dyaw)
        an, ae = x["acc_ned_lp_m_s2"][0], x["acc_ned_lp_m_s2"][1]
        x["acc_ned_lp_m_s2"][0], x["acc_ned_lp_m_s2"][1] = c * an - s * ae, s * an + c * ae
        tilt_floor = p.nav_init_sigma_tilt_rad ** 2 * 0.04
        for i, var in ((core.E_YAW, var_rad2), (core.E_TILT_N, max(P[core.E_TILT_N, core.E_TILT_N], tilt_floor)),
                       (core.E_TILT_E, max(P[core.E_TILT_E, core.E_TILT_E], tilt_floor))):
            restart_uncorrelated(P, i, var)
        # the gyro and accelerometer biases learned since the heading was last confirmed were learned against a
        # wrong yaw (the magnetometer pulling one way, the GNSS velocity the other, the biases taking up the
        # difference): back to the last confirmed ones (the start-up values before any), with their start-up
        # uncertainty
        x["gyro_bias_rad_s"] = gyro_bias_rad_s
        x["accel_bias_m_s2"] = accel_bias_m_s2
        for i in range(core.E_BG, core.E_BG + 3):
            var = max(P[i, i], p.init_gyro_bias_sigma_rad_s ** 2)
            restart_uncorrelated(P, i, var)
        for i in range(core.E_BA, core.E_BA + 3):
            var = max(P[i, i], p.init_accel_bias_sigma_m_s2 ** 2)
            restart_uncorrelated(P, i, var)
        return dyaw

    def relevel(self, p, lean_sigma_rad: float) -> None:
        """The tilt's 1σ, uncorrelated, becomes at least `lean_sigma_rad` (no more than the 1σ a fix assumes when it
        first sets the velocity, `nav_init_sigma_tilt_rad`), at the first valid GNSS yaw (the alignment, or without a
        magnetometer the yaw kept there). Until then the yaw was tens of degrees off (the magnetometer's, or pulled
        in from an unknown start), and the GNSS velocity levelled the tilt against the horizontal acceleration
        projected through it: a car accelerating away under a yaw 80–100° off leans its tilt by degrees, while the
        linearised updates leave its variance at tenths of a degree. With its variance kept small, the fixes after
        the alignment would put that tilt error into the horizontal accelerometer bias and the z axis's lean just
        released to learn, which keep it (docs/gnss.md "The horizon while the heading is being found")."""
        P = self._P
        var = min(lean_sigma_rad, p.nav_init_sigma_tilt_rad) ** 2
        for i in (core.E_TILT_N, core.E_TILT_E):
            v = max(P[i, i], var)
            restart_uncorrelated(P, i, v)

    def restart_horizontal_accel_bias(self, p, startup_accel_bias_m_s2: np.ndarray) -> None:
        """The horizontal (body x, y) accelerometer bias back to its start-up value and 1σ, uncorrelated: what it
        learned while the yaw was being pulled in was the GNSS acceleration projected through a yaw tens of degrees
        off, which a steady turn cannot separate from a tilt (ins_core._gated_update). The vertical one keeps what
        it learned (the vertical channel sees no yaw)."""
        x, P = self._x, self._P
        var = p.init_accel_bias_sigma_m_s2 ** 2
        for k in range(2):
            x["accel_bias_m_s2"][k] = startup_accel_bias_m_s2[k]
            i = core.E_BA + k
            v = max(P[i, i], var)
            restart_uncorrelated(P, i, v)


def restart_uncorrelated(P: np.ndarray, i: int, var: float) -> None:
    """Error state i restarted on its own: its row and column of P cleared, its variance set to var."""
    P[i, :] = 0.0
    P[:, i] = 0.0
    P[i, i] = var
