"""Compile the optimiser's numba kernels into their on-disk cache ahead of the first run.

``python -m companion.warm_cache`` (``make demo`` and ``make test`` run it once after the
install): one process compiles once, instead of every companion of the first ``make demo``
compiling the same kernels at the same time (31 s and still unfinished for four drones on two
loaded cores). Where the cache lives is numba's choice (next to the sources, or
``NUMBA_CACHE_DIR``), the same the companions will read.
"""

from __future__ import annotations

import sys
import time

from companion.app import build_decider
from companion.config import parse_config

__all__ = ["main", "warm_cache"]


def warm_cache(spec: str = "builtin:image_streaming") -> float:
    """One warm-up decision round on the default policy; seconds it took."""
    config = parse_config({"drone": {"id": "warm-cache"}, "mission": {"spec": spec}})
    decider = build_decider(config)
    t0 = time.perf_counter()
    warm_up = getattr(decider, "warm_up", None)
    if warm_up is not None:
        warm_up()
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    del argv
    try:
        seconds = warm_cache()
    except (ImportError, OSError, RuntimeError, ValueError) as exc:  # an optimisation only
        print(f"warm-cache: not warmed ({exc}); the first run compiles instead",
              file=sys.stderr)
        return 1
    print(f"warm-cache: optimiser compiled and cached in {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
