"""A short soak (bench/soak.py, ~25 s): the daemon on the simulated chip at 819.2 SPS under a mixed MAVLink flood
while faults are injected. The 10-minute figures are in docs/reliability.md (`python bench/soak.py`).

The output rates: bench/soak.py asks each within 5 % of its configured rate. A daemon that is not given the CPU
(a loaded 2-core CI machine) wakes late, sends at most one message of a stream per wake and restarts a schedule
that fell CATCH_UP_LIMIT_S behind (daemon/outputs.py): its 50 Hz and 30 Hz streams then fall short without any
fault of its own. So the 5 % holds whenever the daemon counted no late wake of its own (`overruns`); when it did,
a shortfall down to LOADED_RATIO_MIN is put down to the CPU it counted, never more (a halved or dropped stream
still fails), and no stream may run fast either way."""

from __future__ import annotations

import pytest

from bench import soak

pytestmark = pytest.mark.slow     # a long file: started first under pytest-xdist (tests/conftest.py)

# the lowest rate / configured rate accepted from a daemon that counted late wakes (a rate halved by a bug is 0.5)
LOADED_RATIO_MIN = 0.7


def _output_rate_failures(r: dict) -> list[str]:
    """bench/soak.py's rate criterion (the same intervals between arrivals in fault-free seconds), with the
    shortfall a daemon that counted its own late wakes may have."""
    late_wakes = r["stats"].get("service", {}).get("overruns", 0)
    ok, t0, out = set(soak.fault_free_seconds(r)), r["t_start"], []
    for name, hz in soak.CONFIGURED_HZ.items():
        times = r["arrivals"].get(name, [])
        gaps = [b - a for a, b in zip(times, times[1:]) if int(a - t0) in ok and int(b - t0) in ok]
        if not gaps or sum(gaps) <= 0.0:
            out.append(f"{name}: no two messages in fault-free seconds")
            continue
        ratio = len(gaps) / sum(gaps) / hz
        tolerance = soak.RATE_TOLERANCE + 1.0 / (len(gaps) + 1)
        low = min(LOADED_RATIO_MIN, 1.0 - tolerance) if late_wakes else 1.0 - tolerance
        if not low <= ratio <= 1.0 + tolerance:
            out.append(f"{name} at {ratio:.3f} of {hz:g} Hz (accepted {low:.3f}..{1 + tolerance:.3f}; "
                       f"{late_wakes} late wakes counted by the daemon)")
    return out


def test_short_soak_meets_the_criteria(tmp_path):
    # bench/soak.py's CI schedule (every fault kind once, each window as long as there) with the gaps closed up
    faults = ("alarm@2-2.5:bits=SUPPLY_LOW;garbage@3-5:p=0.02;bus_error@5.5-6.5;stall@7.5-8;"
              "stuck_axis@8.5-10.5:axis=mag_x;short_read@11-12:p=0.01;burst_bug@12.5-14.5")
    r = soak.soak(18.0, faults, 300.0, 1, tmp_path, False)
    lines, failed = soak.evaluate(r)
    print("\n".join(lines))
    # every criterion of bench/soak.py but its wall-clock rate one, which _output_rate_failures replaces
    failed = [f for f in failed if "Hz, configured" not in f] + _output_rate_failures(r)
    # every sample the chip produced while read is processed or counted lost (none hidden); a lost sample
    # counted that the chip did not lose must come from a read the daemon reported as ambiguous
    src, pipe = r["stats"]["source"], r["stats"]["pipeline"]
    chip_total = src["chip_last_index_read"] - src["chip_first_index_read"] + 1
    # (+ the indices the reader thread had read but not handed over when the daemon stopped)
    counted = pipe["samples"] + pipe["lost_samples"] + src.get("reader_undelivered_at_close", 0)
    assert counted >= chip_total, lines
    assert counted - chip_total <= src["index_ambiguous_samples"], lines
    assert not failed, "\n".join(lines)
    st = r["stats"]
    # every injected fault kind was seen and counted by the layer that must catch it
    assert st["faults_injected"]["bus_error"] >= 1 and src["sensor_reopens"] >= 1
    assert src["garbage_frames"] >= 1 and src["ea_flags"] >= 1 and src["stuck_axis"] >= 1
    assert src["sensor_lost_in_fault_windows"] > 0
    assert st["links"] and next(iter(st["links"].values()))["rx_malformed"] > 100
