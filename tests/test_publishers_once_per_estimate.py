"""A VISION_POSITION_ESTIMATE is a measurement the autopilot fuses: each endpoint gets it at most once per
estimate. When no new sample arrives between two due times (a loaded machine, a stalled reader), the second due
time sends nothing instead of the same measurement again with the same time stamp; ATTITUDE (for displays) is
sent as before. A due time that sends nothing is counted by the endpoint's schedule (daemon.outputs `held`):
sent + withheld + unchanged = the deadlines served."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ahrsd.core.estimate import AttitudeEstimate
from ahrsd.daemon.counters import ServiceCounters
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.outputs import UNCHANGED, WITHHELD, OutputSchedule
from ahrsd.daemon.publishers import Publishers

VPE = mavlink.MAVLINK_MSG_ID_VISION_POSITION_ESTIMATE
ATT = mavlink.MAVLINK_MSG_ID_ATTITUDE


class _Endpoint:
    """Every output is due at every publish; what was sent is kept."""

    def __init__(self):
        self.sent = []
        self.schedule = SimpleNamespace(due=lambda now: [ATT, VPE], held=lambda mid, now, reason: None)

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True


class _Context:
    declination_rad = 0.0
    trusted = True

    def heading_trusted(self, now):
        return self.trusted

    def time_boot_ms(self, now=None):
        return int((now or 0.0) * 1000.0)

    def sample_time_monotonic(self, t_s):
        return 1000.0 + t_s

    def autopilot_yaw(self, est):
        return est.heading_true_rad, 0, float(est.sigma_rpy_rad[2])

    def autopilot_yaw_withheld(self, est):
        pass


def _estimate(t_s: float) -> AttitudeEstimate:
    z = np.zeros(3)
    return AttitudeEstimate(t_s=t_s, q_wxyz=np.array([1.0, 0.0, 0.0, 0.0]), roll_rad=0.0, pitch_rad=0.0,
                            yaw_rad=0.3, heading_mag_rad=0.3, heading_true_rad=0.3, rate_body_rad_s=z,
                            gyro_bias_rad_s=z, sigma_rpy_rad=np.full(3, math.radians(1.0)))


def _rig(n_endpoints: int = 2):
    endpoints = [_Endpoint() for _ in range(n_endpoints)]
    pipeline = SimpleNamespace(last_estimate=None, last_sample=None)
    health = SimpleNamespace(samples_flowing=lambda now: True, sensor_error=False)
    pubs = Publishers(SimpleNamespace(endpoints=endpoints), pipeline, health, ServiceCounters(), _Context())
    return pubs, pipeline, endpoints


def _of(ep, mid):
    return [m for m in ep.sent if m.get_msgId() == mid]


def test_the_same_estimate_is_never_sent_twice_as_a_vision_estimate_but_each_new_one_is():
    pubs, pipeline, endpoints = _rig()
    pipeline.last_estimate = _estimate(1.0)
    for now in (10.0, 10.033, 10.066):          # three due times, no new sample between them
        pubs.publish(now)
    pipeline.last_estimate = _estimate(1.040)
    pubs.publish(10.1)
    for ep in endpoints:                        # each endpoint gets each estimate once
        usecs = [m.usec for m in _of(ep, VPE)]
        assert usecs == [int((1000.0 + 1.0) * 1e6), int((1000.0 + 1.040) * 1e6)]
        assert len(_of(ep, ATT)) == 4           # a display output is not limited


def test_no_attitude_output_while_the_sensor_is_stalled_or_failed():
    """docs/reliability.md: a data-ready stall or a sensor error stops the feed (CRITICAL) and it resumes by
    itself. The last estimate stays in the pipeline, but neither ATTITUDE nor VISION_POSITION_ESTIMATE is built
    from it while samples do not flow or the sensor reports an error."""
    pubs, pipeline, endpoints = _rig(1)
    flowing = [False]
    pubs.health = SimpleNamespace(samples_flowing=lambda now: flowing[0], sensor_error=False)
    pipeline.last_estimate = _estimate(1.0)
    pubs.publish(10.0)                          # stalled
    pubs.health.sensor_error = True
    flowing[0] = True
    pubs.publish(10.1)                          # flowing, but the sensor reports an error
    assert endpoints[0].sent == []
    pubs.health.sensor_error = False
    pubs.publish(10.2)                          # resumed: the feed again
    assert len(_of(endpoints[0], ATT)) == 1 and len(_of(endpoints[0], VPE)) == 1


def test_every_deadline_is_sent_or_counted_held_with_its_reason():
    """A 32 Hz VISION_POSITION_ESTIMATE on a real schedule, woken every 1/128 s for 1 s (binary-exact times: the
    deadlines j/32 s, j = 0 … 32, are served at exactly those wakes). New estimates arrive at 64 Hz but none from
    0.25 to 0.5 s (a reader handing its samples over late), and the heading is not trusted from 0.625 to 0.875 s.
    Worked by hand: deadlines 9–15 have no new estimate (unchanged, 7), 20–27 an untrusted heading (withheld, 8),
    the other 18 are sent; the held ones are kept as two runs with their times."""
    pubs, pipeline, endpoints = _rig(1)
    ep = endpoints[0]
    ep.schedule = OutputSchedule({VPE: 32.0})
    for k in range(129):
        now = k / 128
        pubs.context.trusted = not 80 <= k < 112
        if k % 2 == 0 and not 32 <= k < 64:
            pipeline.last_estimate = _estimate(now)
        pubs.publish(now)
    s = ep.schedule
    assert len(_of(ep, VPE)) == 18
    assert s.withheld_slots()[VPE] == 8 and s.unchanged_slots()[VPE] == 7
    assert [(h.reason, h.first_s, h.last_s, h.count) for h in s.held_runs] == [
        (UNCHANGED, 36 / 128, 60 / 128, 7), (WITHHELD, 80 / 128, 108 / 128, 8)]
