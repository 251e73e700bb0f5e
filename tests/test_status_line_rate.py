"""The status line shows no rate until one has been measured: the first start read "0.0 SPS | … | ACTIVE" for the
first second, a rate of zero the sensor never had; a sensor that stops still reads 0.0."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.housekeeping import HealthReport
from ahrsd.daemon.status_line import format_status

LINE = dict(estimate=None, state=0, samples={"missed": 0, "late": 0, "corrupt": 0},
            link={"tx": 0, "rx": 0, "bad": 0}, gnss=None, autopilot=AutopilotState())


def test_no_rate_yet_reads_dashes_and_a_stopped_sensor_reads_zero():
    assert format_status(rate_hz=None, **LINE).startswith("    -- SPS | ")
    assert format_status(rate_hz=0.0, **LINE).startswith("   0.0 SPS | ")
    assert format_status(rate_hz=819.24, **LINE).startswith(" 819.2 SPS | ")


def test_the_rate_is_unmeasured_until_one_window_has_passed():
    counts = SimpleNamespace(samples=0)
    report = HealthReport(SimpleNamespace(), SimpleNamespace(), SimpleNamespace(), counts,
                          watchdog_interval_s=None, start=100.0, cpu_clock=lambda: 0.0)
    assert report.measured_rate_hz is None
    report._update_load(101.0)                  # the first tick opens the window
    assert report.measured_rate_hz is None
    counts.samples = 819
    report._update_load(102.0)
    assert report.measured_rate_hz == 819.0
    report._update_load(103.0)                  # no sample in the second window: the sensor stopped
    assert report.measured_rate_hz == 0.0


def test_the_first_cpu_load_is_measured_from_the_start_on_the_clock_the_report_is_given():
    """The first load window opens at `start` (the housekeeping clock's time), not at a clock read inside: 0.25 s
    of CPU over the first second on a stepped clock is 250 ‰."""
    cpu_s = [0.0]
    report = HealthReport(SimpleNamespace(), SimpleNamespace(), SimpleNamespace(), SimpleNamespace(samples=0),
                          watchdog_interval_s=None, start=100.0, cpu_clock=lambda: cpu_s[0])
    cpu_s[0] = 0.25
    report._update_load(101.0)
    assert report.load_permille == 250
    cpu_s[0] = 1.25
    report._update_load(103.0)
    assert report.load_permille == 500


def test_the_rate_is_counted_on_the_sensors_clock_not_on_the_arrivals():
    """A 204.8 SPS chip whose blocks arrive in a burst (a busy machine: the reader's hand-overs, the kernel
    buffer's reads) read 272.8 SPS over a second of the event loop's clock; the rate is the samples delivered over
    the span of their own time stamps. A lost sample still lowers it (not delivered, its time passes)."""
    counts = SimpleNamespace(samples=0)
    t_last = [None]
    report = HealthReport(SimpleNamespace(), SimpleNamespace(), SimpleNamespace(), counts,
                          watchdog_interval_s=None, start=100.0, cpu_clock=lambda: 0.0,
                          last_sample_t_s=lambda: t_last[0])
    period_s = 1.0 / 204.8
    made = [0]                                   # samples the chip has made: sample k is stamped k periods on

    def deliver(n: int, lost: int = 0) -> None:
        made[0] += n + lost
        counts.samples += n
        t_last[0] = (made[0] - 1) * period_s

    deliver(1)
    report._update_load(101.0)                  # opens the window
    deliver(150)
    report._update_load(102.0)                  # a late second: 150 samples arrived
    assert report.measured_rate_hz == pytest.approx(204.8, rel=1e-12)
    deliver(279)
    report._update_load(103.0)                  # the burst that catches up: 279 arrived in one second
    assert report.measured_rate_hz == pytest.approx(204.8, rel=1e-12)
    deliver(203, lost=2)                        # two samples the chip made and nobody read
    report._update_load(104.0)
    assert report.measured_rate_hz == pytest.approx(203 / 205 * 204.8, rel=1e-12)
    report._update_load(105.0)                  # nothing since: the sensor stopped
    assert report.measured_rate_hz == 0.0
