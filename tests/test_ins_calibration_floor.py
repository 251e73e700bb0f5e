"""ins told a new magnetometer calibration (Ins.set_mag_calibration_sigma, the daemon's one telling at start and at
every hot swap): mid-run, the published yaw σ carries the unconfirmed-yaw floor of the new calibration from the next
sample on (without a trusted calibration, until a GNSS yaw confirms the heading, at least the GNSS yaw bank's 1σ
plus the distance to it; none with a trusted one), not the old calibration's until the next heading check; told
before the first sample, it is the ins built with that calibration. Level turns at 2 m/s (tests/ins_truth.py): at
10 s the GNSS yaw bank is not yet valid, so no GNSS yaw has confirmed the heading."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ins_truth import DECLINATION, gnss_fixes, simulated_run

from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.estimator import ins_core as core
from ahrsd.estimator.gsf_yaw import gsf_output
from ahrsd.estimator.ins import Ins

TRUSTED_RAD = math.radians(0.5)       # below what the heading monitor trusts (DEFAULT_INS_PARAMS)
UNKNOWN = math.nan                    # no calibration's figure: the uncalibrated 20°, untrusted
TELL_AT_S = 10.05
AXES_VAR_RAD2 = math.radians(0.1) ** 2    # InsParams.accel_axes_heading_sigma_rad², added once aided


@pytest.fixture(scope="module")
def boat():
    run = simulated_run("level-turns", 12.0, rate_hz=200.0, seed=15)
    return run, gnss_fixes(run.truth)


class _Feed:
    """The samples and fixes in time order, fed one sample at a time (each fix once the IMU time passes its
    arrival)."""

    def __init__(self, ins, boat):
        self.ins, (self.run, self.fixes) = ins, boat
        self.k = self.fi = 0

    def step(self):
        r, t = self.run, self.run.truth.t_s
        while self.fi < len(self.fixes) and self.fixes[self.fi][0] <= t[self.k]:
            self.ins.update_gnss(self.fixes[self.fi][1])
            self.fi += 1
        e = self.ins.update(make_sample(t[self.k], r.gyro[self.k], r.accel[self.k], r.mag[self.k],
                                        flags=SampleFlags.NEW_DATA))
        self.k += 1
        return e

    def until(self, t_s):
        while self.run.truth.t_s[self.k] < t_s:
            e = self.step()
        return e

    def next_arrives_a_fix(self) -> bool:
        return self.fi < len(self.fixes) and self.fixes[self.fi][0] <= self.run.truth.t_s[self.k]


def _told_mid_run(boat, built_rad, told_rad):
    """The published yaw σ at the sample after telling (no fix arrives with it, so no heading check runs between),
    with what it is worked out from at the telling: the filter's yaw and the GNSS yaw bank's yaw and 1σ."""
    ins = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=built_rad)
    feed = _Feed(ins, boat)
    before = feed.until(TELL_AT_S)
    assert not feed.next_arrives_a_fix()
    assert before.nav is not None and ins._heading.ever_aided
    assert not ins._heading.confirmation.heading_confirmed         # the case in question: no GNSS yaw has confirmed the heading
    # the filter's true yaw: the estimate's is magnetic, and turned by the published slew's offset (`_published`)
    yaw_rad = before.yaw_rad + DECLINATION - ins._published.offset_rad
    gsf_yaw, gsf_sigma, gsf_valid, _ = gsf_output(ins._gsf)
    assert not gsf_valid and math.isfinite(gsf_yaw) and math.isfinite(gsf_sigma)
    ins.set_mag_calibration_sigma(told_rad)
    after = feed.step()
    return before, after, ins, yaw_rad, gsf_yaw, gsf_sigma


def _published(ins, sigma_rad: float) -> float:
    """The published yaw σ for a σ: the accelerometer axes' 0.1° in quadrature (aided), then a yaw slewed by an
    offset (the filter's yaw moved faster than the published one may) adds |offset|/3 (slewed_yaw.py)."""
    return math.sqrt(sigma_rad ** 2 + AXES_VAR_RAD2) + abs(ins._published.offset_rad) / 3.0


def test_untrusted_calibration_told_mid_run_publishes_its_floor_at_the_next_sample(boat):
    """Built with a trusted calibration (no floor), told an unknown one: the next sample's yaw σ is the floor,
    √(σ_gsf² + (ψ_gsf − ψ)²), as published (`_published`)."""
    before, after, ins, yaw, gsf_yaw, gsf_sigma = _told_mid_run(boat, TRUSTED_RAD, UNKNOWN)
    d = (gsf_yaw - yaw + math.pi) % (2.0 * math.pi) - math.pi
    floor = math.sqrt(gsf_sigma ** 2 + d * d)
    own = math.sqrt(ins._P[core.E_YAW, core.E_YAW])
    assert floor > 2.0 * own     # the floor is what is published, and well apart from the filter's own σ
    assert after.sigma_rpy_rad[2] == pytest.approx(_published(ins, floor), rel=1e-9)


def test_trusted_calibration_told_mid_run_drops_the_floor_at_the_next_sample(boat):
    """Built without a calibration (floored), told a trusted one: the next sample's yaw σ is the filter's own,
    √P_ψψ as published (`_published`), no longer the old calibration's floor."""
    before, after, ins, *_ = _told_mid_run(boat, UNKNOWN, TRUSTED_RAD)
    own = math.sqrt(ins._P[core.E_YAW, core.E_YAW])
    assert before.sigma_rpy_rad[2] > 1.1 * own       # the floor was published before the telling
    assert after.sigma_rpy_rad[2] == pytest.approx(_published(ins, own), rel=1e-9)


@pytest.mark.parametrize("sigma_rad", [UNKNOWN, TRUSTED_RAD, 0.1])
def test_told_before_the_first_sample_is_built_with_it(boat, sigma_rad):
    """ins built with the calibration's σ and ins built without it, then told it before the first sample, publish
    the same estimates (bit for bit) and keep the same learned iron: the daemon tells ins once, after building it."""
    built = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=sigma_rad)
    told = Ins(declination_rad=DECLINATION)
    told.set_mag_calibration_sigma(sigma_rad)
    a, b = _Feed(built, boat), _Feed(told, boat)
    for _ in range(len(boat[0].truth.t_s)):
        ea, eb = a.step(), b.step()
        assert np.array_equal(ea.q_wxyz, eb.q_wxyz) and np.array_equal(ea.sigma_rpy_rad, eb.sigma_rpy_rad), ea.t_s
        assert ea.heading_state == eb.heading_state, ea.t_s
    for x, y in zip(built.learned_iron() + built.learned_soft_iron(), told.learned_iron() + told.learned_soft_iron()):
        assert np.array_equal(x, y)
