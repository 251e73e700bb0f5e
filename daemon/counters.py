"""The daemon's own counters (the stats file's "service" section). One instance, shared: each part adds to
its own fields only."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ServiceCounters:
    wakes: int = 0               # sample reader
    overruns: int = 0            # sample reader: wakes that started after their deadline by more than one period
    late_samples: int = 0        # sample reader: samples used more than LATE_AFTER_S after they became ready
    driver_errors: int = 0       # sample reader: bus failures (and runs of corrupt frames) that failed the sensor
    frame_errors: int = 0        # sample reader: single corrupt frames rejected by the driver
    unsigned_refused: int = 0    # parameter protocol: PARAM_SET refused unsigned (commands: the router counts)
    published: int = 0          # publishers
    statustext_suppressed: int = 0  # outbound: non-critical STATUSTEXTs dropped by the rate limit (flooding peer)
    timesync_answered: int = 0   # inbound: TIMESYNC requests answered, within their sender's rate limit
    timesync_refused: int = 0    # inbound: TIMESYNC requests not answered, beyond their sender's rate limit
