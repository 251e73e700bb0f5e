"""Back-stepping levelled by the GNSS-aided estimator (calibration.backstepping_aided) on the simulated boat:
the levelling takes its heading from the magnetometer (heading only), calibrated by the accelerometer-levelled
fit. On a seed on which the aided filter without a magnetometer never acquires its heading from the GNSS
velocity, levelling by that filter (the first behaviour) left the fit 5° off."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ahrsd.calibration.mag.backstepping_aided import fit_backstepping_aided
from ahrsd.calibration.mag.fit_types import MagFitInput
from ahrsd.simulation import DEFAULT_SITE, open_stream, simulate_gnss
from support.sim_heading import heading_error_on_other_attitudes_deg

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

RATE_HZ = 50.0      # the boat's IMU rate here: half the simulator's 100 SPS (the levelling's cost is per sample)


def test_the_levelling_takes_its_heading_from_the_magnetometer_where_gnss_alone_never_finds_it(caplog):
    from ahrsd.calibration.mag.backstepping_aided import aided_roll_pitch

    caplog.set_level(logging.ERROR)
    stream = open_stream("boat", rate_hz=RATE_HZ, seed=8, site=DEFAULT_SITE)
    b = stream.next_block(int(180 * RATE_HZ))
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1008)
    data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
    # without a magnetometer: no heading, the velocity reset (within 30 s on this seed: its first 30 s show it)
    first = b.t_s < 30.0
    *_, alone = aided_roll_pitch(data.select(first), [f for f in fixes if f.t_s < 30.0],
                                 stream.earth_field.declination_rad, smooth=False)
    assert alone.gnss_counters.reset_velocity > 0
    # the filter's own levelling (smooth=False): the heading is what is tested here; the smoother's horizon is
    # test_backstepping_aided_prediction's and test_a_calibrated_accelerometer_lets_the_levelling_split_bias_from_tilt's
    res = fit_backstepping_aided(data, fixes, stream.earth_field, stream.earth_field.declination_rad, smooth=False)
    assert res.ok, res.refused
    passes = res.quality["aided_levelling"]["passes"]
    aided = [p for p in passes if "magnetometer" in p]
    assert [p["magnetometer"] for p in aided] == ["heading only, the previous fit's calibration"] * 2, passes
    assert all(p["healthy"] and p["gnss"]["reset_velocity"] == 0 for p in aided), passes
    err = heading_error_on_other_attitudes_deg(res.model, stream)
    assert np.sqrt(np.mean(err ** 2)) < 0.5, np.sqrt(np.mean(err ** 2))


def test_a_calibrated_accelerometer_lets_the_levelling_split_bias_from_tilt(caplog):
    """On a boat that stays near level, 120 s of GNSS-aided motion barely tells an accelerometer bias from a
    tilt: with the accelerometer exactly calibrated but the filter's default (uncalibrated) bias prior, the
    smoothed horizon is still off; told the bias is known to ACCEL_BIAS_SIGMA_CALIBRATED_M_S2 it is not
    (truth from the simulator, via scipy). Seed 12's default-prior error was mostly the bias the yaw's pull-in
    taught before the first valid GNSS yaw, restarted there since tilt29
    (YawReset.restart_horizontal_accel_bias: 0.72 → 0.07°); seed 19's default prior is still off (at 100 SPS 0.34 → 0.17°, the calibrated 0.105°; at the 50 SPS
    here 0.22°, the calibrated 0.09°: the levelling's cost is per sample)."""
    from ahrsd.calibration.accel_trust import ACCEL_BIAS_SIGMA_CALIBRATED_M_S2
    from ahrsd.calibration.mag.backstepping_aided import aided_roll_pitch
    from ahrsd.calibration.models import AccelModel

    caplog.set_level(logging.ERROR)
    for seed in (12, 19):
        stream = open_stream("boat", rate_hz=RATE_HZ, seed=seed, site=DEFAULT_SITE)
        b = stream.next_block(int(120 * RATE_HZ))
        fixes = simulate_gnss(b, rate_hz=5.0, seed=1000 + seed)
        e = stream.errors
        exact = AccelModel(bias_m_s2=e.accel_bias_m_s2, matrix=np.linalg.inv(e.accel_matrix))
        data = MagFitInput(b.t_s, b.mag_ut, np.ascontiguousarray(exact.apply(b.accel_m_s2)), b.gyro_rad_s)
        q = b.truth_q_wxyz
        ypr = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")
        late = b.t_s > 30.0

        def tilt_rms_deg(sigma):
            r, p, _, _ = aided_roll_pitch(data, fixes, stream.earth_field.declination_rad,
                                          accel_bias_sigma_m_s2=sigma)
            d = np.hypot(np.angle(np.exp(1j * (r - ypr[:, 2]))), p - ypr[:, 1])[late]
            return float(np.degrees(np.sqrt(np.mean(d ** 2))))

        calibrated_prior = tilt_rms_deg(ACCEL_BIAS_SIGMA_CALIBRATED_M_S2)
        assert calibrated_prior < 0.2, (seed, calibrated_prior)
        if seed == 19:     # seed 12's default prior is no longer off (above): only seed 19 is levelled with it
            default_prior = tilt_rms_deg(None)
            assert calibrated_prior < 0.75 * default_prior, (seed, default_prior, calibrated_prior)
            print(f"seed 19: tilt RMS {calibrated_prior:.3f}° calibrated, {default_prior:.3f}° default prior")


def test_the_antenna_lever_arm_reaches_the_levelling_filter(caplog):
    """An antenna 2.2 m from the IMU on a rolling boat moves at tenths of a m/s the IMU does not: the simulator
    puts it there (its own lever-arm kinematics). Levelled without the arm, the filter rejects most fixes'
    velocities; told the arm (`filter_overrides`, what `calibrate mag --lever-arm-m` passes), it fuses them and
    its horizon is closer to the truth (scipy)."""
    from ahrsd.calibration.mag.backstepping_aided import aided_roll_pitch

    caplog.set_level(logging.ERROR)
    arm = (-1.0, 0.0, -2.0)
    stream = open_stream("boat", rate_hz=100.0, seed=4, site=DEFAULT_SITE)   # at 50 SPS, told the arm it
    b = stream.next_block(9000)                                                # still rejects 22 fixes
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1004, lever_arm_m=arm)
    data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
    q = b.truth_q_wxyz
    truth = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]])).as_euler("ZYX")
    late = b.t_s > 30.0
    out = {}
    for name, overrides in (("ignored", None), ("given", {"lever_arm_m": arm})):
        roll, pitch, _, est = aided_roll_pitch(data, fixes, stream.earth_field.declination_rad, smooth=False,
                                               filter_overrides=overrides)
        err = np.hypot(np.angle(np.exp(1j * (roll - truth[:, 2]))), pitch - truth[:, 1])[late]
        out[name] = (est.gnss_counters.rejected_velocity, float(np.degrees(np.sqrt(np.mean(err ** 2)))))
    print(out)
    assert out["ignored"][0] > 100 and out["given"][0] == 0, out
    assert out["given"][1] < 0.5 * out["ignored"][1], out


def test_an_untold_lever_arm_is_named_in_the_warning(caplog, monkeypatch):
    """A levelling that rejects the GNSS velocities says how many and points at the antenna's lever arm; told the
    arm, it rejects none and says nothing. One heading-only pass each: the second is levelled as the first (the
    same overrides, the same rejections), and both run in test_the_levelling_takes_its_heading_from_the_magnetometer."""
    from ahrsd.calibration.mag import backstepping_aided

    monkeypatch.setattr(backstepping_aided, "MAG_HEADING_PASSES", 1)
    caplog.set_level(logging.ERROR)
    arm = (-1.0, 0.0, -2.0)
    stream = open_stream("boat", rate_hz=RATE_HZ, seed=4, site=DEFAULT_SITE)
    b = stream.next_block(int(180 * RATE_HZ))   # 180 s: a full circle
    fixes = simulate_gnss(b, rate_hz=5.0, seed=1004, lever_arm_m=arm)
    data = MagFitInput(b.t_s, b.mag_ut, b.accel_m_s2, b.gyro_rad_s)
    decl = stream.earth_field.declination_rad
    untold = fit_backstepping_aided(data, fixes, stream.earth_field, decl, smooth=False)
    warning = " ".join(untold.quality.get("warnings", []))
    assert "rejected" in warning and "check the antenna's lever arm" in warning, warning
    assert "told 0 0 0 m" in warning, warning
    told = fit_backstepping_aided(data, fixes, stream.earth_field, decl, smooth=False,
                                  filter_overrides={"lever_arm_m": arm})
    told_passes = told.quality["aided_levelling"]["passes"]
    assert [p["magnetometer"] for p in told_passes if "magnetometer" in p] == [
        "heading only, the previous fit's calibration"], told_passes
    assert all(p.get("healthy", True) for p in told_passes), told.quality
    assert not any("lever arm" in w for w in told.quality.get("warnings", []))
