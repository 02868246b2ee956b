"""The price of bytes at the root: a send must earn the utility per byte the horizon pays.

The tree plans the fleet's sends from what this agent knows; room it sees free in the window
is often taken by the others' frames it has not heard of yet (they arrive later than planned:
the fleet overshoots ξ). So a cheap, low-value option the tree squeezes into that room (a
quarter-size copy of a frame, a plain frame in a burst) is not free: its bytes displace a
denser message, now or later. The gate keeps the tree's option only when it earns at least
the density at which the horizon's messages fill the budget (the default policy's threshold,
:func:`~companion.middleware.mcts.rollout_threshold`); otherwise the best option that does,
or drop.
"""

from __future__ import annotations

from companion.middleware.incremental import Problem

__all__ = ["priced_option"]


def priced_option(problem: Problem, level: int, option: int, lam: float) -> int:
    """``option`` for ``level`` if it earns ``lam`` per byte over its stream's base, else the
    option with the most utility among those that do (0, drop, when none does)."""
    if option == 0 or lam <= 0 or not 0 <= level < problem.n:
        return option
    earning = [
        o for o in range(1, int(problem.nopt[level]))
        if float(problem.gain[level, o, 0]) >= lam * max(1, int(problem.size[level, o]))
    ]
    if option in earning:
        return option
    # a larger option than the tree's may not fit its window: only smaller ones replace it
    cap = int(problem.size[level, option])
    smaller = [o for o in earning if int(problem.size[level, o]) <= cap]
    return max(smaller, key=lambda o: float(problem.gain[level, o, 0]), default=0)
