"""A compiled kernel's directly callable entry point, for the filters' one-sample paths (`mekf_core`,
`ins_core`).

Numba's dispatcher resolves the argument types on every call (several times a filter step's own arithmetic);
the entry point of one compiled signature skips that. The arguments must then have exactly that signature,
which the entry point does not check (an int64 array would be read as float64): the callers pass their own
buffers and check what comes from outside."""

from __future__ import annotations

import numpy as np


def entry_point(kernel, sig: tuple):
    """`kernel` (a numba dispatcher) compiled for the argument types `sig`, as that overload's entry point;
    the dispatcher itself if this numba version does not expose entry points (same code, slower call)."""
    try:
        kernel.compile(sig)
        return kernel.overloads[sig].entry_point
    except Exception:  # pragma: no cover - numba internals moved
        pass
    return kernel  # pragma: no cover


# an array's numba type by what numba's typeof reads of it (numba.core.typing.typeof._typeof_ndarray: the dtype, the
# dimensions, the layout from the contiguity flags, read-only; the class, for a subclass such as np.recarray): numba
# builds a structured dtype's type field by field at every typeof, milliseconds for ins's records at each construction
_ARRAY_TYPES: dict = {}


def argument_types(kernel, args: tuple) -> tuple:
    """The numba types of `args` (`kernel.typeof_pyval` of each), an array's looked up once per process."""
    types = []
    for a in args:
        if type(a) in (np.ndarray, np.recarray):
            f = a.flags
            key = (type(a), a.dtype, a.dtype.isalignedstruct, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable)
            t = _ARRAY_TYPES.get(key)
            if t is None:
                t = _ARRAY_TYPES[key] = kernel.typeof_pyval(a)
            types.append(t)
        else:
            types.append(kernel.typeof_pyval(a))
    return tuple(types)
