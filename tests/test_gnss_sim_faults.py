"""The daemon's simulated receiver with the [gnss] sim_outage_* / sim_glitch_* faults: the keys are validated,
an outage makes the daemon's GNSS task report "outage" (STATUSTEXT, the estimate's flags), and a glitch is
rejected and counted (the estimator's innovation gate, or the validator for an invalid position).

The whole daemon path below the event loop runs: config → GnssTask → ScenarioGnssReceiver writing UBX into a
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
from ahrsd.daemon.gnss_task import GnssTask
from ahrsd.drivers.gnss.scenario import ScenarioGnssReceiver
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import simulate

RATE_HZ = 100.0
SCENARIO, SEED = "car", 2


class Clock:
    t = 0.0

    def __call__(self) -> float:
        return self.t


class FakeService:
    """What GnssTask uses of the daemon's Service: the config, the chip clock, the pipeline, STATUSTEXT."""

    def __init__(self, config, clock):
        self.config, self.loop, self.texts = config, None, []
        self.source = type("Source", (), {"chip": type("Chip", (), {"now": clock})()})()
        self.pipeline = type("Pipeline", (), {"estimator": Ins(), "last_estimate": None})()

    def statustext(self, severity, text):
        self.texts.append((self.config_time(), text))

    def on_gnss_position(self):
        pass

    def log_gnss_fix(self, fix, rejection):
        pass


def _config(gnss: str):
    return parse_config(tomllib.loads(f'[sensor]\nsource = "sim"\nscenario = "{SCENARIO}"\nseed = {SEED}\n'
                                      f'[gnss]\nsource = "sim"\n{gnss}'))


def _run(monkeypatch, gnss: str, seconds: float):
    """Step the simulated daemon for `seconds`; return the task, the service and the estimate flags per step."""
    monkeypatch.setattr(ScenarioGnssReceiver, "start", lambda self: self)     # no thread: write_due below
    clock = Clock()
    service = FakeService(_config(gnss), clock)
    service.config_time = clock
    task = GnssTask(service, service.config.gnss, clock=clock)
    task.open()
    block = simulate(SCENARIO, seconds, rate_hz=RATE_HZ, seed=SEED, errors="ideal")
    est = service.pipeline.estimator
    flags, aiding = [], []
    try:
        for k, t in enumerate(block.t_s):
            clock.t = float(t)
            before = task.receiver.fixes_written
            task.receiver.write_due()
            if task.receiver.fixes_written > before:      # the pty delivers in the kernel's own time: wait for it
                select.select([task.serial.fileno()], [], [], 2.0)
            task._on_readable()
            e = est.update(make_sample(t, block.gyro_rad_s[k], block.accel_m_s2[k], block.truth_mag_ut[k],
                                       flags=SampleFlags.NEW_DATA))
            service.pipeline.last_estimate = e
            if k % 10 == 0:
                task.tick(float(t))
            flags.append(int(e.flags))
            aiding.append((float(t), task.aiding()))
    finally:
        task.close()
    return task, service, block.t_s, flags, aiding


def test_an_outage_is_reported_and_a_glitch_rejected_and_counted(monkeypatch):
    task, service, t, flags, aiding = _run(monkeypatch, "sim_outage_start_s = 6.0\nsim_outage_s = 9.0\n"
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
    texts = [txt for _, txt in service.texts]
    # what the ground station sees: the receiver went quiet (the link state), and ins dead-reckons
    assert "ahrsd: GNSS silent, outage" in texts, service.texts
    assert texts[-1] == "ahrsd: GNSS 3D 12 sats, aided", service.texts


def test_outage_with_no_fix_solutions_and_invalid_positions(monkeypatch):
    task, service, t, flags, aiding = _run(monkeypatch, "sim_outage_start_s = 3.0\nsim_outage_s = 9.0\n"
                                                        "sim_outage_no_fix = true\nsim_glitch_every_s = 2.0\n"
                                                        'sim_glitch_kind = "nan"\n', 14.0)
    v = task.stats()["validator"]
    assert 44 <= v["no_fix"] <= 46, v                          # the receiver kept sending NO_FIX for 9 s
    assert v["nonfinite_field"] == 2, v                        # the glitches at 2 s and 12 s (invalidLlh)
    assert dict(aiding)[6.0] == "outage"
    assert "ahrsd: GNSS no fix, outage" in [txt for _, txt in service.texts], service.texts


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
