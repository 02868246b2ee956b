"""The price of bytes at the root: a send must earn the utility per byte the horizon pays.

The tree plans the fleet's sends from what this agent knows; room it sees free in the window
is often taken by the others' frames it has not heard of yet (they arrive later than planned:
the fleet overshoots ξ). So a cheap, low-value option the tree squeezes into that room (a
quarter-size copy of a frame, a plain frame in a burst) is not free: its bytes displace a
denser message, now or later. The gate keeps the tree's option only when it earns at least
the density at which the horizon's messages fill the budget (:func:`price_per_byte`);
otherwise the best option that does, or drop.

The price counts each message in its densest version with that version's bytes. Round 5
used the default policy's threshold (:func:`~companion.middleware.mcts.rollout_threshold`),
which takes the density of the densest version but the bytes of the full one: when ξ·T is
below a few full frames (the demo's adaptive ξ of about 10 kB/s over T = 2 s, below one
31 kB frame), the first frame filled the budget, the price was the best forecast frame's
density, and each drone sent only the top frames of its *own* stream, about as often as
every other drone: the red drone's share over red was 1.0-3.3x (round 6).

This module also holds the window check that decides whether a send is a planned violation
(:func:`creates_violation`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from companion.middleware.incremental import Problem

__all__ = ["creates_violation", "price_per_byte", "priced_option"]


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


def creates_violation(sends: Iterable[tuple[float, int]], *, now: float, size: int,
                      window_s: float, budget_bytes: float) -> bool:
    """Would ``size`` bytes sent at ``now`` make a window of eq. 5.5/5.7 break the budget
    that did not before? The windows are ``[t, t + T]`` from each send instant ``t``
    (``sends``: (time, bytes), none after ``now``); the new send's own window holds only
    itself. A window that the others' sends already put over the budget is violated
    whatever this agent does: a send inside it adds no violated instant (thesis eq. 5.5
    counts instants), so it is not a planned violation."""
    if size > budget_bytes + 1e-9:
        return True
    recent = sorted((t, b) for t, b in sends if now - window_s - 1e-9 <= t <= now + 1e-9)
    total = sum(b for _, b in recent)
    for _, b in recent:  # the window from each instant holds every recent send from it on
        if total <= budget_bytes + 1e-9 < total + size:
            return True
        total -= b
    return False


def price_per_byte(problem: Problem, *, level: int | None = None,
                   expected: Mapping[str, float] | None = None) -> float:
    """The utility per byte at which the horizon's messages, densest first, fill the budget
    over the horizon: each message counted in its densest version, with that version's
    bytes (the density and the bytes of one and the same option).

    A message's gain is over its stream's base, as if it were the stream's only send. With
    ``level`` (the decided message), the later messages of its own stream count what they
    add once it is sent (round 11): a redder frame to come still raises the price (the
    value of waiting), but a copy does not. Counted on their own, a red drone's own
    forecast frames, each worth more the longer after its last send, set a price its
    current frame never earned: it sent a half frame per ~2 s with the window half empty.

    The other drones' streams stay independent: pricing each of their frames at what it
    adds after the previous one (as if all were sent) let plain drones take 1/3 of a
    2-drone link that the red drone should mostly have (round 11, not kept).

    With ``expected`` (sender -> the bytes it is expected to send over the horizon, from
    its reported rate), another agent's messages with versions count only up to those
    bytes, its densest first: the forecast has a frame per camera period, but a drone on
    a narrow link sends one in five or fewer. Counted all, each of them denser than this
    agent's frame (their bases age as its own does), the price rose above every drone's
    own frame whenever the fleet was silent, and the whole demo fleet sent no image for
    8-18 s with the link empty (docs/adaptive.md, "The decider's lag"). The bytes heard
    are the versions sent (half frames, ~8 kB), those counted the densest versions (often
    the full frame, ~30 kB): a drone heard sending a half frame a second counts about one
    frame per 3 s horizon, not three.
    """
    n = problem.n
    if n == 0:
        return 0.0
    opts = np.arange(1, problem.size.shape[1])
    gains = problem.gain[np.arange(n)[:, None], opts[None, :], np.zeros((n, 1), dtype=np.int64)]
    sizes = np.maximum(1, problem.size[:, 1:])
    per_byte = gains / sizes
    per_byte[opts[None, :] >= problem.nopt[:, None]] = -np.inf
    best = per_byte.argmax(axis=1)
    density = np.maximum(per_byte[np.arange(n), best], 0.0)
    nbytes = sizes[np.arange(n), best].astype(np.float64)
    own = int(problem.stream[level]) if level is not None and 0 <= level < n else -1
    if own >= 0 and level is not None:
        after = problem.next_slot(level, int(best[level]) + 1, 0)
        for i in range(level + 1, n):
            if int(problem.stream[i]) == own:
                gain = float(problem.gain[i, int(best[i]) + 1, after])
                density[i] = max(0.0, gain / nbytes[i])
    if expected is not None:
        density = _expected_only(problem, density, nbytes, expected, level=level)
    span = float(problem.send_t[-1] - problem.send_t[0])
    capacity = problem.budget_bytes * max(1.0, span / problem.window_s)
    order = np.lexsort((nbytes, density))[::-1]  # densest first; ties: larger first
    order = order[np.isfinite(density[order])]  # not left out (``expected``)
    over = np.nonzero(np.cumsum(nbytes[order]) > capacity)[0]
    return float(density[order[over[0]]]) if len(over) else 0.0


def _expected_only(problem: Problem, density: np.ndarray, nbytes: np.ndarray,
                   expected: Mapping[str, float], *, level: int | None) -> np.ndarray:
    """``density`` with the versioned messages of other agents beyond their ``expected``
    bytes set to -inf (left out of the price): per sender, densest first, a message counts
    while the sender's counted bytes stay within half a message of its expected bytes."""
    own = problem.items[level].message.sender if level is not None and 0 <= level < problem.n \
        else None
    out = density.copy()
    by_sender: dict[str, list[int]] = {}
    for i, item in enumerate(problem.items):
        sender = item.message.sender
        if sender != own and item.message.versions and i != level:
            by_sender.setdefault(sender, []).append(i)
    for sender, idx in by_sender.items():
        room = float(expected.get(sender, 0.0))
        for i in sorted(idx, key=lambda j: (-density[j], -nbytes[j])):
            if room >= 0.5 * nbytes[i]:
                room -= nbytes[i]
            else:
                out[i] = -np.inf
    return out
