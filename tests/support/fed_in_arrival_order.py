"""Feed a simulated run (bench/vehicle_accuracy.simulate_vehicle) to an `ins` with `step`, each GNSS fix offered before
the first sample at or after its arrival time (`extra["t_rx_s"]`), as the daemon's loop offers them."""

from __future__ import annotations

from ahrsd.core.sample import SampleFlags, make_sample


def stepped(est, run):
    """(t_s, the view `est.step` returned) for each sample of `run`, the fixes offered where they arrive."""
    fi = 0
    for k, t in enumerate(run.t_s):
        while fi < len(run.fixes) and run.fixes[fi].extra["t_rx_s"] <= t:
            est.update_gnss(run.fixes[fi])
            fi += 1
        yield t, est.step(make_sample(t, run.gyro_rad_s[k], run.accel_m_s2[k], run.mag_ut[k],
                                      flags=SampleFlags.NEW_DATA))
