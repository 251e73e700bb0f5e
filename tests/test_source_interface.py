"""Every IMU sensor source in drivers/ declares each member of the interface the daemon reads
(drivers/source_interface.py): the daemon reads them directly, so a source missing one must fail here, not
in the field. The source classes are found by name (`*Source` in a drivers module), so a new one is checked
without being listed."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import typing

import pytest

import ahrsd.drivers
from ahrsd.drivers.source_interface import LiveSource, PerSampleSource, SensorSource


def _members(protocol) -> set[str]:
    """The attributes and methods a Protocol declares (its own and its Protocol bases')."""
    names: set[str] = set()
    for klass in protocol.__mro__:
        if klass in (typing.Protocol, typing.Generic, object):
            continue
        names |= set(getattr(klass, "__annotations__", {}))
        names |= {n for n, v in vars(klass).items() if callable(v) and not n.startswith("_")}
    return names


def _declared(cls) -> set[str]:
    """What a class declares: class attributes, properties and methods, and annotated instance attributes."""
    names = set(dir(cls))
    for klass in cls.__mro__:
        names |= set(getattr(klass, "__annotations__", {}))
    return names


def _source_classes() -> list[type]:
    found = []
    for info in pkgutil.iter_modules(ahrsd.drivers.__path__):
        if info.ispkg:
            continue        # drivers.gnss: GNSS receivers, with their own interface
        module = importlib.import_module(f"ahrsd.drivers.{info.name}")
        for name, cls in vars(module).items():
            if (inspect.isclass(cls) and cls.__module__ == module.__name__ and name.endswith("Source")
                    and not getattr(cls, "_is_protocol", False) and cls is not LiveSource):
                found.append(cls)
    return sorted(found, key=lambda c: c.__name__)


SOURCES = _source_classes()


def test_the_sources_are_found():
    names = {c.__name__ for c in SOURCES}
    assert {"ChipSource", "ReconnectingSource", "GroundTruthSource", "ThreadedSource", "ProcessSource",
            "IioSource", "ReplaySource"} <= names


def test_the_interface_names_what_the_daemon_reads():
    assert _members(SensorSource) >= {"description", "sample_rate_hz", "per_sample", "monotonic_offset_s",
                                      "recording_time_base", "finished", "chip", "poll", "counters", "close"}
    assert _members(PerSampleSource) - _members(SensorSource) == {"read_one", "next_read_time"}


@pytest.mark.parametrize("cls", SOURCES, ids=lambda c: c.__name__)
def test_every_source_declares_every_member(cls):
    missing = _members(SensorSource) - _declared(cls)
    assert not missing, f"{cls.__name__} does not declare {sorted(missing)}"
    if cls.per_sample:
        missing = _members(PerSampleSource) - _declared(cls)
        assert not missing, f"{cls.__name__} reads per sample but does not declare {sorted(missing)}"


def test_a_source_missing_a_member_fails():
    class HalfSource(LiveSource):
        description = "a source without counters"
        sample_rate_hz = 819.2
        per_sample = False

        def poll(self):
            return []

        def close(self):
            pass

    assert _members(SensorSource) - _declared(HalfSource) == {"counters"}


def test_a_replay_and_a_live_source_answer_the_time_base_questions():
    from ahrsd.drivers.replay_source import ReplaySource

    replay = ReplaySource(iter(()), "nothing", realtime=False)
    assert isinstance(replay, SensorSource) and not isinstance(replay, PerSampleSource)
    assert replay.recording_time_base is True and replay.chip is None and replay.finished is False
    assert replay.poll() == [] and replay.finished is True
    assert LiveSource.recording_time_base is False and LiveSource.finished is False and LiveSource.chip is None
