"""The daemon's SIGINT/SIGTERM handler says once that it shuts down."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import signal

from ahrsd.daemon.config import Config, StateConfig
from ahrsd.daemon.service import Service


def test_a_second_signal_is_not_logged_again(tmp_path, caplog):
    """#30 (session 16's walk): Ctrl-C under `script` with `timeout` delivered SIGINT twice and the journal said
    "received SIGINT, shutting down" twice. (Seen failing without the check: 2 lines.)"""
    service = Service(dataclasses.replace(Config(), state=StateConfig(str(tmp_path))))
    service._stop = asyncio.Event()
    with caplog.at_level(logging.INFO, logger="ahrsd.daemon.service"):
        service._on_signal(signal.SIGINT)
        service._on_signal(signal.SIGINT)
        service._on_signal(signal.SIGTERM)
    said = [r.getMessage() for r in caplog.records if "shutting down" in r.getMessage()]
    assert said == ["received SIGINT, shutting down"]
    assert service._stop.is_set() and service.exit_code == 0
