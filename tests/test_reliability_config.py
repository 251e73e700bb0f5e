"""Configuration and state under abuse: malformed, mistyped, unknown, unreadable or binary config files; an
unusable state directory; a full disk during a calibration save; a corrupted calibration file at start.

Extends tests/test_daemon_config.py (validation messages) and tests/test_cal_store.py (store fallback) with the
daemon's behaviour: exit code 2 and one clear line (never a traceback) for config errors, running on with
warnings when state cannot persist, and the last good calibration kept in force and on disk.
"""

from __future__ import annotations

import dataclasses
import errno
import json

import numpy as np
import pytest
from hypothesis import given, settings
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


@settings(derandomize=True, deadline=None, max_examples=200)
@given(st.binary(max_size=300))
def test_any_bytes_as_config_give_config_or_a_configerror(data):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "c.toml"
        path.write_bytes(data)
        try:
            load_config(path)
        except ConfigError:
            pass


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
    service.statustext = lambda sev, text: texts.append(text)

    class Ctx:
        results: list = []

        def finish(self, result):
            self.results.append(result)

        def progress(self, pct):
            pass
    try:
        ctx = Ctx()
        cal = GyroBiasCalibration(service, ctx, 819.2)
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
