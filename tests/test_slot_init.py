"""core.slot_init: the cheaper __init__ of the per-sample frozen dataclasses stores every field as the generated
one does (compared with a twin class that keeps dataclasses' own __init__), keeps them frozen, and refuses
what it would not reproduce."""

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pytest

from ahrsd.core.estimate import AttitudeEstimate, HeadingIntegrity, NavState
from ahrsd.core.gnss import GnssFix
from ahrsd.core.sample import ImuSample, SampleFlags
from ahrsd.core.slot_init import slot_init


def _twin(cls):
    """The same fields and defaults, with dataclasses' generated __init__ (the reference)."""
    fields = dataclasses.fields(cls)
    body = {"__annotations__": {f.name: f.type for f in fields},
            **{f.name: f.default for f in fields if f.default is not dataclasses.MISSING},
            **{f.name: field(default_factory=f.default_factory) for f in fields
               if f.default_factory is not dataclasses.MISSING}}
    return dataclass(frozen=True, slots=True)(type("Twin" + cls.__name__, (), body))


@pytest.mark.parametrize("cls", [ImuSample, AttitudeEstimate, NavState, HeadingIntegrity, GnssFix])
def test_every_field_is_stored_where_the_generated_init_stores_it(cls):
    twin = _twin(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    required = [f.name for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    values = {name: (k, name) for k, name in enumerate(names)}            # a distinct value per field
    for given in (names, required):                                       # all given, and the defaults taken
        args = [values[n] for n in given]
        got, want = cls(*args), twin(*args)
        assert [getattr(got, n) for n in names] == [getattr(want, n) for n in names]
        kw = {n: values[n] for n in given}
        assert [getattr(cls(**kw), n) for n in names] == [getattr(twin(**kw), n) for n in names]
    with pytest.raises(TypeError):
        cls(*[values[n] for n in required[:-1]])                          # a required field missing
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(cls(*[values[n] for n in required]), names[0], 1)


def test_a_default_factory_makes_a_fresh_value_each_time():
    a, b = GnssFix(0.0, 1.0, 2.0, 3.0, np.zeros(3)), GnssFix(0.0, 1.0, 2.0, 3.0, np.zeros(3))
    assert a.extra == {} and a.extra is not b.extra
    given = {"t_rx_s": 1.0}
    assert GnssFix(0.0, 1.0, 2.0, 3.0, np.zeros(3), extra=given).extra is given


def test_a_sample_is_the_same_dataclass():
    s = ImuSample(1.5, np.zeros(3), np.ones(3), np.full(3, 2.0), flags=SampleFlags.NEW_DATA, counter=4)
    r = dataclasses.replace(s, t_s=2.0)
    assert (r.t_s, r.counter, r.flags) == (2.0, 4, SampleFlags.NEW_DATA) and r.mag_ut is s.mag_ut


def test_what_it_cannot_reproduce_is_refused():
    with pytest.raises(TypeError):
        @slot_init
        @dataclass(frozen=True, slots=True)
        class NotInInit:
            a: int = field(default=0, init=False)
    with pytest.raises(TypeError):
        @slot_init
        @dataclass(frozen=False, slots=True)
        class NotFrozen:
            a: int
