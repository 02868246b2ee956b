"""numba's ``njit`` when numba is installed, else the plain function.

The compiled kernels (the max envelope here, the optimiser's search in the middleware) are
written in the subset of Python numba compiles, so without numba they still run, slower.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["JIT", "jit"]

F = TypeVar("F", bound=Callable[..., Any])

try:  # pragma: no cover - which branch runs depends on the environment
    import numba

    def jit(f: F) -> F:
        compiled: F = numba.njit(cache=True, nogil=True)(f)  # type: ignore[assignment]
        return compiled

    JIT = True
except ImportError:  # pragma: no cover

    def jit(f: F) -> F:
        return f

    JIT = False
