"""One default accuracy for a fix that reports none: a live NMEA fix (NaN accuracies, the estimator fills them)
and the same fix replayed from a recording (the reader fills them) must give the same `ins` result."""

import datetime as dt
import math

import numpy as np
from pynmeagps import NMEAReader

from ahrsd.core.gnss import DEFAULT_H_ACC_M, DEFAULT_S_ACC_M_S, DEFAULT_V_ACC_M
from ahrsd.core.sample import SampleFlags, make_sample
from ahrsd.drivers.gnss.nmea import NmeaEpochAssembler, nmea_epoch_sentences
from ahrsd.drivers.gnss.recording import GnssRecordingWriter, read_gnss_recording
from ahrsd.drivers.gnss.validation import GnssFixValidator
from ahrsd.estimator.ins import Ins
from ahrsd.simulation import GnssErrors, simulate, simulate_gnss

RATE_HZ = 100.0
SECONDS = 20.0


def _nmea_fixes(fixes):
    """What a live NMEA receiver delivers for `fixes`: RMC/VTG/GGA bytes, parsed, assembled per epoch."""
    asm = NmeaEpochAssembler()
    utc0 = dt.datetime(2026, 6, 1, 12, 0, 0, tzinfo=dt.timezone.utc)
    out = []
    for f in fixes:
        for msg in nmea_epoch_sentences(f, utc0 + dt.timedelta(seconds=f.t_s)):
            out += asm.add(NMEAReader.parse(msg.serialize()), f.t_s)
    return out + asm.flush()


def _run_ins(block, fixes):
    """ins over the block, each fix (validated, as the daemon does) before the first sample not earlier."""
    est, validator = Ins(), GnssFixValidator()
    q = np.empty((len(block.t_s), 4))
    fi = 0
    for k, t in enumerate(block.t_s):
        while fi < len(fixes) and fixes[fi].t_s <= t:
            if validator.check(fixes[fi]) is None:
                est.update_gnss(fixes[fi])
            fi += 1
        e = est.update(make_sample(t, block.gyro_rad_s[k], block.accel_m_s2[k], block.truth_mag_ut[k],
                                   flags=SampleFlags.NEW_DATA))
        q[k] = e.q_wxyz
    return q, e.nav, est, validator


def test_a_live_nmea_fix_and_its_recording_weigh_the_same(tmp_path):
    block = simulate("car", SECONDS, rate_hz=RATE_HZ, seed=3, errors="ideal")
    sim = simulate_gnss(block, rate_hz=5.0, seed=4, errors=GnssErrors(horizontal_m=1.5, velocity_m_s=0.05),
                        latency_s=0.0)
    live = _nmea_fixes(sim)
    assert len(live) >= 90
    assert all(math.isnan(f.h_acc_m) and math.isnan(f.v_acc_m) and math.isnan(f.s_acc_m_s) for f in live)

    path = tmp_path / "car.gnss.csv"
    with GnssRecordingWriter(path) as w:     # `ahrsd record` writes the fix as received: NaN accuracies
        for f in live:
            w.write(f)
    replayed = read_gnss_recording(path)
    assert [(f.h_acc_m, f.v_acc_m, f.s_acc_m_s) for f in replayed] == \
        [(DEFAULT_H_ACC_M, DEFAULT_V_ACC_M, DEFAULT_S_ACC_M_S)] * len(live)

    q_live, nav_live, est_live, val_live = _run_ins(block, live)
    q_rec, nav_rec, est_rec, val_rec = _run_ins(block, replayed)
    assert val_live.counters["accepted"] == val_rec.counters["accepted"] == len(live)
    assert est_live.gnss_counters.fused_position == est_rec.gnss_counters.fused_position > 0.8 * len(live)
    # same weights, same arithmetic: the same result to the last bits, not just close
    assert np.max(np.abs(q_live - q_rec)) < 1e-12
    np.testing.assert_array_equal(nav_live.vel_ned_m_s, nav_rec.vel_ned_m_s)
    np.testing.assert_array_equal(nav_live.sigma_pos_m, nav_rec.sigma_pos_m)     # the weights show here first
    assert (nav_live.lat_deg, nav_live.lon_deg) == (nav_rec.lat_deg, nav_rec.lon_deg)


def test_the_default_is_the_m8_datasheet_per_axis_sigma():
    """Independent of the code: the CEP and 50 % figures converted with scipy's normal and Rayleigh laws."""
    from scipy.stats import norm, rayleigh

    assert DEFAULT_H_ACC_M == round(2.5 / rayleigh.ppf(0.5), 1)                  # 2.5 m CEP
    ratio = (5.0 / norm.ppf(0.975)) / (3.0 / rayleigh.ppf(0.95))                # SPS PS 2008: 3 m H, 5 m V, 95 %
    assert abs(DEFAULT_V_ACC_M - DEFAULT_H_ACC_M * ratio) < 0.05
    assert DEFAULT_S_ACC_M_S == round(0.05 / norm.ppf(0.75), 3)                 # 0.05 m/s, 50 %, one axis
