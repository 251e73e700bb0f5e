"""daemon.position_memory: the daemon's last real position, kept in the state directory across restarts, the
resolver's "remembered" source (below the autopilot, above the simulator), its age and stale limit, a corrupt
file refused and counted, and `ahrsd calibrate mag` taking its reference field there and saying so.

Distances below from 1° of latitude = 111.2 km (the mean Earth radius, 6371 km): 0.0045° = 500 m, 0.0108° =
1.2 km. Times on a stepped wall clock (the memory's `wall_clock`, the module's `_wall_time_s` for the service)."""

from __future__ import annotations

import dataclasses
import datetime
import json
import logging
import math

import pytest

import ahrsd.daemon.position_memory as position_memory
from ahrsd.core.wmm import earth_field
from ahrsd.daemon.autopilot import AutopilotState
from ahrsd.daemon.config import Config, LocationConfig
from ahrsd.daemon.position import PositionResolver
from ahrsd.daemon.position_memory import FILE_NAME, PositionMemory
from ahrsd.daemon.service import Service

T0 = datetime.datetime(2026, 12, 4, 12, 0, tzinfo=datetime.timezone.utc).timestamp()
DAY_S = 86400.0
SITE = (47.0, 8.0, 400.0)


def saved(state) -> dict:
    return json.loads((state / FILE_NAME).read_text())


def resolver(memory, gnss=lambda: None, autopilot=None, simulator=False):
    return PositionResolver(LocationConfig(), gnss_position=gnss, autopilot=autopilot or AutopilotState(),
                            simulator=simulator, memory=memory)


def test_a_live_position_is_saved_when_it_moved_a_kilometre_an_hour_later_and_at_shutdown(tmp_path):
    """Saved at the first fix; not for 500 m; at 1.2 km; not 3599 s after that save, at 3600 s (the date
    refreshed); the last position of the run at shutdown. Read back after a restart as "remembered"."""
    t = [T0]
    gnss = [SITE]
    memory = PositionMemory(tmp_path, wall_clock=lambda: t[0])
    live = resolver(memory, gnss=lambda: gnss[0])
    live.note_live_position()                                 # a fix arrived
    assert live.position().source == "gnss"
    doc = saved(tmp_path)
    assert {k: doc[k] for k in ("lat_deg", "lon_deg", "alt_m", "source", "wall_time_s")} == {
        "lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 400.0, "source": "gnss", "wall_time_s": T0}
    assert doc["saved_utc"] == "2026-12-04T12:00:00+00:00"
    gnss[0], t[0] = (47.0045, 8.0, 400.0), T0 + 60          # 500 m north
    live.note_live_position()
    assert saved(tmp_path)["lat_deg"] == 47.0
    gnss[0], t[0] = (47.0108, 8.0, 400.0), T0 + 120         # 1.2 km from the saved position
    live.note_live_position()
    assert (saved(tmp_path)["lat_deg"], saved(tmp_path)["wall_time_s"]) == (47.0108, T0 + 120)
    t[0] = T0 + 120 + 3599
    live.note_live_position()
    assert saved(tmp_path)["wall_time_s"] == T0 + 120
    t[0] = T0 + 120 + 3600
    live.note_live_position()
    assert saved(tmp_path)["wall_time_s"] == T0 + 3720
    gnss[0], t[0] = (47.0153, 8.0, 401.0), T0 + 3780         # 500 m on, then the daemon stops
    live.note_live_position()
    assert saved(tmp_path)["lat_deg"] == 47.0108
    memory.save_now()
    assert (saved(tmp_path)["lat_deg"], saved(tmp_path)["alt_m"]) == (47.0153, 401.0)
    assert memory.counters() == {"rejected_files": 0, "saves": 4, "save_failures": 0}

    t[0] = T0 + 3780 + 2 * DAY_S                            # the next start, two days later, no fix yet
    restarted = resolver(PositionMemory(tmp_path, wall_clock=lambda: t[0]), simulator=True)
    p = restarted.position()
    assert (p.source, p.lat_deg, p.lon_deg, p.alt_m) == ("remembered", 47.0153, 8.0, 401.0)
    assert p.describe() == "remembered (gnss, 2026-12-04, 2.0 days old)"
    assert p.date is None                                   # the WMM at today's date


def test_the_remembered_position_is_used_up_to_a_year_and_a_clock_behind_it_uses_its_date(tmp_path):
    t = [T0]
    PositionMemory(tmp_path, wall_clock=lambda: t[0]).note(*SITE, "autopilot")
    for age_days, source in ((364.0, "remembered"), (366.0, "simulator")):
        t[0] = T0 + age_days * DAY_S
        assert resolver(PositionMemory(tmp_path, wall_clock=lambda: t[0]), simulator=True).position().source \
            == source, age_days
    t[0] = 0.0                                              # no real-time clock: 1970 until the time is set
    p = resolver(PositionMemory(tmp_path, wall_clock=lambda: t[0])).position()
    assert p.source == "remembered" and "age unknown" in p.describe()
    assert p.date == datetime.date(2026, 12, 4)             # not 1970: the WMM's secular variation


def test_asking_for_the_position_notes_nothing(tmp_path):
    """The memory is fed where positions arrive: `position()` (the declination every minute, a calibration's
    reference field) only reads, so nothing is noted or saved until a position arrives."""
    memory = PositionMemory(tmp_path, wall_clock=lambda: T0)
    live = resolver(memory, gnss=lambda: SITE)
    for _ in range(3):
        assert live.position().source == "gnss"
    memory.save_now()
    assert not (tmp_path / FILE_NAME).exists() and memory.usable() is None
    live.note_live_position()
    assert saved(tmp_path)["source"] == "gnss" and memory.usable().lat_deg == SITE[0]


def test_the_live_position_noted_is_the_receivers_else_the_autopilots_if_allowed(tmp_path):
    """What the resolver calls live, by its priority: the GNSS receiver's position above the autopilot's, and the
    autopilot's only when [location] use_autopilot_position; the configured position is no live one."""
    ap = AutopilotState(lat_deg=10.0, lon_deg=20.0, alt_m=5.0)
    cases = [(lambda: SITE, LocationConfig(), "gnss", SITE[0]),
             (lambda: None, LocationConfig(), "autopilot", 10.0),
             (lambda: SITE, LocationConfig(lat_deg=1.0, lon_deg=2.0), "gnss", SITE[0]),   # outranked, still kept
             (lambda: None, LocationConfig(use_autopilot_position=False), None, None)]
    for k, (gnss, location, source, lat) in enumerate(cases):
        state = tmp_path / str(k)
        memory = PositionMemory(state, wall_clock=lambda: T0)
        PositionResolver(location, gnss_position=gnss, autopilot=ap, simulator=False,
                         memory=memory).note_live_position()
        if source is None:
            assert not (state / FILE_NAME).exists(), k
        else:
            assert (saved(state)["source"], saved(state)["lat_deg"]) == (source, lat), k


def test_a_simulated_or_replayed_run_remembers_nothing(tmp_path):
    memory = PositionMemory(tmp_path, record=False)
    resolver(memory, gnss=lambda: SITE).note_live_position()
    memory.save_now()
    assert not (tmp_path / FILE_NAME).exists()


GOOD = {"format": "ahrsd-last-position", "schema_version": 1, "lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 400.0,
        "source": "gnss", "wall_time_s": T0}


@pytest.mark.parametrize("content, reason", [
    (b"", "not JSON"),
    (json.dumps(GOOD).encode()[:40], "not JSON"),                       # a truncated write
    (b"\xff\xfe\x00", "not JSON"),
    (b"[47.0, 8.0]", "not a JSON object"),
    (json.dumps({**GOOD, "format": "ahrsd-calibration"}).encode(), "format"),
    (json.dumps({**GOOD, "schema_version": 2}).encode(), "version 2"),
    (json.dumps({k: v for k, v in GOOD.items() if k != "lon_deg"}).encode(), "missing key"),
    (json.dumps({**GOOD, "lat_deg": "north"}).encode(), "not a number"),
    (json.dumps({**GOOD, "lat_deg": 91.0}).encode(), "out of range"),
    (json.dumps({**GOOD, "lon_deg": -181.0}).encode(), "out of range"),
    (json.dumps({**GOOD, "alt_m": 1e9}).encode(), "altitude"),
    (json.dumps(GOOD).replace("400.0", "NaN").encode(), "not finite"),
    (json.dumps({**GOOD, "wall_time_s": "Infinity"}).encode(), "not finite"),
    (json.dumps({**GOOD, "source": "simulator"}).encode(), "unknown source"),
    (json.dumps({**GOOD, "wall_time_s": -5.0}).encode(), "not a date"),
])
def test_a_corrupt_file_is_a_logged_counted_rejection_and_no_position(tmp_path, caplog, content, reason):
    (tmp_path / FILE_NAME).write_bytes(content)
    with caplog.at_level(logging.WARNING, logger="ahrsd.daemon.position_memory"):
        memory = PositionMemory(tmp_path, wall_clock=lambda: T0 + DAY_S)
    assert memory.rejected_files == 1 and memory.remembered is None
    assert any(str(tmp_path / FILE_NAME) in r.getMessage() and reason in r.getMessage() for r in caplog.records), \
        caplog.text
    assert resolver(memory, simulator=True).position().source == "simulator"
    assert resolver(memory).position() is None


def test_the_good_file_of_the_corrupt_cases_is_read(tmp_path):
    """The corrupt cases above are each one change away from a file that is read."""
    (tmp_path / FILE_NAME).write_text(json.dumps(GOOD))
    memory = PositionMemory(tmp_path, wall_clock=lambda: T0 + DAY_S)
    assert memory.rejected_files == 0 and resolver(memory).position().source == "remembered"


def test_no_file_is_no_rejection(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        memory = PositionMemory(tmp_path / "new")
    assert memory.rejected_files == 0 and memory.remembered is None and not caplog.records


def _service(tmp_path, source: str) -> Service:
    cfg = Config().with_overrides(state_dir=str(tmp_path / "state"))
    return Service(dataclasses.replace(cfg, sensor=dataclasses.replace(cfg.sensor, source=source)))


def test_the_daemon_starts_with_the_position_it_last_knew(tmp_path, monkeypatch, caplog):
    """Run 1 (the real chip): the autopilot's position, then 500 m further (not saved by the rule), then a
    stop (saved). Run 2, three days later, without an autopilot yet: the declination at the remembered
    position, its age in the log. A simulator run with an autopilot saves nothing."""
    t = [T0]
    monkeypatch.setattr(position_memory, "_wall_time_s", lambda: t[0])
    svc = _service(tmp_path, "spi")
    svc.autopilot.on_global_position_int(_global_position_int(*SITE), 0.0)
    assert saved(tmp_path / "state")["lat_deg"] == SITE[0]
    t[0] += 600
    svc.autopilot.on_global_position_int(_global_position_int(47.0045, 8.0, 400.0), 1.0)
    assert saved(tmp_path / "state")["lat_deg"] == SITE[0]
    svc.shutdown_io("test")
    t[0] += 3 * DAY_S
    again = _service(tmp_path, "spi")
    with caplog.at_level(logging.INFO, logger="ahrsd.daemon.declination"):
        again.declination.resolve(initial=True)
    assert again.declination.source == "WMM at 47.0045,8.0000 (remembered from autopilot, 2026-12-04)"
    assert again.declination.rad == pytest.approx(earth_field(47.0045, 8.0, 400.0).declination_rad, abs=1e-12)
    assert "3.0 days old" in caplog.text
    assert again.positions.memory.counters()["rejected_files"] == 0

    sim_state = tmp_path / "sim"
    sim = Service(dataclasses.replace(Config().with_overrides(state_dir=str(sim_state), sim="static")))
    sim.autopilot.on_global_position_int(_global_position_int(10.0, 20.0, 0.0), 0.0)
    sim.declination.resolve(initial=True)
    sim.shutdown_io("test")
    assert not (sim_state / FILE_NAME).exists()


def _global_position_int(lat_deg: float, lon_deg: float, alt_m: float):
    from ahrsd.daemon.mavlink_io import mavlink

    return mavlink.MAVLink_global_position_int_message(1000, round(lat_deg * 1e7), round(lon_deg * 1e7),
                                                       round(alt_m * 1e3), 0, 0, 0, 0, 0)


def test_the_daemon_notes_each_gnss_fix_as_it_arrives(tmp_path, monkeypatch):
    """The receiver's fix (here [gnss] source = "mavlink", with the autopilot's own position not used) is noted
    by the GNSS task as it is accepted: saved at once, the first position known."""
    from ahrsd.daemon.config import GnssConfig, SensorConfig
    from ahrsd.daemon.mavlink_io import mavlink
    from service_rig import gcs_socket, start_service, stop_service

    monkeypatch.setattr(position_memory, "_wall_time_s", lambda: T0)
    gcs = gcs_socket()
    svc, loop = start_service(gcs, tmp_path / "state", gnss=GnssConfig(source="mavlink"),
                              sensor=SensorConfig(source="spi"),
                              location=LocationConfig(use_autopilot_position=False))
    try:
        fix = mavlink.MAVLink_gps_raw_int_message(1_000_000, 3, 473977418, 85455939, 488000, 90, 150, 500, 9000,
                                                  11, 0, 1200, 2500, 300, 0)
        svc.gnss.on_mavlink(fix, svc.clock())               # outside the loop: the save runs at once
        doc = saved(tmp_path / "state")
        assert doc["source"] == "gnss"
        assert (doc["lat_deg"], doc["lon_deg"], doc["alt_m"]) == pytest.approx((47.3977418, 8.5455939, 488.0),
                                                                               abs=1e-9)
    finally:
        stop_service(svc, loop)
        gcs.close()


def test_calibrate_mag_takes_the_remembered_position_and_says_so(tmp_path, ahrsd_inproc):
    """No --lat/--lon/--gnss: the reference field is WMM2025's (pygeomag here) at the position in the state
    directory's file (written here by hand, in the documented format), and the report says where it came
    from; without the file, a usage error naming the three ways to give a site."""
    from pygeomag import GeoMag

    from ahrsd.drivers.recording import TRUTH_COLUMNS, RecordingWriter
    from ahrsd.core.sample import make_sample
    from ahrsd.simulation import DEFAULT_SITE, SensorErrors, simulate

    rec = tmp_path / "tumble.csv"
    block = simulate("tumble", 60, rate_hz=20, seed=3, errors=SensorErrors.adis16405(seed=3))
    with RecordingWriter(rec, extra_columns=TRUTH_COLUMNS) as w:
        for i in range(len(block)):
            w.write(make_sample(i / 20.0, block.gyro_rad_s[i], block.accel_m_s2[i], block.mag_ut[i]),
                    truth_q_wxyz=block.truth_q_wxyz[i])
    state = tmp_path / "state"
    missing = ahrsd_inproc("mag", rec, "--state-dir", state, "--dry-run")
    assert missing.returncode == 2
    for way in ("no position remembered", "give --lat and --lon", "--gnss GNSS.csv", "ahrsd run",
                str(state / FILE_NAME)):
        assert way in missing.stderr, missing.stderr

    state.mkdir()
    lat, lon, alt = DEFAULT_SITE.lat_deg, DEFAULT_SITE.lon_deg, DEFAULT_SITE.alt_m
    (state / FILE_NAME).write_text(json.dumps({**GOOD, "lat_deg": lat, "lon_deg": lon, "alt_m": alt,
                                               "wall_time_s": T0}))
    date = DEFAULT_SITE.date
    out = json.loads(ahrsd_inproc("mag", rec, "--state-dir", state, "--dry-run", "--json", "--date",
                                  date.isoformat(), check_rc=0).stdout)
    site = out["reference_site"]
    assert (site["lat_deg"], site["lon_deg"], site["alt_m"]) == (lat, lon, alt)
    assert "the position the daemon last knew, from its gnss on 2026-12-04" in site["source"]
    year = date.year + (date.timetuple().tm_yday - 1) / (366 if date.year % 4 == 0 else 365)
    truth = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(glat=lat, glon=lon, alt=alt / 1000.0, time=year)
    assert out["field_ut"] == pytest.approx(truth.f / 1000.0, abs=2e-3)
    assert out["inclination_deg"] == pytest.approx(truth.i, abs=1e-3)
    text = ahrsd_inproc("mag", rec, "--state-dir", state, "--dry-run", check_rc=0).stdout
    assert "the position the daemon last knew" in text and "give --lat/--lon if the vehicle has moved" in text


def test_calibrate_mag_refuses_a_remembered_position_older_than_the_daemon_would_use(tmp_path, ahrsd_inproc):
    import time

    state = tmp_path / "state"
    state.mkdir()
    (state / FILE_NAME).write_text(json.dumps({**GOOD, "wall_time_s": time.time() - 400 * DAY_S}))
    recording = tmp_path / "x.csv"        # exists: a missing file is said first (exit 1), before the position
    recording.write_text("")
    res = ahrsd_inproc("mag", recording, "--state-dir", state, "--dry-run")
    assert res.returncode == 2 and "days old" in res.stderr and "give --lat and --lon" in res.stderr, res.stderr
    assert math.isfinite(position_memory.MAX_AGE_DAYS) and position_memory.MAX_AGE_DAYS < 400
