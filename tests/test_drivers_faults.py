"""Every injected fault ends as a typed error or a counted, flagged rejection; never a crash, never a wrong
sample passed on as good."""

import math

import numpy as np
import pytest

from ahrsd.drivers import registers as R
from ahrsd.drivers.adis16405 import Adis16405
from ahrsd.drivers.errors import BusError, DriverError, FrameError, ShortRead
from ahrsd.drivers.faults import FaultKind, FaultPlan
from ahrsd.core.sample import SampleFlags
from ahrsd.drivers.simulated import SimulatedAdis16405
from sim_streams import FixedStream

G0 = R.STANDARD_GRAVITY_M_S2
BAD = (SampleFlags.GYRO_INVALID | SampleFlags.ACCEL_INVALID | SampleFlags.MAG_INVALID | SampleFlags.STALE)


def started(stream=None, plan=None):
    plan = plan if plan is not None else FaultPlan(seed=7)
    stream = stream or FixedStream(np.radians([0.3, -0.2, 0.1]), [0.0, 0.5, -G0], [20.0, 1.0, 45.0],
                                   noise_std=(math.radians(0.5), 0.03, 0.2), seed=3)
    chip = SimulatedAdis16405(stream, faults=plan)
    imu = Adis16405(chip)
    imu.start()
    return chip, imu, plan


def assert_exact(sample, chip):
    """The sample carries exactly what the chip's output registers hold (nothing corrupted slipped through)."""
    lsb = chip.output_lsb
    assert np.array_equal(np.rint(sample.gyro_rad_s / R.GYRO_RAD_S_PER_LSB), lsb[1:4])
    assert np.array_equal(np.rint(sample.accel_m_s2 / R.ACCEL_M_S2_PER_LSB), lsb[4:7])
    assert np.array_equal(np.rint(sample.mag_ut / R.MAG_UT_PER_LSB), lsb[7:10])


def read_all(imu, n):
    """Read n times; return (samples, errors by type) — any other exception fails the test."""
    samples, errors = [], {}
    for _ in range(n):
        try:
            samples.append(imu.read_sample())
        except DriverError as exc:
            errors[type(exc).__name__] = errors.get(type(exc).__name__, 0) + 1
    return samples, errors


def test_fault_plan_schedules_and_toggles():
    plan = FaultPlan(seed=1)
    f = plan.add("alarm", start_sample=5, stop_sample=8)
    assert [bool(plan.active(FaultKind.ALARM, i)) for i in range(10)] == [False] * 5 + [True] * 3 + [False] * 2
    f.enabled = False
    assert not plan.active(FaultKind.ALARM, 6) and not plan
    plan.enable("alarm")
    assert plan.active(FaultKind.ALARM, 6) and plan.injected["alarm"] == 4
    with pytest.raises(ValueError):
        plan.add("stuck_axis", axis=9)
    with pytest.raises(ValueError):
        plan.add("no_such_fault")


def test_alarm_sets_ea_and_the_diag_bits_are_named_and_counted():
    chip, imu, plan = started()
    plan.add("alarm", start_sample=chip.sample_index + 3, stop_sample=chip.sample_index + 6,
             diag_bits=int(R.DiagStat.ALARM2 | R.DiagStat.SUPPLY_HIGH))
    samples, errors = read_all(imu, 10)
    assert not errors
    alarmed = [s for s in samples if s.flags & SampleFlags.ALARM]
    assert len(alarmed) == 3 == imu.counters["ea_flags"]
    assert all(s.diag_stat == R.DiagStat.ALARM2 | R.DiagStat.SUPPLY_HIGH for s in alarmed)
    assert imu.counters["diag_alarm2"] == 3 and imu.counters["diag_supply_high"] == 3
    assert samples[-1].diag_stat == 0 and not samples[-1].flags & SampleFlags.ALARM


def test_self_test_axis_failure_in_operation_invalidates_that_sensor():
    chip, imu, plan = started()
    plan.add("alarm", start_sample=chip.sample_index + 1, diag_bits=int(R.DiagStat.YACCL_SELF_TEST))
    s = imu.read_sample()
    assert s.flags & SampleFlags.ACCEL_INVALID and not s.flags & SampleFlags.GYRO_INVALID


def test_stuck_axis_is_detected_counted_and_flagged():
    chip, imu, plan = started()
    window = int(round(0.5 * imu.sample_rate_hz))
    start = chip.sample_index + 50
    plan.add("stuck_axis", axis=4, start_sample=start, stop_sample=start + 2 * window)
    samples, errors = read_all(imu, 50 + 3 * window)
    assert not errors
    flagged = [i for i, s in enumerate(samples) if s.flags & SampleFlags.ACCEL_INVALID]
    assert imu.counters["stuck_axis"] == 1
    assert flagged and flagged[0] >= 49 + window - 1 and flagged[-1] < 50 + 2 * window + 1
    assert not any(s.flags & SampleFlags.GYRO_INVALID for s in samples)
    assert not samples[-1].flags & SampleFlags.ACCEL_INVALID            # recovered when the axis moves again


def test_constant_ideal_signals_are_not_called_stuck():
    chip = SimulatedAdis16405(FixedStream())
    imu = Adis16405(chip)
    imu.start()
    samples, _ = read_all(imu, 1000)
    assert imu.counters["stuck_axis"] == 0 and not any(s.flags & BAD for s in samples)


def test_injected_saturation():
    chip, imu, plan = started()
    plan.add("saturation", axis=7, sign=-1, start_sample=chip.sample_index + 2, stop_sample=chip.sample_index + 4)
    samples, errors = read_all(imu, 6)
    sat = [s for s in samples if s.flags & SampleFlags.MAG_SATURATED]
    assert len(sat) == 2 and all(s.flags & SampleFlags.MAG_INVALID for s in sat)
    assert all(s.mag_ut[1] == pytest.approx(-250.0) for s in sat)
    assert imu.counters["saturations"] == 2


def test_garbage_is_rejected_and_nothing_wrong_passes():
    chip, imu, plan = started()
    plan.add("garbage", start_sample=chip.sample_index + 1, probability=0.3)
    good = 0
    rejected = 0
    for _ in range(3000):
        try:
            s = imu.read_sample()
        except FrameError:
            rejected += 1
            continue
        if s.flags & SampleFlags.NEW_DATA and not s.flags & BAD:
            assert_exact(s, chip)
            good += 1
    injected = plan.injected["garbage"]
    assert injected > 700 and good > 1800
    # every injected garbage frame was caught (an ND/EA or supply or range check) or verified by a register read
    assert rejected == imu.counters["garbage_frames"] + imu.counters["short_reads"]
    assert rejected >= injected - imu.counters["burst_bug_recovered"] - imu.counters["burst_bug_unverified"] - 5


def test_burst_bug_small_negative_rate_recovered_by_register_read():
    # EZ 81805: -0.4 °/s (0xBFF8) comes back as 0x9FF8 (+409.2 °/s) in the burst
    chip, imu, plan = started(FixedStream(np.radians([-0.4, 0.0, 0.0]), [0, 0, -G0], [20, 0, 45]))
    plan.add("burst_bug", start_sample=chip.sample_index + 1)
    samples, errors = read_all(imu, 200)
    assert not errors
    assert all(s.gyro_rad_s[0] == pytest.approx(math.radians(-0.4)) for s in samples)
    assert all(s.flags & SampleFlags.BURST_BUG_RECOVERED for s in samples)
    assert imu.counters["burst_bug_recovered"] == 200 == plan.injected["burst_bug"]
    assert not any(s.flags & SampleFlags.GYRO_INVALID for s in samples)


@pytest.mark.parametrize("rate_dps", [-250.0, -150.0, -60.0])
def test_burst_bug_large_negative_rates_caught_by_the_consistency_check(rate_dps):
    # below -204.8 °/s the buggy value (+8192 LSB) is inside the ±300 °/s range: only the jump gives it away
    chip, imu, plan = started(FixedStream(np.radians([rate_dps, 1.0, 0.0]), [0, 0, -G0], [20, 0, 45],
                                          noise_std=(math.radians(0.5), 0.0, 0.0)))
    plan.add("burst_bug", start_sample=chip.sample_index + 1, probability=0.5)
    samples, errors = read_all(imu, 400)
    assert not errors
    assert all(abs(math.degrees(s.gyro_rad_s[0]) - rate_dps) < 5 for s in samples)
    assert imu.counters["burst_bug_recovered"] == plan.injected["burst_bug"] > 150


def test_genuine_fast_positive_rate_is_kept():
    chip, imu, _ = started(FixedStream(np.radians([250.0, 0, 0]), [0, 0, -G0], [20, 0, 45]))
    s = [imu.read_sample() for _ in range(50)]
    assert all(x.gyro_rad_s[0] == pytest.approx(math.radians(250.0)) for x in s)
    assert imu.counters["burst_bug_recovered"] == 0 and imu.counters["burst_bug_unverified"] == 0


def test_device_gone_raises_bus_error_then_recovers():
    chip, imu, plan = started()
    fault = plan.add("bus_error", start_sample=chip.sample_index + 1)
    with pytest.raises(BusError, match="gone"):
        imu.read_sample()
    assert imu.counters["bus_errors"] == 1
    with pytest.raises(BusError):
        imu.read_register(R.PRODUCT_ID)
    fault.enabled = False
    assert imu.read_sample().flags & SampleFlags.NEW_DATA


def test_short_reads_are_typed_and_counted():
    chip, imu, plan = started()
    plan.add("short_read", start_sample=chip.sample_index + 1, probability=0.5)
    samples, errors = read_all(imu, 200)
    assert errors.keys() == {"ShortRead"} and errors["ShortRead"] == imu.counters["short_reads"] > 50
    assert issubclass(ShortRead, FrameError)
    for s in samples:
        assert s.flags & SampleFlags.NEW_DATA


def test_data_ready_stall_gives_stale_samples():
    chip, imu, plan = started()
    plan.add("stall", start_sample=chip.sample_index + 3, stop_sample=chip.sample_index + 10)
    samples, errors = read_all(imu, 15)
    assert not errors
    stale = [s for s in samples if s.flags & SampleFlags.STALE]
    assert len(stale) == 7 == imu.counters["stale"]
    assert all(s.counter == samples[1].counter and s.t_s == samples[1].t_s for s in stale)
    assert samples[-1].flags & SampleFlags.NEW_DATA and samples[-1].counter == samples[1].counter + 6


def test_mixed_faults_never_crash():
    chip, imu, plan = started()
    k = chip.sample_index + 1
    for kind in ("garbage", "short_read", "bus_error", "burst_bug", "stall", "alarm"):
        plan.add(kind, start_sample=k, probability=0.05)
    plan.add("stuck_axis", axis=2, start_sample=k + 100, stop_sample=k + 1000)
    samples, errors = read_all(imu, 3000)
    assert set(errors) <= {"FrameError", "ShortRead", "BusError"}
    assert len(samples) > 2000
    c = imu.counters
    assert sum(errors.values()) == c["garbage_frames"] + c["short_reads"] + c["bus_errors"]
