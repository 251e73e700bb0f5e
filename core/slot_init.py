"""A cheaper `__init__` for the frozen, slotted dataclasses built once per sample or per estimate (ImuSample,
AttitudeEstimate, ...).

A frozen dataclass's generated `__init__` stores each field with `object.__setattr__(self, "name", value)`
(its own `__setattr__` raises): a global and an attribute lookup, then a look-up of the name on the type, per
field. The slot's member descriptor (`cls.__dict__["name"]`) is what that look-up finds, and its `__set__`
stores the value the same way; calling it directly skips the look-ups. The class stays the same dataclass: the
same fields, defaults, signature, frozen `__setattr__`, `replace`, equality and pickling; only the body of
`__init__` differs.
"""

from __future__ import annotations

import dataclasses


_HAS_FACTORY = object()     # the default of a field with a default factory: "not given"


def slot_init(cls):
    """Class decorator (below `@dataclass(frozen=True, slots=True)`): replace the generated `__init__` by one that
    stores the fields through their member descriptors. Refuses what it would not reproduce (a field left out of
    `__init__` or keyword-only, a `__post_init__`)."""
    params = dataclasses.fields(cls)
    if not (cls.__dataclass_params__.frozen and "__slots__" in cls.__dict__) or hasattr(cls, "__post_init__"):
        raise TypeError(f"slot_init needs a frozen, slotted dataclass without __post_init__: {cls.__name__}")
    namespace: dict = {}
    args, body = [], []
    for f in params:
        if not f.init or f.kw_only:
            raise TypeError(f"slot_init: field {cls.__name__}.{f.name} needs the generated __init__")
        if f.default_factory is not dataclasses.MISSING:
            # as dataclasses does: a marker default, replaced by a fresh value from the factory on each call
            namespace[f"_factory_{f.name}"] = f.default_factory
            namespace["_HAS_FACTORY"] = _HAS_FACTORY
            args.append(f"{f.name}=_HAS_FACTORY")
            body.append(f"    if {f.name} is _HAS_FACTORY:\n        {f.name} = _factory_{f.name}()")
        elif f.default is dataclasses.MISSING:
            args.append(f.name)
        else:
            namespace[f"_default_{f.name}"] = f.default
            args.append(f"{f.name}=_default_{f.name}")
        namespace[f"_set_{f.name}"] = cls.__dict__[f.name].__set__
        body.append(f"    _set_{f.name}(self, {f.name})")
    source = f"def __init__(self, {', '.join(args)}):\n" + "\n".join(body or ["    pass"]) + "\n"
    exec(source, namespace)   # noqa: S102 - the source is built above from the field names only, as dataclasses does
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__module__ = cls.__module__
    init.__doc__ = cls.__init__.__doc__
    cls.__init__ = init
    return cls
