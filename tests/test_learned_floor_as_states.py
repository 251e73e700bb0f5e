"""Once a learned iron's error is carried as the five harmonic states (the learning ended), the learned magnetometer's
floor — the field error no learned iron explains, `iron_unmodelled_ut` over the horizontal field — is carried in the
states' prior and not fused as noise lasting `iron_learned_tau_s` (session 41, highlat): what the floor stands for
(the WMM's error or a local anomaly, fixed in the NED frame; the soft iron's third column times the vertical field on a
level vehicle, fixed to the body) is a function of the heading, which a straight leg does not average away.

Checked on the filter's own MagErrorStates with the default InsParams, at Rio de Janeiro's field (the in-sample
place traced in docs/gnss.md "(highlat)"): the kernel's noise share of the floor is zero, and the prior's heading
variance at every level heading is at least the floor, worked out here by hand from the field (1 µT / H)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ahrsd.estimator import ins_core as core
from ahrsd.estimator.ins import InsParams
from ahrsd.estimator.iron_in_use import IronInUse
from ahrsd.estimator.mag_error_states import MagErrorStates

# The simulator's WMM field at Rio de Janeiro (−22.91, −43.17), rounded (µT, NED): north 15.57, east −6.61, down
# −15.78 (a weak total field, the South Atlantic anomaly); H² = 15.57² + 6.61² = 286.11 µT², so the floor of 1 µT
# is 1/√286.11 rad = 3.39°.
FIELD_NED_UT = np.array([15.57, -6.61, -15.78])
FLOOR_VAR_RAD2 = 1.0 ** 2 / (15.57 ** 2 + 6.61 ** 2)
HARMONICS = slice(core.E_MH, core.E_MF)


def _states(params: InsParams):
    par = params.to_array(-0.38)[0]
    x = np.zeros(1, core.INS_STATE_DTYPE)[0]
    P = np.eye(core.N_ERR) * 1e-6
    iron = IronInUse(params.iron_prior_sigma_ut, params.iron_soft_prior)
    return MagErrorStates(x, P, par, iron), par, P


def _heading_var(prior: np.ndarray, psi: float) -> float:
    h = np.array([1.0, math.cos(psi), math.sin(psi), math.cos(2 * psi), math.sin(2 * psi)])
    return float(h @ prior @ h)


def test_the_default_floor_is_not_fused_as_noise_once_the_iron_is_carried_as_states():
    params = InsParams()
    states, par, P = _states(params)
    states.select(params, "iron", FIELD_NED_UT, -0.38)
    assert par["mag_harmonics_on"] == 1.0
    assert par["mag_harmonic_residual_var_rad2"] == 0.0       # nothing of the floor as 3 s noise
    prior = P[HARMONICS, HARMONICS]
    for psi in np.linspace(0.0, 2.0 * math.pi, 9):
        # the learner's prior covariance adds to it; the floor alone is the least the states must carry
        assert _heading_var(prior, psi) >= FLOOR_VAR_RAD2 * (1.0 - 1e-9)


def test_the_floor_goes_to_the_noise_only_as_far_as_the_share_says():
    """The share is still a parameter: at 1 (session 26's choice) the whole floor is fused as noise, none in the
    prior; the prior then is the learner's alone, smaller than with the floor by the floor at every heading."""
    params = InsParams(iron_harmonic_residual_share=1.0)
    states, par, P = _states(params)
    states.select(params, "iron", FIELD_NED_UT, -0.38)
    assert par["mag_harmonic_residual_var_rad2"] == pytest.approx(FLOOR_VAR_RAD2, rel=1e-12)
    noise_prior = P[HARMONICS, HARMONICS].copy()
    default = InsParams()
    states0, _, P0 = _states(default)
    states0.select(default, "iron", FIELD_NED_UT, -0.38)
    for psi in np.linspace(0.0, 2.0 * math.pi, 9):
        assert _heading_var(P0[HARMONICS, HARMONICS], psi) - _heading_var(noise_prior, psi) == pytest.approx(
            FLOOR_VAR_RAD2, rel=1e-9)
