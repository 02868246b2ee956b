"""A mission's characteristics (thesis sec. 5.4, figure 7.2): how much a random drop costs.

The utility of one message depends on which others arrived, so the thesis characterises a
mission by the *expected* utility of each message: replay the mission's generated messages
through random drops at several probabilities, and average what each delivered message
added (its leave-one-out marginal: U of its stream with it minus without it). Most messages
worth little next to a few (figure 7.2, the image demonstrator) means a random drop loses
much of the utility and an optimiser has much to win.

Sans-I/O: messages and a seed in, numbers out. Delivery is instant (``t_rcv = t_gen``), as in
the thesis' study; a message with versions is taken in its best version.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from utility_specs.evaluate import evaluate
from utility_specs.message import Message, MessageKey
from utility_specs.spec import MissionSpec

__all__ = ["Characteristics", "DropRun", "characteristics"]

RECEIVER = "ground"


@dataclass(frozen=True, slots=True)
class DropRun:
    """One replay: every message dropped with probability ``drop``."""

    drop: float
    achieved_drop: float
    utility_pct: float
    """Utility received, in % of every message delivered."""


@dataclass(frozen=True, slots=True)
class Characteristics:
    ideal: float
    """U(M) with every generated message delivered at once."""
    runs: list[DropRun]
    expected: dict[MessageKey, float]
    """Per message (sender, seq) delivered in some replay: its mean marginal utility."""

    def normalised(self) -> np.ndarray:
        """Expected utilities over the largest (the thesis' histogram's x axis)."""
        values = np.array(sorted(self.expected.values()), dtype=float)
        top = float(values.max()) if len(values) and values.max() > 0 else 1.0
        return values / top


def _stream_key(spec: MissionSpec, m: Message) -> tuple[str, str | None]:
    return (m.type, m.sender if spec.types[m.type].per_sender else None)


def characteristics(messages: Sequence[Message], spec: MissionSpec, *, t_start: float,
                    t_end: float, drops: Sequence[float], runs: int, seed: int,
                    progress: Callable[[str], None] | None = None) -> Characteristics:
    """Replay ``messages`` (the generated ones, any receiver or none) ``runs`` times at each
    probability of ``drops`` and average each delivered message's marginal utility."""
    if not messages:
        raise ValueError("no generated message of the spec's types in [t_start, t_end]")
    if runs < 1 or any(not 0.0 <= d < 1.0 for d in drops):
        raise ValueError("need runs >= 1 and every drop probability in [0, 1)")
    copies = [dataclasses.replace(m, receiver=RECEIVER, t_sent=m.t_gen, t_rcv=m.t_gen,
                                  version=0 if m.versions else None) for m in messages]
    streams: dict[tuple[str, str | None], list[int]] = defaultdict(list)
    for i, m in enumerate(copies):
        streams[_stream_key(spec, m)].append(i)
    ideal = evaluate(copies, spec, t_start=t_start, t_end=t_end).total
    rng = np.random.default_rng(seed)
    gathered: dict[MessageKey, list[float]] = defaultdict(list)
    out: list[DropRun] = []
    for drop in drops:
        for run in range(runs):
            kept = rng.random(len(copies)) >= drop
            total = 0.0
            for members in streams.values():
                sent = [copies[i] for i in members if kept[i]]
                if not sent:
                    continue
                whole = evaluate(sent, spec, t_start=t_start, t_end=t_end).total
                total += whole
                for k, m in enumerate(sent):
                    rest = sent[:k] + sent[k + 1:]
                    without = evaluate(rest, spec, t_start=t_start, t_end=t_end).total \
                        if rest else 0.0
                    gathered[m.key].append(whole - without)
            pct = 100.0 * total / ideal if ideal > 0 else 100.0
            out.append(DropRun(drop=drop, achieved_drop=1.0 - float(kept.mean()),
                               utility_pct=pct))
            if progress is not None:
                progress(f"drop {drop:.2f} run {run + 1}/{runs}: {pct:.1f} % of the utility")
    expected = {key: float(np.mean(v)) for key, v in gathered.items()}
    return Characteristics(ideal=ideal, runs=out, expected=expected)
