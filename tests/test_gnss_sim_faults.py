"""The daemon's simulated receiver with the [gnss] sim_outage_* / sim_glitch_* faults: the keys are validated,
an outage makes the daemon's GNSS task report "outage" (STATUSTEXT, the estimate's flags), and a glitch is
rejected and counted (the estimator's innovation gate, or the validator for an invalid position).

The whole daemon path below the event loop runs: config → gnss_backend_for → GnssTask → ScenarioGnssReceiver writing UBX into a
pty → SerialGnssSource → GnssFixValidator → Ins, on a simulated clock stepped here faster than real time (the
receiver's writer thread replaced by its own `write_due`, called at each step).
"""

from __future__ import annotations

import select
import tomllib

import pytest

from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.daemon.config import ConfigError, parse_config
from ahrsd.daemon.gnss_task import GnssTask, gnss_backend_for
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import simulate

RATE_HZ = 100.0
SCENARIO, SEED = "car", 2


class Clock:
    t = 0.0

    def __call__(self) -> float:
        return self.t


class Pipeline:
    """The estimator hook of the GnssTask: the aided filter and its latest estimate."""

    def __init__(self):
        self.estimator, self.last_estimate = Ins(), None


def _config(gnss: str):
    return parse_config(tomllib.loads(f'[sensor]\nsource = "sim"\nscenario = "{SCENARIO}"\nseed = {SEED}\n'
                                      f'[gnss]\nsource = "sim"\n{gnss}'))


def _run(gnss: str, seconds: float):
    """Step the simulated daemon for `seconds`; return the task, the STATUSTEXTs and the estimate flags per step."""
    clock = Clock()
    config = _config(gnss)
    pipeline, texts = Pipeline(), []
    backend = gnss_backend_for(config.gnss, clock=clock, sensor=config.sensor, scenario_clock=clock,
                              sim_writer_thread=False)     # stepped here: write_due
    task = GnssTask(backend, config.gnss, clock=clock, estimator=pipeline,
                    statustext=lambda severity, text: texts.append((clock.t, text)))
    task.open()
    receiver = backend.receiver
    block = simulate(SCENARIO, seconds, rate_hz=RATE_HZ, seed=SEED, errors="ideal")
    est = pipeline.estimator
    flags, aiding = [], []
    try:
        for k, t in enumerate(block.t_s):
            clock.t = float(t)
            before = receiver.fixes_written
            receiver.write_due()
            if receiver.fixes_written > before:      # the pty delivers in the kernel's own time: wait for it
                select.select([backend.fileno()], [], [], 2.0)
            task.poll()
            e = est.update(make_sample(t, block.gyro_rad_s[k], block.accel_m_s2[k], block.truth_mag_ut[k],
                                       flags=SampleFlags.NEW_DATA))
            pipeline.last_estimate = e
            if k % 10 == 0:
                task.tick(float(t))
            flags.append(int(e.flags))
            aiding.append((float(t), task.aiding()))
    finally:
        task.close()
    return task, texts, block.t_s, flags, aiding


def test_an_outage_is_reported_and_a_glitch_rejected_and_counted():
    task, texts, t, flags, aiding = _run("sim_outage_start_s = 6.0\nsim_outage_s = 9.0\n"
                                                        "sim_glitch_every_s = 4.0\n", 20.0)
    stats = task.stats()
    assert "outage 6–15 s" in task.description and "position_jump every 4 s" in task.description
    # the receiver said nothing from 6 to 15 s: 45 of its 100 epochs are missing
    assert 50 <= stats["sim_receiver"]["fixes_written"] <= 55, stats
    # glitches every 4 s: at 4 s and 16 s (8 s and 12 s fall in the outage, 20 s after the end)
    assert stats["sim_receiver"]["glitches_written"] == 2, stats
    assert stats["validator"]["accepted"] == stats["sim_receiver"]["fixes_written"]
    assert stats["estimator"]["rejected_position"] == 2, stats          # the 50 m jumps: the innovation gate
    by_time = dict(aiding)
    assert by_time[5.0] == "aided"
    assert all(a == "outage" for tt, a in aiding if 8.6 <= tt < 15.0), [a for tt, a in aiding if 8.6 <= tt < 15]
    assert by_time[19.0] == "aided"                                       # back after the outage
    outage = EstimateFlags.GNSS_OUTAGE
    assert all(f & outage for tt, f in zip(t, flags) if 8.6 <= tt < 15.0)
    shown = [txt for _, txt in texts]
    # what the ground station sees: the receiver went quiet (the link state), and ins dead-reckons
    assert "ahrsd: GNSS silent, outage" in shown, texts
    assert shown[-1] == "ahrsd: GNSS 3D 12 sats, aided", texts


def test_outage_with_no_fix_solutions_and_invalid_positions():
    task, texts, t, flags, aiding = _run("sim_outage_start_s = 3.0\nsim_outage_s = 9.0\n"
                                                        "sim_outage_no_fix = true\nsim_glitch_every_s = 2.0\n"
                                                        'sim_glitch_kind = "nan"\n', 14.0)
    v = task.stats()["validator"]
    assert 44 <= v["no_fix"] <= 46, v                          # the receiver kept sending NO_FIX for 9 s
    assert v["nonfinite_field"] == 2, v                        # the glitches at 2 s and 12 s (invalidLlh)
    assert dict(aiding)[6.0] == "outage"
    assert "ahrsd: GNSS no fix, outage" in [txt for _, txt in texts], texts


@pytest.mark.parametrize("gnss, key", [
    ("sim_outage_s = -1.0", "gnss.sim_outage_s"),
    ("sim_outage_start_s = nan", "gnss.sim_outage_start_s"),
    ('sim_outage_s = "10"', "gnss.sim_outage_s"),
    ("sim_outage_no_fix = 1", "gnss.sim_outage_no_fix"),
    ("sim_glitch_every_s = 0.2", "gnss.sim_glitch_every_s"),
    ('sim_glitch_kind = "teleport"', "gnss.sim_glitch_kind"),
    ('sim_glitch_kind = "time_backwards"', "gnss.sim_glitch_kind"),
    ("sim_glitch_magnitude = -5", "gnss.sim_glitch_magnitude"),
    ("sim_glitch_magnitude = 1e6", "gnss.sim_glitch_magnitude"),
])
def test_bad_sim_fault_values_are_refused_by_name(gnss, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        _config(gnss + "\n")


def test_sim_fault_defaults_are_off():
    g = _config("").gnss
    assert g.sim_outage_s == 0.0 and g.sim_glitch_every_s == 0.0
