"""numba's ``njit`` when numba is installed, else the plain function.

The compiled kernels (the max envelope here, the optimiser's search in the middleware) are
written in the subset of Python numba compiles, so without numba they still run, slower.
Compiled code is cached on disk next to the sources or in the user's cache folder. Where
neither is writable (a read-only root filesystem, a service user without a home) numba would
refuse to decorate at import; the kernels are then compiled in each process instead (a few
seconds at the first call), with one warning that says how to give them a cache.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["JIT", "jit"]

F = TypeVar("F", bound=Callable[..., Any])

try:  # pragma: no cover - which branch runs depends on the environment
    import numba

    _warned = False

    def jit(f: F) -> F:
        global _warned
        try:
            compiled: F = numba.njit(cache=True, nogil=True)(f)  # type: ignore[assignment]
        except RuntimeError as exc:  # "cannot cache function ...: no locator available"
            if not _warned:
                _warned = True
                warnings.warn(
                    f"numba cannot cache compiled code ({exc}); compiling in this process "
                    "instead. Set NUMBA_CACHE_DIR to a writable folder to cache it.",
                    RuntimeWarning,
                    stacklevel=2,
                )
            compiled = numba.njit(nogil=True)(f)  # type: ignore[assignment]
        return compiled

    JIT = True
except ImportError:  # pragma: no cover

    def jit(f: F) -> F:
        return f

    JIT = False
