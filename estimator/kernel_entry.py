"""A compiled kernel's directly callable entry point, for the filters' one-sample paths (`mekf_core`,
`ins_core`).

Numba's dispatcher resolves the argument types on every call (several times a filter step's own arithmetic);
the entry point of one compiled signature skips that. The arguments must then have exactly that signature,
which the entry point does not check (an int64 array would be read as float64): the callers pass their own
buffers and check what comes from outside."""

from __future__ import annotations


def entry_point(kernel, sig: tuple):
    """`kernel` (a numba dispatcher) compiled for the argument types `sig`, as that overload's entry point;
    the dispatcher itself if this numba version does not expose entry points (same code, slower call)."""
    try:
        kernel.compile(sig)
        return kernel.overloads[sig].entry_point
    except Exception:  # pragma: no cover - numba internals moved
        pass
    return kernel  # pragma: no cover
