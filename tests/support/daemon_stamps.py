"""When `ahrsd run` sent (or sampled) what a test received, in the daemon's own clock: CLOCK_MONOTONIC s, the
clock a test process on the same machine shares with it. A rate counted in these stamps does not depend on when
the test got round to receiving (a test process starved on a loaded machine receives late and in bursts).

- `time_usec` / `usec` (HIGHRES_IMU, VISION_POSITION_ESTIMATE): the sample's CLOCK_MONOTONIC time in µs, as is
  (daemon/output_registry.py, `sample_time_monotonic`).
- `time_boot_ms` (ATTITUDE, ATTITUDE_QUATERNION, ...): ms since the daemon started, taken when the message is
  built for sending; the start is the least (arrival − time_boot_ms) over the messages given: a message never
  arrives before it is sent, and the least delivery delay of many on loopback is small beside their period."""

from __future__ import annotations


def stamps_s(received: list[tuple[float, object]]) -> list[float]:
    """The daemon's stamp of each (arrival CLOCK_MONOTONIC s, message) of one type, in CLOCK_MONOTONIC s."""
    if not received:
        return []
    first = received[0][1]
    if hasattr(first, "time_boot_ms"):
        start_s = min(t - m.time_boot_ms * 1e-3 for t, m in received)
        return [start_s + m.time_boot_ms * 1e-3 for _, m in received]
    field = "time_usec" if hasattr(first, "time_usec") else "usec"
    return [getattr(m, field) * 1e-6 for _, m in received]
