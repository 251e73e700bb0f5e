"""Configuration and state under abuse: malformed, mistyped, unknown, unreadable or binary config files; an
unusable state directory; a full disk during a calibration save; a corrupted calibration file at start.

Extends tests/test_daemon_config.py (validation messages) and tests/test_cal_store.py (store fallback) with the
daemon's behaviour: exit code 2 and one clear line (never a traceback) for config errors, running on with
warnings when state cannot persist, and the last good calibration kept in force and on disk.
"""

from __future__ import annotations

import dataclasses
import datetime
import errno
import json
import math
import tomllib
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ahrsd.calibration.models import Calibration, GyroModel
from ahrsd.calibration.store import CalibrationStore
from ahrsd.cli.main import main
from ahrsd.daemon.config import ConfigError, load_config
from service_rig import gcs_socket, start_service, stop_service


def run_cli(args, capsys) -> tuple[int, str]:
    code = main(args)
    out = capsys.readouterr()
    return code, out.err + out.out


@pytest.mark.parametrize("content, words", [
    (b"[sensor\nsource = 'sim'\n", "not valid TOML"),
    (b"[sensor]\nsource = 'sim'\nsource = 'spi'\n", "not valid TOML"),                 # duplicate key
    (b"[sensor]\nseed = 'zero'\n", "sensor.seed"),                                       # wrong type
    (b"[outputs]\nattitude_hz = -3\n", "outputs.attitude_hz"),                           # out of range
    (b"[sensor]\nsorce = 'sim'\n", "sorce"),                                             # typo: unknown key
    (b"[sensnor]\n", "sensnor"),                                                         # unknown section
    (b"[[endpoint]]\nurl = 'udp-out:1.2.3.4:99999'\n", "endpoint"),
    (b"\xff\xfe[sensor]\n\x00\x81", "config file"),                                     # binary junk
])
def test_bad_config_files_exit_2_with_one_clear_line(tmp_path, capsys, content, words):
    path = tmp_path / "ahrsd.toml"
    path.write_bytes(content)
    code, text = run_cli(["run", "--config", str(path), "--check-config"], capsys)
    assert code == 2 and words in text and str(path) in text, text
    assert "Traceback" not in text and len(text.strip().splitlines()) == 1


def test_unreadable_and_missing_config(tmp_path, capsys):
    code, text = run_cli(["run", "--config", str(tmp_path), "--check-config"], capsys)     # a directory
    assert code == 2 and "cannot read config file" in text
    code, text = run_cli(["run", "--config", str(tmp_path / "nope.toml"), "--check-config"], capsys)
    assert code == 2 and "does not exist" in text


# ------------------------------------------------------------------------------------------ valid TOML, bad values
# Random bytes almost never parse as TOML, so they only reach the TOML parser. These documents are valid TOML
# (built as dicts and written by the small emitter below: no TOML writer is a dependency) holding the defaults
# of every section with ONE key changed to a hostile value — a wrong type, out of range, non-finite, an
# unknown key or section — so every case reaches the validation of that key.


def _toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(k: str) -> str:
    return k if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k) else _toml_string(k)


def toml_value(v) -> str:
    """TOML 1.0 for bool, int, float (nan/inf included), str, date/datetime, list and inline table."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (datetime.date, datetime.datetime)):
        return v.isoformat()
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_document(doc: dict) -> str:
    lines = []
    for section, table in doc.items():
        for t in table if isinstance(table, list) else [table]:
            lines.append(f"[[{_toml_key(section)}]]" if isinstance(table, list) else f"[{_toml_key(section)}]")
            lines += [f"{_toml_key(k)} = {toml_value(v)}" for k, v in t.items()]
    return "\n".join(lines) + "\n"


def default_document() -> dict:
    """Every section with its defaults (None = unset is left out: TOML has no null)."""
    from ahrsd.daemon.config import SECTIONS, Config
    from ahrsd.daemon.magcal import MagCalSettings

    cfg = Config()
    doc = {}
    for section in SECTIONS:
        if section == "endpoint":
            doc[section] = [{"url": cfg.endpoints[0].url}]
            continue
        if section == "nmea":                       # an array of tables, none by default
            doc[section] = [{"url": "udp:127.0.0.1:10110"}]
            continue
        value = MagCalSettings() if section == "magcal" else getattr(cfg, section)
        doc[section] = {k: list(v) if isinstance(v, tuple) else v
                        for k, v in dataclasses.asdict(value).items() if v is not None}
    return doc


def section_keys() -> dict:
    from ahrsd.daemon.config import SECTIONS
    from ahrsd.daemon.magcal import MagCalSettings

    return {s: [f.name for f in dataclasses.fields(cls or MagCalSettings)] for s, cls in SECTIONS.items()}


SCALARS = st.one_of(
    st.text(st.characters(blacklist_categories=("Cs",)), max_size=12),
    st.sampled_from(["", "sim", "spi", "replay", "udpout:1.2.3.4:99999", "/dev/", "mekf", "auto", "on"]),
    st.sampled_from([0, 1, -1, 2**31, 2**32, 2**63 - 1, -2**63]), st.integers(-2**63, 2**63 - 1),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0, -0.0, 1e-300, 0.5]), st.floats(),
    st.booleans(), st.dates(), st.datetimes(),
)
HOSTILE_TOML_VALUES = st.one_of(SCALARS, st.lists(SCALARS, max_size=4),
                                st.dictionaries(st.text(min_size=1, max_size=6), SCALARS, max_size=3))
# keys whose (valid) value can make a rule about ANOTHER key of the section fail: the error names that key
CROSS_KEY_RULES = {("sensor", "source"), ("location", "lat_deg"), ("location", "lon_deg"), ("gnss", "source")}
CONFIG_CASES = Counter()


@st.composite
def hostile_documents(draw):
    keys = section_keys()
    doc = default_document()
    how = draw(st.sampled_from(["value", "value", "value", "unknown_key", "unknown_section"]))
    section = draw(st.sampled_from(sorted(keys)))
    if how == "unknown_section":
        name = draw(st.text(st.characters(min_codepoint=97, max_codepoint=122), min_size=1, max_size=10)
                    .filter(lambda n: n not in keys))
        doc[name] = {"x": 1}
        return doc, how, name, None, None
    key = draw(st.sampled_from(keys[section])) if how == "value" else draw(
        st.text(st.characters(min_codepoint=97, max_codepoint=122), min_size=1, max_size=12)
        .filter(lambda k: k not in keys[section]))
    value = draw(HOSTILE_TOML_VALUES)
    table = doc[section][0] if section in ("endpoint", "nmea") else doc[section]
    table[key] = value
    return doc, how, section, key, value


@settings(derandomize=True, deadline=None, max_examples=400, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(hostile_documents())
def test_valid_toml_with_a_hostile_value_gives_a_configerror_naming_the_key(tmp_path, case):
    doc, how, section, key, value = case
    path = tmp_path / "ahrsd.toml"
    path.write_text(toml_document(doc), encoding="utf-8")
    with open(path, "rb") as f:
        assert tomllib.load(f) is not None          # the emitter wrote valid TOML: this reaches validation
    try:
        cfg = load_config(path)
    except ConfigError as exc:
        text = str(exc)
        assert len(text.splitlines()) == 1 and str(path) in text, text
        if how == "unknown_section":
            assert f"[{section}]" in text, text
        else:
            prefix = f"{section}[0]" if section in ("endpoint", "nmea") else section
            named = f"{prefix}.{key}" in text or ((section, key) in CROSS_KEY_RULES and f"{prefix}." in text)
            assert named, text
        CONFIG_CASES[(how, "ConfigError")] += 1
        return
    # accepted: then the value was a valid one, and what is in force is that value, finite
    assert how == "value", f"{how} {section}.{key} accepted"
    if section == "endpoint":
        got = cfg.endpoints[0].url
    elif section == "nmea":
        got = getattr(cfg.nmea[0], key)
        if key == "sentences":                      # kept as (name, Hz) pairs, each rate a float
            got, value = dict(got), {k: float(v) for k, v in value.items()}
    else:
        got = getattr(cfg.magcal if section == "magcal" else getattr(cfg, section), key)
    if isinstance(got, float):
        assert math.isfinite(got), f"{section}.{key} = {got} accepted"
    want = tuple(value) if isinstance(value, list) else value
    assert got == want or (isinstance(want, int) and got == float(want)), (section, key, got, value)
    CONFIG_CASES[(how, "accepted")] += 1


def test_config_fuzz_summary():
    print("\nconfig cases (mutation, outcome): " + ", ".join(f"{k}: {n}" for k, n in sorted(CONFIG_CASES.items())))
    if CONFIG_CASES:
        assert CONFIG_CASES[("value", "ConfigError")] > 100


# ------------------------------------------------------------------------------------------ state


def _cal(bias_deg_s: float) -> Calibration:
    ident = Calibration.identity()
    return dataclasses.replace(ident, gyro=GyroModel(np.radians([bias_deg_s, 0.0, 0.0]), np.eye(3)))


def _started_service(state_dir, tmp_path):
    gcs = gcs_socket()
    service, loop = start_service(gcs, state_dir)

    def close():
        stop_service(service, loop)
        gcs.close()
    return service, close


def test_unusable_state_directory_runs_on_without_persisting(tmp_path, caplog):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    service, close = _started_service(blocker / "state", tmp_path)     # mkdir fails: ENOTDIR
    try:
        assert any("state directory" in r.getMessage() for r in caplog.records)
        ok, _ = service.params.set("SR_ATTITUDE", 20.0)                 # applied, persistence fails loudly
        assert ok and service.params.get("SR_ATTITUDE") == 20.0
        assert any("cannot persist parameters" in r.getMessage() for r in caplog.records)
        before = service.calibration
        with pytest.raises(OSError):
            service.apply_calibration(_cal(0.5), save=True, reason="test")
        assert service.calibration is before and service.reset_counter == 0   # nothing half-applied
    finally:
        close()


def test_full_disk_during_calibration_save_keeps_the_last_good_one(tmp_path, monkeypatch):
    state = tmp_path / "state"
    store = CalibrationStore(state)
    store.save(_cal(0.1))
    good_bytes = store.current_path.read_bytes()
    service, close = _started_service(state, tmp_path)
    try:
        assert np.allclose(np.degrees(service.calibration.gyro.bias_rad_s), [0.1, 0, 0])
        import ahrsd.calibration.store as store_mod

        def enospc(fd):
            raise OSError(errno.ENOSPC, "No space left on device")
        monkeypatch.setattr(store_mod.os, "fsync", enospc)
        with pytest.raises(OSError) as info:
            service.apply_calibration(_cal(0.7), save=True, reason="disk full")
        assert info.value.errno == errno.ENOSPC
        monkeypatch.undo()
        assert np.allclose(np.degrees(service.calibration.gyro.bias_rad_s), [0.1, 0, 0])   # in force: old
        assert store.current_path.read_bytes() == good_bytes                              # on disk: old
        assert not list(state.glob(".*.tmp"))                                             # no debris
        assert np.allclose(np.degrees(CalibrationStore(state).load().gyro.bias_rad_s), [0.1, 0, 0])
    finally:
        close()


def test_gyro_calibration_command_reports_a_failed_save(tmp_path, monkeypatch):
    """The PREFLIGHT_CALIBRATION path: a save that hits a full disk ends in FAILED with a STATUSTEXT; the
    calibration in force and on disk stay the old ones."""
    from ahrsd.daemon.gyro_cal import GyroBiasCalibration
    from ahrsd.daemon.mavlink_io import mavlink
    from ahrsd.core.sample import make_sample
    import ahrsd.calibration.store as store_mod

    state = tmp_path / "state"
    CalibrationStore(state).save(_cal(0.1))
    service, close = _started_service(state, tmp_path)
    texts = []

    class Operator:      # what the calibration tells the operator
        def statustext(self, sev, text):
            texts.append(text)

    class Ctx:
        results: list = []

        def finish(self, result):
            self.results.append(result)

        def progress(self, pct):
            pass
    try:
        ctx = Ctx()
        cal = GyroBiasCalibration(ctx, 819.2, listeners=service.listeners, loop=service.loop, health=service.health,
                                  outbound=Operator(), autopilot=service.autopilot, swap=service.swap)
        cal.start()
        still = make_sample(0.0, np.radians([0.1 + 0.3, 0.0, 0.0]), [0.0, 0.0, -9.80665], [20.0, 0.0, 45.0])
        for _ in range(cal.needed):
            cal.on_sample(still, None)

        def enospc(fd):
            raise OSError(errno.ENOSPC, "No space left on device")
        monkeypatch.setattr(store_mod.os, "fsync", enospc)
        cal._finish()
        monkeypatch.undo()
        assert ctx.results == [mavlink.MAV_RESULT_FAILED]
        assert any("gyro calibration failed" in t and "No space" in t for t in texts), texts
        assert np.allclose(np.degrees(service.calibration.gyro.bias_rad_s), [0.1, 0, 0])
        assert np.allclose(np.degrees(CalibrationStore(state).load().gyro.bias_rad_s), [0.1, 0, 0])
        assert not service.health.calibrating
    finally:
        close()


def test_corrupted_calibration_file_at_start_falls_back_to_the_previous(tmp_path):
    state = tmp_path / "state"
    store = CalibrationStore(state)
    store.save(_cal(0.2))
    store.save(_cal(0.3))                                   # 0.2 becomes the previous file
    data = bytearray(store.current_path.read_bytes())
    data[len(data) // 2] ^= 0x20                            # flip a bit inside the JSON: checksum fails
    store.current_path.write_bytes(bytes(data))
    service, close = _started_service(state, tmp_path)
    try:
        assert np.allclose(np.degrees(service.calibration.gyro.bias_rad_s), [0.2, 0, 0])
    finally:
        close()
    store.current_path.write_bytes(b"\x00" * 10)
    store.previous_path.write_text(json.dumps({"not": "a calibration"}))
    service, close = _started_service(state, tmp_path)      # both bad: identity, and the daemon still runs
    try:
        assert np.allclose(service.calibration.gyro.bias_rad_s, 0.0)
    finally:
        close()


def test_check_config_prints_the_field_calibrations_defaults_without_a_magcal_table(tmp_path, capsys):
    """`run --check-config` shows what the daemon will use: without [magcal] the field calibration's defaults
    (MAVProxy's broadcast `magcal start` ignored), not null (session 23's walk)."""
    path = tmp_path / "ahrsd.toml"
    path.write_text("[sensor]\nsource = 'sim'\n")
    code, text = run_cli(["run", "--config", str(path), "--check-config"], capsys)
    assert code == 0
    shown = json.loads(text)
    assert shown["magcal"]["accept_broadcast"] is False and shown["magcal"]["timeout_s"] == 300.0
    path.write_text("[magcal]\naccept_broadcast = true\n")
    code, text = run_cli(["run", "--config", str(path), "--check-config"], capsys)
    assert code == 0 and json.loads(text)["magcal"]["accept_broadcast"] is True
