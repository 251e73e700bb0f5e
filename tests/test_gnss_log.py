"""The on-vehicle GNSS log (drivers/gnss/log.py, daemon.vehicle_log): the daemon replays an IMU + GNSS recording
with logging on; every fix it was given is in the `.gnss.csv.gz` log, accepted or rejected with the reason the
recording was built to trigger (known by construction, not from the validator); `ahrsd log cut` writes
REC.gnss.csv beside REC.csv; and replaying the cut (`--replay REC.csv --gnss-replay REC.gnss.csv`) gives the
validator the same fixes, which it accepts and rejects as it did live."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math

import numpy as np
import pytest

from ahrsd.cli.main import main
from ahrsd.core.gnss import GnssFixType, make_fix
from ahrsd.core.sample import make_sample
from ahrsd.daemon.config import Config, EndpointConfig, GnssConfig, LogConfig, SensorConfig, StateConfig
from ahrsd.daemon.run_stats import collect_stats
from ahrsd.daemon.service import Service
from ahrsd.drivers.gnss.log import REJECTION_CODES, GnssLog
from ahrsd.drivers.gnss.recording import GnssRecordingWriter, read_gnss_recording
from ahrsd.drivers.gnss.validation import GnssRejection
from ahrsd.drivers.recording import SAMPLE_COLUMNS, RecordingWriter, read_recording

from service_rig import gcs_socket

RATE_HZ, SECONDS, FIX_HZ = 100.0, 4.0, 5.0
T0 = 5000.0


def fixes_with_known_verdicts():
    """(fix, the verdict the validator must give) at 5 Hz; every fourth one broken in a known way."""
    out = []
    for k in range(int(SECONDS * FIX_HZ) - 1):
        t = T0 + 0.1 + k / FIX_HZ
        fix = make_fix(t, 36.42 + 1e-6 * k, 54.98, 12.5 + 0.01 * k, [1.5, -0.25, 0.0], h_acc_m=1.2, v_acc_m=2.1,
                       s_acc_m_s=0.15, fix_type=GnssFixType.FIX_3D, num_sats=11, hdop=0.9,
                       extra={"receiver_time_s": 1000.0 + k * 0.2})
        verdict = None
        if k % 4 == 1:
            fix, verdict = dataclasses.replace(fix, fix_type=GnssFixType.NO_FIX), GnssRejection.NO_FIX
        elif k % 4 == 3:
            fix, verdict = dataclasses.replace(fix, alt_m=1e6), GnssRejection.OUT_OF_RANGE
        out.append((fix, verdict))
    return out


def write_recordings(d):
    rng = np.random.default_rng(3)
    imu, gnss = d / "trip.csv", d / "trip.gnss.csv"
    with RecordingWriter(imu, extra_columns=SAMPLE_COLUMNS) as w:
        for k in range(int(SECONDS * RATE_HZ)):
            w.write(make_sample(T0 + k / RATE_HZ, rng.normal(0, 1e-3, 3), [0.0, 0.0, -9.80665] + rng.normal(0, 0.01, 3),
                                [22.0, 1.5, 42.0] + rng.normal(0, 0.1, 3), counter=k))
    fixes = fixes_with_known_verdicts()
    with GnssRecordingWriter(gnss, extra_columns=("receiver_time_s",)) as w:
        for fix, _ in fixes:
            w.write(fix)
    return imu, gnss, fixes


def replay(tmp, imu, gnss, log_dir=None) -> dict:
    """The daemon in-process replaying imu + gnss as fast as it can; its stats."""
    sink = gcs_socket()
    cfg = dataclasses.replace(
        Config(), endpoints=(EndpointConfig(f"udpout:127.0.0.1:{sink.getsockname()[1]}"),),
        state=StateConfig(str(tmp / "state")),
        sensor=SensorConfig(source="replay", replay_file=str(imu), replay_realtime=False),
        gnss=GnssConfig(source="replay", file=str(gnss)),
        log=LogConfig(enabled=log_dir is not None, dir=str(log_dir or "")))
    service = Service(cfg, environ={})
    try:
        assert asyncio.run(asyncio.wait_for(service.run(), 120)) == 0
    finally:
        sink.close()
    return collect_stats(service)


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gnss_log")
    imu, gnss, fixes = write_recordings(tmp)
    stats = replay(tmp, imu, gnss, tmp / "logs")
    return tmp, fixes, stats


def code(verdict) -> float:
    return float(REJECTION_CODES["accepted" if verdict is None else verdict.value])


def test_every_fix_is_logged_with_its_verdict(logged):
    tmp, fixes, stats = logged
    assert stats["logs"]["gnss"]["written"] == len(fixes) and stats["logs"]["gnss"]["dropped"] == 0
    (path,) = sorted((tmp / "logs").glob("gnss-*.gnss.csv.gz"))
    got = read_gnss_recording(path)
    assert len(got) == len(fixes)
    for g, (f, verdict) in zip(got, fixes):
        assert (g.t_s, g.lat_deg, g.lon_deg, g.alt_m, g.h_acc_m, g.num_sats, g.fix_type) == \
               (f.t_s, f.lat_deg, f.lon_deg, f.alt_m, f.h_acc_m, f.num_sats, f.fix_type)
        np.testing.assert_array_equal(g.vel_ned_m_s, f.vel_ned_m_s)
        assert g.extra["receiver_time_s"] == f.extra["receiver_time_s"]
        assert g.extra["rejection"] == code(verdict)
    side = json.loads(path.with_name(path.name + ".json").read_text())
    assert side["rejection_codes"] == REJECTION_CODES and side["closed"] and side["entries"] == len(fixes)
    assert side["t_first_s"] == fixes[0][0].t_s and side["t_last_s"] == fixes[-1][0].t_s


def test_the_cut_writes_the_gnss_recording_and_its_replay_judges_the_fixes_as_live(logged, tmp_path):
    tmp, fixes, _ = logged
    cut = tmp_path / "REC.csv"
    assert main(["log", "cut", "--dir", str(tmp / "logs"), "--from", str(T0 + 1.0), "--to", str(T0 + 3.0),
                 "--output", str(cut), "--quiet"]) == 0
    rec = read_recording(cut)
    span = [(f, v) for f, v in fixes if rec.t_s[0] <= f.t_s <= rec.t_s[-1]]
    got = read_gnss_recording(tmp_path / "REC.gnss.csv")
    assert [g.t_s for g in got] == [f.t_s for f, _ in span] and 8 <= len(span) < len(fixes)
    assert [g.extra["rejection"] for g in got] == [code(v) for _, v in span]
    meta = json.loads((tmp_path / "REC.csv.json").read_text())["gnss"]
    assert meta["fixes"] == len(span) and meta["rejected"] == sum(v is not None for _, v in span)

    stats = replay(tmp_path, cut, tmp_path / "REC.gnss.csv")
    g = stats["gnss"]
    assert g["fixes"] == len(span)
    assert g["accepted"] == sum(v is None for _, v in span) and g["rejected"] == len(span) - g["accepted"]
    by_reason = g["validator"]
    for reason in (GnssRejection.NO_FIX, GnssRejection.OUT_OF_RANGE):
        assert by_reason[reason.value] == sum(v is reason for _, v in span)


def test_a_fix_without_a_time_is_logged_and_the_sidecar_keeps_the_time_mapping(tmp_path):
    good = make_fix(10.0, 1.0, 2.0, 3.0, [0, 0, 0])
    timeless = dataclasses.replace(good, t_s=math.nan)
    with GnssLog(tmp_path) as log:
        log.put((timeless, GnssRejection.NONFINITE_TIME))
        log.put((good, None))
    (path,) = tmp_path.glob("gnss-*.gnss.csv.gz")
    got = read_gnss_recording(path)
    assert math.isnan(got[0].t_s) and got[0].extra["rejection"] == REJECTION_CODES["nonfinite_time"]
    side = json.loads(path.with_name(path.name + ".json").read_text())
    assert side["t_first_s"] == side["t_last_s"] == 10.0 and "unix_minus_t_s" in side
