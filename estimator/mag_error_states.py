"""The magnetometer's calibration-error states as ins.Ins runs them: which error the five heading harmonics carry
(the calibration's, the learned iron's, or none), what they leave as noise, whether the calibration frame's tilt
states are on, and their restarts from their priors (mag_error_restarts.py).

The part owns one decision's state, the harmonics' source, and writes the kernel's state record, covariance and
parameter record it is built with (the filter's own arrays, written in place, as the kernel does). It reads the
learned iron (iron_in_use.IronInUse) for a learned iron's prior. What it cannot know is handed to it at each call:
the parameters in force (they change with a new calibration), the WMM field at the filter's position and the
declination, and which source the heading checks allow (`harmonics_source`).
"""

from __future__ import annotations

import math

import numpy as np

from . import ins_core as core
from .calibration_heading import calibration_states_error
from .iron_in_use import IronInUse
from .mag_error_restarts import (IRON_HARMONIC_YAWS_RAD, calibration_harmonics_prior, frame_tilt_heading_sigma_rad,
                                 iron_harmonics_prior, restart_frame_tilt, restart_harmonics)
from .wmm_declination_error import wmm_declination_sigma_rad


def learned_floor_var_rad2(p, h2_ut2: float, share: float = 1.0) -> float:
    """The floor of a learned magnetometer's heading variance at a horizontal field of h2 (µT²), rad²: what no
    learned iron explains (`iron_unmodelled_ut`) over the field, at most the calibration's own figure. `p`: the
    InsParams in force; `share`: the part of the unexplained variance counted (slow_floor.py: what is left of it
    over a trust window); the calibration's own figure is never scaled."""
    return min(p.calibration_sigma_rad ** 2, share * p.iron_unmodelled_ut ** 2 / h2_ut2)


def harmonics_source(p, *, calibration_untrusted: bool, iron_learned: bool, ever_aided: bool, iron_learning: bool,
                     mag_rejected: bool, field_ned_ut: np.ndarray | None) -> str | None:
    """Which heading error the harmonic states carry: "calibration", "iron" or None (off).

    The calibration's (InsParams.mag_harmonic_states): a calibration that states its error, trusted by the heading
    monitor, and no iron learned on top of it (a learned iron's error is the learner's covariance). Else the
    learned iron's (InsParams.iron_harmonic_states): an iron learned or restored, its learning ended (the monitor
    neither learns nor rejects the magnetometer), the filter GNSS-aided at a known WMM field (what the prior is
    projected at)."""
    if (p.mag_harmonic_states and p.mag_enabled and calibration_states_error(p.mag_calibration_sigma_rad)
            and not calibration_untrusted and not iron_learned):
        return "calibration"
    field = field_ned_ut
    if (p.iron_harmonic_states and p.mag_harmonic_states and p.mag_enabled and ever_aided and iron_learned
            and not iron_learning and not mag_rejected and field is not None and field[0] ** 2 + field[1] ** 2 > 0.0):
        return "iron"
    return None


class MagErrorStates:
    """The heading harmonics and the calibration frame's tilt in the kernel (see the module docstring)."""

    def __init__(self, x, P: np.ndarray, par, learned_iron: IronInUse) -> None:
        self._x, self._P, self._par = x, P, par     # the kernel's state record, covariance and parameter record
        self._learned_iron = learned_iron
        self.source: str | None = None    # what the harmonic states carry: "calibration", "iron" or None (off)
        # WMM's declination error is in the calibration's offset prior (c0) since its latest restart
        self._wmm_in_offset = False

    @property
    def harmonics_on(self) -> bool:
        return self._par["mag_harmonics_on"] > 0.0

    def select(self, p, source: str | None, field_ned_ut: np.ndarray | None, declination_rad: float) -> None:
        """Tell the kernel whether the harmonic states carry the heading error (`source`, `harmonics_source`), and
        what they leave as noise; switched on, or to the other error, they start from its prior."""
        par = self._par
        was = self.source
        self.source = source
        par["mag_harmonics_on"] = 0.0 if source is None else 1.0
        par["mag_harmonic_residual_var_rad2"] = p.mag_harmonic_residual_share * p.calibration_sigma_rad ** 2
        if source == "iron":
            par["mag_harmonic_residual_var_rad2"] = p.iron_harmonic_residual_share * _floor_var(p, field_ned_ut)
        if source is not None and source != was:
            self.restart_harmonics(p, field_ned_ut, declination_rad)
        elif source == "calibration" and not self._wmm_in_offset:
            self._add_wmm_declination_error(p, field_ned_ut)     # the WMM field known only now (the first fix)
        self.set_frame_tilt(p)

    def set_frame_tilt(self, p) -> None:
        """Tell the kernel whether the frame-tilt states carry the calibration frame's tilt (mag_frame_tilt.py):
        with the harmonic states, when the calibration states a frame tilt; switched on they start from their
        prior, switched off they are zero with zero variance."""
        s = float(p.mag_calibration_frame_tilt_sigma_rad)
        on = self._par["mag_harmonics_on"] > 0.0 and math.isfinite(s) and s > 0.0
        was_on = self._par["mag_frame_tilt_on"] > 0.0
        self._par["mag_frame_tilt_on"] = 1.0 if on else 0.0
        if on != was_on:
            self.restart_frame_tilt(p)

    def restart(self, p, field_ned_ut: np.ndarray | None, declination_rad: float) -> None:
        """The magnetometer's error states — the heading harmonics and the calibration frame's tilt — back to their
        priors together (start-up, a new calibration, a yaw reset): both are estimated against the heading."""
        self.restart_harmonics(p, field_ned_ut, declination_rad)
        self.restart_frame_tilt(p)

    def restart_frame_tilt(self, p) -> None:
        """The frame-tilt states back to their prior (mag_error_restarts.restart_frame_tilt): the calibration's
        stated tilt while they are on, shared with the accelerometer bias with `mag_frame_tilt_shares_accel_bias`."""
        restart_frame_tilt(self._x, self._P, self._par["mag_frame_tilt_on"] > 0.0,
                           p.mag_calibration_frame_tilt_sigma_rad, p.mag_frame_tilt_shares_accel_bias)

    def restart_harmonics(self, p, field_ned_ut: np.ndarray | None, declination_rad: float) -> None:
        """The harmonic states back to zero with their prior (at start-up, a new calibration, a yaw reset, the iron
        learning ended; mag_error_restarts.py): the calibration's, uncorrelated, or the learned iron's
        (`iron_prior`); without them (`select` off) zero, variance zero: they never move."""
        prior = None
        if self._par["mag_harmonics_on"] > 0.0 and self.source == "iron":
            prior = self.iron_prior(p, field_ned_ut, declination_rad)
        elif self._par["mag_harmonics_on"] > 0.0:
            prior = calibration_harmonics_prior(p.calibration_sigma_rad, p.mag_harmonic_offset_share,
                                                self._frame_tilt_heading_sigma_rad(p))
        restart_harmonics(self._x, self._P, prior)
        self._wmm_in_offset = False
        if prior is not None and self.source == "calibration":
            self._add_wmm_declination_error(p, field_ned_ut)

    def _add_wmm_declination_error(self, p, field_ned_ut: np.ndarray | None) -> None:
        """WMM's declination error at the WMM field (wmm_declination_error.py) added to the calibration's offset
        state c0's variance, once per restart, when `mag_wmm_declination_error` and the field is known: the true
        field's azimuth is off WMM's by it, fixed to north, which a calibration made against WMM's field cannot
        know. Added to a state uncorrelated with it (a new independent error), P stays a covariance."""
        field = field_ned_ut
        if not p.mag_wmm_declination_error or field is None:
            return
        sigma_rad = wmm_declination_sigma_rad(math.hypot(float(field[0]), float(field[1])))
        self._P[core.E_MH, core.E_MH] += sigma_rad ** 2
        self._wmm_in_offset = True

    def _frame_tilt_heading_sigma_rad(self, p) -> float:
        """The share of the calibration's heading error the frame-tilt states carry (rad), with the condition of
        `set_frame_tilt` evaluated here: the harmonics restart before it runs."""
        return frame_tilt_heading_sigma_rad(self._par["mag_harmonics_on"] > 0.0, p.mag_calibration_frame_tilt_sigma_rad,
                                            p.mag_calibration_frame_tilt_heading_sigma_rad)

    def iron_prior(self, p, field_ned_ut: np.ndarray, declination_rad: float) -> np.ndarray:
        """The harmonic states' prior for a learned iron (5×5, rad², mag_error_restarts.iron_harmonics_prior) at the
        WMM field: the learned iron's covariance with its window's yaw share, and the floor's unfused part."""
        yaw = IRON_HARMONIC_YAWS_RAD
        iron = self._learned_iron
        return iron_harmonics_prior(iron.learner.level_heading_rows(field_ned_ut, yaw), yaw - declination_rad,
                                    iron.harmonic_cov(), _floor_var(p, field_ned_ut),
                                    p.iron_harmonic_residual_share, p.mag_harmonic_offset_share)


def _floor_var(p, field_ned_ut: np.ndarray) -> float:
    """`learned_floor_var_rad2` at the WMM field (rad²)."""
    field = field_ned_ut
    return learned_floor_var_rad2(p, float(field[0] ** 2 + field[1] ** 2))
