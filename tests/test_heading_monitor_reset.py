"""When the heading monitor resets the yaw to the GNSS yaw (estimator/heading_monitor.py `_emergency_reset`; EKF3's
realignYawGPS): only when all of these hold — the GNSS yaw is valid and beyond the gate (3σ of yaw and GNSS yaw
together) from the filter's, the filter's own velocity fusion fails (its low-passed NIS above
`reset_velocity_nis` = 6), and the magnetometer cannot hold the heading (rejected, absent, or its slowly varying
error above `trusted_sigma_rad` = 3°). A trusted magnetometer that agrees with the filter keeps the heading
whatever the GNSS yaw says (a bank confidently wrong in a coordinated turn must not turn it); a filter whose
velocities still fit keeps it too.

Worked cases: the filter at yaw 0 ± 0.3°, the GNSS yaw 40° ± 2° (13× the gate's 3·√(0.3² + 2²) ≈ 6.1°), one
check every 0.2 s. The expectations are the rule above, not the monitor's arithmetic."""

from __future__ import annotations

import math

import pytest

from ahrsd.estimator.heading_monitor import HeadingMonitor

D = math.radians
GSF_YAW, GSF_VAR = D(40.0), D(2.0) ** 2
YAW_VAR = D(0.3) ** 2
FAILING_NIS = 50.0       # the filter's velocities do not fit its heading
FITTING_NIS = 2.0        # they do (a 2–3 dof NIS near its mean)


def resets(monitor, checks, *, mag_yaw_rad, mag_sigma_rad, velocity_nis, t0=0.0):
    """The checks (of `checks`, 0.2 s apart) at which the monitor decided a reset, with the yaw it reset to."""
    out = []
    for i in range(checks):
        d = monitor.check(t0 + 0.2 * i, 0.0, YAW_VAR, mag_yaw_rad, mag_sigma_rad ** 2, GSF_YAW, GSF_VAR, True,
                          True, velocity_nis, mag_sigma_rad ** 2)
        if d.reset_yaw_to_rad is not None:
            out.append((i, d.reset_yaw_to_rad))
    return out


def test_a_trusted_magnetometer_that_agrees_keeps_the_heading_against_a_failing_velocity_fit():
    """The magnetometer (0.5° error) agrees with the filter; the GNSS yaw 40° away, the velocity fit failing for
    20 s: no reset, and the magnetometer is not rejected for the GNSS yaw's disagreement alone."""
    mon = HeadingMonitor(D(0.5))
    assert resets(mon, 100, mag_yaw_rad=0.0, mag_sigma_rad=D(0.5), velocity_nis=FAILING_NIS) == []
    assert not mon.mag_rejected and mon.resets == 0


@pytest.mark.parametrize("mag_yaw_rad, mag_sigma_rad", [(math.nan, D(0.5)), (0.0, D(5.0))],
                         ids=["no magnetometer", "magnetometer error 5 deg"])
def test_without_a_trusted_magnetometer_a_failing_velocity_fit_resets_to_the_gnss_yaw(mag_yaw_rad, mag_sigma_rad):
    """No magnetometer heading, or one whose error (5°) is above the trusted 3°: the first check resets the yaw
    to the GNSS yaw; the next is `reset_spacing_s` = 20 s later at the earliest (checks 0.2 s apart: index 100)."""
    mon = HeadingMonitor(D(0.5))
    got = resets(mon, 110, mag_yaw_rad=mag_yaw_rad, mag_sigma_rad=mag_sigma_rad, velocity_nis=FAILING_NIS)
    assert got[0] == (0, pytest.approx(GSF_YAW))
    assert [i for i, _ in got] == [0, 100]


def test_no_reset_while_the_filters_velocities_fit_its_heading():
    """No magnetometer, the GNSS yaw 40° away, but the velocity fit passes (NIS 2, below 6) for 20 s: no reset.
    Once it fails (NIS 50) the low-passed NIS passes 6 at its n-th failing check (τ = 5 s: 2 + 48·(1 − e^(−0.2n/5))
    > 6 from n = 3), and that check resets the yaw."""
    mon = HeadingMonitor(D(0.5))
    assert resets(mon, 100, mag_yaw_rad=math.nan, mag_sigma_rad=D(0.5), velocity_nis=FITTING_NIS) == []
    got = resets(mon, 10, mag_yaw_rad=math.nan, mag_sigma_rad=D(0.5), velocity_nis=FAILING_NIS, t0=20.0)
    n = next(n for n in range(1, 10) if 2.0 + 48.0 * (1.0 - math.exp(-0.2 * n / 5.0)) > 6.0)
    assert n == 3
    assert got and got[0][0] == n - 1 and got[0][1] == pytest.approx(GSF_YAW)


@pytest.mark.parametrize("innovation_deg, rejected", [(0.5, False), (0.7, True)])
def test_the_gnss_yaw_rejects_the_magnetometer_only_with_an_innovation_beyond_its_1_sigma(innovation_deg, rejected):
    """The GNSS yaw 40° from the magnetometer's (beyond the gate of 3·√(2² + 0.5²)° = 6.2°) rejects it only when
    the filter's own innovation is beyond 1σ too: √(0.3² + 0.5²) = 0.58°. 0.5° (within the 3σ gate of 1.75° by
    itself): never rejected in 20 s; 0.7°: rejected at the third check (`reject_checks` = 3)."""
    mon = HeadingMonitor(D(0.5))
    decisions = [mon.check(0.2 * i, 0.0, YAW_VAR, D(innovation_deg), D(0.5) ** 2, GSF_YAW, GSF_VAR, True, True,
                           FITTING_NIS, D(0.5) ** 2) for i in range(100)]
    used = [d.mag_use for d in decisions]
    if rejected:
        assert used[:2] == [True, True] and not used[2]
    else:
        assert all(used) and not mon.mag_rejected
