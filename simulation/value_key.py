"""A hashable key that stands for everything an object's computation can read: the value of every piece of
state reachable from it (numbers, strings, arrays by their bytes, tuples, dataclasses and plain objects field by
field, recursively), its class, and every function and value its class and the class's bases define (held by
identity: a key keeps them alive, so a monkeypatched method or constant is another key).

Two objects with equal keys compute the same from the same inputs, as long as what they compute reads nothing
but that state and module constants (the simulator's scenarios: their velocity is a function of their
parameters, profiles and class tables). `value_key` returns None for what it cannot vouch for (a callable
attribute, a file, an object with more than these kinds of state): no key, no sharing.
"""

from __future__ import annotations

import dataclasses
import enum
import types

import numpy as np


class _Unkeyable(Exception):
    pass


_SCALARS = (bool, int, float, complex, str, bytes, type(None))
_MAX_DEPTH = 8


def value_key(obj):
    """The key of `obj` (see the module's docstring), or None."""
    try:
        return _key(obj, 0)
    except _Unkeyable:
        return None


def _key(obj, depth: int):
    if depth > _MAX_DEPTH:
        raise _Unkeyable
    if isinstance(obj, _SCALARS):
        # the type and, for a float, its bits: -0.0 is not 0.0, and a NaN is its own bits (NaN != NaN)
        return (type(obj), np.float64(obj).tobytes()) if type(obj) is float else (type(obj), obj)
    if isinstance(obj, enum.Enum):
        return (type(obj), obj.value)
    if isinstance(obj, (tuple, list)):
        return (type(obj), tuple(_key(x, depth + 1) for x in obj))
    if isinstance(obj, np.ndarray):
        if obj.dtype.hasobject:
            raise _Unkeyable
        return (np.ndarray, obj.dtype.str, obj.shape, np.ascontiguousarray(obj).tobytes())
    if isinstance(obj, np.generic):
        return (type(obj), obj.tobytes())
    if isinstance(obj, (type, types.FunctionType, types.MethodType, types.BuiltinFunctionType)) or callable(obj):
        raise _Unkeyable
    state = []
    if dataclasses.is_dataclass(obj):
        state += [(f.name, _key(getattr(obj, f.name), depth + 1)) for f in dataclasses.fields(obj)]
    if hasattr(obj, "__dict__"):
        state += [(name, _key(value, depth + 1)) for name, value in sorted(vars(obj).items())]
    elif not dataclasses.is_dataclass(obj):
        raise _Unkeyable
    return (type(obj), _class_key(type(obj)), tuple(state))


def _class_key(cls) -> tuple:
    """What the classes of the MRO define, by identity (functions, descriptors) or by value (tables)."""
    out = []
    for c in cls.__mro__:
        if c is object:
            continue
        for name, value in vars(c).items():
            if name in ("__dict__", "__weakref__", "__doc__", "__module__", "__annotations__",
                        "__dataclass_fields__", "__dataclass_params__", "__match_args__", "__slots__"):
                continue
            try:
                out.append((c.__qualname__, name, _key(value, 1)))
            except _Unkeyable:
                try:
                    hash(value)
                except TypeError:
                    raise _Unkeyable from None
                out.append((c.__qualname__, name, "id", value))    # held: the key keeps it alive
    return tuple(out)
