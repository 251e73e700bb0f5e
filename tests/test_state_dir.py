"""core.state_dir: the one default state directory of `ahrsd run`, `calibrate` and `log`."""

from __future__ import annotations

import ahrsd.core.state_dir as state_dir


def test_the_default_state_directory_in_order(tmp_path, monkeypatch):
    service = tmp_path / "var-lib-ahrsd"
    monkeypatch.setattr(state_dir, "SERVICE_STATE_DIR", service)
    user = {"XDG_STATE_HOME": str(tmp_path / "xdg")}
    assert state_dir.default_state_dir(user) == tmp_path / "xdg" / "ahrsd"          # no service installed
    service.mkdir()
    assert state_dir.default_state_dir(user) == service                              # installed, writable
    monkeypatch.setattr(state_dir.os, "access", lambda path, mode: False)            # a user who may not write it
    assert state_dir.default_state_dir(user) == tmp_path / "xdg" / "ahrsd"
    unit = {"STATE_DIRECTORY": "/var/lib/ahrsd:/var/lib/other", **user}              # the service itself
    assert str(state_dir.default_state_dir(unit)) == "/var/lib/ahrsd"
