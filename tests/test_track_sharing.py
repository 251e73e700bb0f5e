"""simulation.track shares a built chunk of a track between streams only when it is the same track: the same
vehicle state by value (value_key), the same velocity function, the same start. Compared with the track integrated
afresh (the shared chunks cleared), and with vehicles that differ in a field, in a class table, or in a method."""

import numpy as np
import pytest

from ahrsd.simulation import track
from ahrsd.simulation.track import GeodeticTrack
from ahrsd.simulation.value_key import value_key
from ahrsd.simulation.vehicles import Boat

T_S = np.linspace(0.0, 40.0, 401)


def _fresh(vehicle):
    track._SHARED.clear()
    return GeodeticTrack(vehicle.velocity_ned_m_s, 10.0, 20.0, 5.0).position(T_S)


def _shared(vehicle):
    return GeodeticTrack(vehicle.velocity_ned_m_s, 10.0, 20.0, 5.0).position(T_S)


def _same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(a, b))


def test_a_second_track_of_the_same_vehicle_is_the_fresh_one():
    fresh = _fresh(Boat())
    assert _same(_shared(Boat()), fresh) and len(track._SHARED) == 1


def test_a_vehicle_that_differs_gets_its_own_track(monkeypatch):
    _fresh(Boat())
    other = Boat(current_ned_m_s=(0.5, 0.0, 0.0))                        # a field
    assert _same(_shared(other), _fresh(other)) and not _same(_fresh(other), _fresh(Boat()))
    _fresh(Boat())
    monkeypatch.setattr(Boat, "_HEAVE", ((0.9, 3.0, 0.0),))              # a class table
    assert _same(_shared(Boat()), _fresh(Boat()))
    monkeypatch.undo()
    base = _fresh(Boat())
    monkeypatch.setattr(Boat, "_heave", lambda self, t: (1.0, 0.0))     # a method
    assert not _same(_shared(Boat()), base)


def test_what_cannot_be_keyed_is_not_shared():
    assert value_key(type("WithCallable", (), {"__init__": lambda self: setattr(self, "f", print)})()) is None
    track._SHARED.clear()
    GeodeticTrack(lambda t: np.ones((len(t), 3)), 10.0, 20.0, 5.0).position(T_S)
    assert not track._SHARED
