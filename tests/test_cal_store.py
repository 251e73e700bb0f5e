"""The calibration store: atomic saves, previous version kept, checksums, and the documented fallbacks."""

from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest

from ahrsd.calibration.models import Calibration, GyroModel, MagModel
from ahrsd.calibration.store import (
    CURRENT_NAME,
    PREVIOUS_NAME,
    CalibrationFileError,
    CalibrationStore,
    checksum,
    encode_calibration,
    load_calibration_file,
)


def cal_a() -> Calibration:
    return Calibration(mag=MagModel([1.0, 2.0, 3.0], np.eye(3) * 1.1), metadata={"sensor_id": "A"})


def cal_b() -> Calibration:
    return Calibration(gyro=GyroModel([0.01, 0.0, -0.01], np.eye(3)), metadata={"sensor_id": "B"})


@pytest.fixture
def store(tmp_path) -> CalibrationStore:
    return CalibrationStore(tmp_path / "state")


def test_missing_directory_and_files_give_identity(store, caplog):
    with caplog.at_level(logging.INFO, logger="ahrsd.calibration.store"):
        cal = store.load()
    assert cal.is_identity
    assert store.last_load.source == "identity" and store.last_load.path is None
    assert "no calibration" in caplog.text


def test_save_then_load_round_trips_and_keeps_previous(store):
    store.save(cal_a())
    assert store.load() == cal_a() and store.last_load.source == "current"
    assert not store.previous_path.exists()
    store.save(cal_b())
    assert store.load() == cal_b()
    assert load_calibration_file(store.previous_path) == cal_a()
    store.save(cal_a())
    assert load_calibration_file(store.previous_path) == cal_b()


def test_file_is_human_readable_json_with_version_and_checksum(store):
    store.save(cal_a())
    doc = json.loads(store.current_path.read_text())
    assert doc["format"] == "ahrsd-calibration" and doc["schema_version"] == 1
    assert doc["sha256"] == checksum(doc["calibration"])
    assert doc["calibration"]["mag"]["hard_iron_ut"] == [1.0, 2.0, 3.0]
    assert store.current_path.read_text().count("\n") > 20  # indented, one value per line


def _corrupt(path, how):
    text = path.read_text()
    doc = json.loads(text)
    if how == "truncated":
        path.write_text(text[: len(text) // 2])
    elif how == "empty":
        path.write_text("")
    elif how == "garbage":
        path.write_bytes(b"\x00\xff\xfe not json")
    elif how == "wrong-version":
        doc["schema_version"] = 2
        path.write_text(json.dumps(doc))
    elif how == "bad-checksum":
        doc["calibration"]["mag"]["hard_iron_ut"][0] = 5.0  # edited without updating the checksum
        path.write_text(json.dumps(doc))
    elif how == "missing-key":
        del doc["calibration"]["gyro"]
        doc["sha256"] = checksum(doc["calibration"])
        path.write_text(json.dumps(doc))
    elif how == "non-finite":
        doc["calibration"]["gyro"]["bias_rad_s"][0] = float("nan")  # json writes it as NaN
        path.write_text(json.dumps(doc))
    elif how == "wrong-shape":
        doc["calibration"]["mag"]["soft_iron"] = [[1.0, 0.0], [0.0, 1.0]]
        doc["sha256"] = checksum(doc["calibration"])
        path.write_text(json.dumps(doc))
    elif how == "not-ours":
        path.write_text(json.dumps({"hello": "world"}))
    elif how == "deleted":
        path.unlink()
    else:
        raise AssertionError(how)


REASONS = {
    "truncated": "truncated",
    "empty": "empty",
    "garbage": "corrupt",
    "wrong-version": "wrong schema version 2",
    "bad-checksum": "bad checksum",
    "missing-key": "missing key 'gyro'",
    "non-finite": "non-finite",
    "wrong-shape": "3×3",
    "not-ours": "not an ahrsd calibration file",
    "deleted": "does not exist",
}


@pytest.mark.parametrize("how", sorted(REASONS))
def test_bad_current_file_gives_a_clear_error_and_falls_back_to_previous(store, how, caplog):
    store.save(cal_a())
    store.save(cal_b())          # current = B, previous = A
    _corrupt(store.current_path, how)
    with pytest.raises(CalibrationFileError, match=REASONS[how]) as info:
        load_calibration_file(store.current_path)
    assert info.value.path == store.current_path
    with caplog.at_level(logging.WARNING, logger="ahrsd.calibration.store"):
        cal = store.load()
    assert cal == cal_a()
    assert store.last_load.source == "previous"
    assert REASONS[how] in store.last_load.describe()
    assert "previous good calibration" in caplog.text


def test_both_files_bad_gives_identity_and_says_why(store, caplog):
    store.save(cal_a())
    store.save(cal_b())
    _corrupt(store.current_path, "truncated")
    _corrupt(store.previous_path, "bad-checksum")
    with caplog.at_level(logging.WARNING, logger="ahrsd.calibration.store"):
        cal = store.load()
    assert cal.is_identity and store.last_load.source == "identity"
    assert "truncated" in store.last_load.describe() and "bad checksum" in store.last_load.describe()
    assert "no usable calibration" in caplog.text


def test_crash_between_write_and_rename_leaves_the_old_file_valid(store):
    """Simulate a crash after the temp file was written but before the rename: the old file still loads,
    the orphan temp file is ignored, and the next save works."""
    store.save(cal_a())
    tmp = store.state_dir / f".{CURRENT_NAME}.crash.tmp"
    data = encode_calibration(cal_b())
    tmp.write_bytes(data[: len(data) // 3])   # a half-written temp file, never renamed
    assert store.load() == cal_a() and store.last_load.source == "current"
    store.save(cal_b())
    assert store.load() == cal_b()


def test_crash_inside_save_before_rename_keeps_old_file(store, monkeypatch):
    store.save(cal_a())
    real_replace = os.replace

    def crash(src, dst):
        if str(dst).endswith(CURRENT_NAME):
            raise OSError("power lost")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="power lost"):
        store.save(cal_b())
    monkeypatch.setattr(os, "replace", real_replace)
    assert store.load() == cal_a()
    assert not list(store.state_dir.glob("*.tmp"))  # the temp file was cleaned up


def test_a_corrupt_current_file_is_not_rotated_over_a_good_previous(store):
    store.save(cal_a())
    store.save(cal_b())
    _corrupt(store.current_path, "garbage")
    store.save(cal_a())
    assert load_calibration_file(store.previous_path) == cal_a()  # the good previous (A) was kept
    assert store.load() == cal_a()


def test_save_rejects_non_calibrations(store):
    with pytest.raises(TypeError):
        store.save({"mag": 1})


def test_unreadable_file_is_a_clear_error(tmp_path):
    with pytest.raises(CalibrationFileError, match="does not exist"):
        load_calibration_file(tmp_path / "nope.json")
    d = tmp_path / "dir.json"
    d.mkdir()
    with pytest.raises(CalibrationFileError, match="cannot read"):
        load_calibration_file(d)


def test_previous_name_is_documented_constant(store):
    assert store.previous_path.name == PREVIOUS_NAME
