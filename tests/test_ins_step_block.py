"""ins stepped a run of samples in one compiled call (Ins.step_block, through the daemon's Pipeline with
`stepped_ahead`) must give, bit for bit, what stepping every sample alone gives: each sample's flags and time, the
published estimate at each block's end, the filter's state and covariance. The run has what stops a run: fixes
queued ahead of the samples (fused at the first sample that reaches them), a gap that restarts the filter, invalid
samples, and blocks of 1 to 40 samples."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ahrsd.calibration.models import Calibration
from ahrsd.core.estimate import EstimateFlags
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.core.sample_block import SampleBlock
from ahrsd.daemon.pipeline import Pipeline
from ahrsd.estimator.ins import Ins

from ins_truth import DECLINATION, gnss_fixes, simulated_run

RATE_HZ = 200.0
SECONDS = 40.0
GAP_AT_S, GAP_S = 25.0, 3.0          # a gap longer than reinit_dt_s (2 s): the filter restarts at its end
INVALID_AT = range(3000, 3010)      # samples with the accelerometer flagged invalid
FIRST_FIX_S = 8.0                   # before it, the field-circle check takes a sample every period (stepped alone)


def _samples_and_fixes():
    run = simulated_run("boat", SECONDS, rate_hz=RATE_HZ, seed=3)
    t = run.truth.t_s.copy()
    t[t >= GAP_AT_S] += GAP_S
    samples = []
    for k in range(len(t)):
        flags = SampleFlags.NEW_DATA | (SampleFlags.ACCEL_INVALID if k in INVALID_AT else 0)
        samples.append(make_sample(t[k], run.gyro[k], run.accel[k], run.mag[k], flags=flags, counter=k))
    # offered 0.1 s before the samples reach them: queued, fused at the first sample at or after their time;
    # the fixes' times moved with the gap as the samples' were
    fixes = []
    for _, fix in gnss_fixes(run.truth, seed=5, start_s=FIRST_FIX_S):
        if fix.t_s >= GAP_AT_S - 1.0 and fix.t_s < GAP_AT_S + 1.0:
            continue
        shift = GAP_S if fix.t_s >= GAP_AT_S else 0.0
        fixes.append((fix.t_s + shift - 0.1, dataclasses.replace(fix, t_s=fix.t_s + shift)))
    return samples, fixes


def _run(samples, fixes, stepped_ahead: bool):
    """Each sample's (time, flags), each block's published estimate, and the state at the end."""
    # a calibration that states its heading error: the field-circle check runs before the first fix, as in the
    # daemon with the simulated chip's calibration
    ins = Ins(declination_rad=DECLINATION, mag_calibration_sigma_rad=math.radians(1.0))
    assert ins._field_circle_on
    pipeline = Pipeline(ins, Calibration.identity())
    rng = np.random.default_rng(11)
    per_sample, per_block = [], []
    runs = [0]
    inner = ins._step_block

    def counted(*args):
        k = inner(*args)
        runs[0] += k
        return k
    ins._step_block = counted
    k0 = fi = 0
    while k0 < len(samples):
        block = samples[k0:k0 + int(rng.integers(1, 41))]
        while fi < len(fixes) and fixes[fi][0] <= block[0].t_s:
            ins.update_gnss(fixes[fi][1])
            fi += 1
        for est in pipeline.process_block(SampleBlock.of(block), stepped_ahead):
            per_sample.append((est.t_s, int(est.flags)))
        e = pipeline.last_estimate
        per_block.append((e.t_s, int(e.flags), e.q_wxyz.tobytes(), np.asarray(e.sigma_rpy_rad).tobytes(),
                          None if e.nav is None else (e.nav.lat_deg, e.nav.lon_deg, np.asarray(e.nav.vel_ned_m_s).tobytes())))
        k0 += len(block)
    return per_sample, per_block, ins._x_arr.tobytes() + ins._P.tobytes() + ins._hist.tobytes(), runs[0], ins


def test_a_block_stepped_in_runs_equals_every_sample_stepped_alone_bit_for_bit():
    samples, fixes = _samples_and_fixes()
    one, one_blocks, one_state, one_runs, one_ins = _run(samples, fixes, stepped_ahead=False)
    ahead, ahead_blocks, ahead_state, ahead_runs, ahead_ins = _run(samples, fixes, stepped_ahead=True)
    assert one_runs == 0
    # the block path was taken for most samples (before the first fix and at each due fix they go alone)
    assert ahead_runs > 0.8 * len(samples)
    assert len(one) == len(ahead) == len(samples)
    assert one == ahead
    assert one_blocks == ahead_blocks
    assert one_state == ahead_state
    assert one_ins.gnss_counters == ahead_ins.gnss_counters
    assert one_ins._published.state.tobytes() == ahead_ins._published.state.tobytes()
    # what the run exercised: the field circle checked before the first fix, fixes fused (queued ahead of the
    # samples), a restart after the gap
    assert one_ins._field_circle.result == ahead_ins._field_circle.result
    assert one_ins._field_circle.due_t_s == ahead_ins._field_circle.due_t_s > 1.0
    assert one_ins.gnss_counters.fused_velocity > 0.9 * len(fixes)
    assert sum(1 for _, f in one if f & int(EstimateFlags.REINITIALISED)) >= 1


def test_the_reader_lets_the_estimator_step_ahead_only_when_every_listener_says_so():
    from ahrsd.daemon.sample_reader import SampleListeners

    listeners = SampleListeners()
    assert listeners.allow_steps_ahead()                  # no listener
    allowed = [True]
    drop_fast = listeners.add(lambda s, e: None, in_place=True, steps_ahead=lambda: allowed[0])
    assert listeners.allow_steps_ahead()
    allowed[0] = False                                    # e.g. the field calibration's session started
    assert not listeners.allow_steps_ahead()
    allowed[0] = True
    drop_slow = listeners.add(lambda s, e: None)          # a listener that did not say (it may build snapshots)
    assert not listeners.allow_steps_ahead()
    drop_slow()
    assert listeners.allow_steps_ahead()
    drop_fast()
    assert listeners.steps_ahead == {}
