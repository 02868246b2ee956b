"""Time to evaluate a 10-agent, 100 s mission with every utility function (issue 2 target).

Prints a table (messages, median and p95 time per evaluation) and exits non-zero when the
median is not under the target. Run: ``.venv/bin/python benchmarks/bench_model.py``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from utility_specs.evaluate import evaluate
from utility_specs.files import builtin_spec
from utility_specs.message import Message, StateHistory, Version

TARGET_MS = 50.0
# (type, rate Hz) per agent: 1 Hz telemetry, 4 images/s split over the four image types
# (a drone has one camera), sparse objectives, map patches and scores.
STREAMS = [("battery", 1.0), ("position", 1.0), ("status", 0.1), ("heartbeat", 1.0),
           ("objective", 0.05), ("map", 0.2), ("video", 1.0), ("thumbnail", 0.5),
           ("image", 2.0), ("target", 0.5), ("score", 0.5), ("linear", 1.0)]
VERSIONS = (Version(name="full", size=60_000, quality=1.0),
            Version(name="half", size=18_000, quality=0.5),
            Version(name="quarter", size=6_000, quality=0.25))


def mission(seed: int, agents: int = 10, duration_s: float = 100.0) -> tuple[
        list[Message], dict[str, StateHistory]]:
    rng = np.random.default_rng(seed)
    messages: list[Message] = []
    for a in range(agents):
        sender = f"drone{a}"
        for type_name, rate in STREAMS:
            period = 1.0 / rate
            t = float(rng.uniform(0, period))
            seq = 0
            while t < duration_s:
                data: dict[str, object] = {}
                versions: tuple[Version, ...] = ()
                version = None
                if type_name == "battery":
                    data = {"level": float(1.0 - 0.004 * t)}
                elif type_name == "objective":
                    data = {"objective": f"o{int(rng.integers(0, 5))}"}
                elif type_name == "map":
                    x, y = rng.integers(0, 40, size=2)
                    data = {"cells": [[int(x + i), int(y + j)] for i in range(4) for j in range(4)]}
                elif type_name in ("image", "thumbnail"):
                    data = {"red": float(rng.choice([0.0, 0.0, 0.02, 0.3]))}
                    versions, version = VERSIONS, int(rng.integers(0, 3))
                elif type_name == "target":
                    data = {"object": bool(rng.random() < 0.2)}
                elif type_name == "score":
                    data = {"value": float(rng.uniform(0, 5))}
                lost = rng.random() < 0.1
                t_rcv = None if lost else t + float(rng.exponential(0.15))
                messages.append(Message(
                    sender=sender, receiver="gs", seq=seq, type=f"{type_name}", t_gen=t,
                    t_sent=t, t_rcv=t_rcv, size=versions[version].size if versions else 64,
                    data=data, versions=versions, version=version))
                seq += 1
                t += period * float(rng.uniform(0.9, 1.1))
    history = StateHistory(
        (float(t), {"objectives": [f"o{int(i)}" for i in rng.choice(5, 2, replace=False)],
                    "observed_cells": [[int(t) % 40 + i, 20 + j] for i in range(3)
                                       for j in range(3)]})
        for t in np.arange(0.0, duration_s, 2.0))
    return messages, {"gs": history}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args(argv)
    spec = builtin_spec("all_types")
    messages, states = mission(seed=1)
    timings = []
    result = None
    for _ in range(args.repeat):
        start = time.perf_counter()
        result = evaluate(messages, spec, t_end=100.0, states=states)
        timings.append((time.perf_counter() - start) * 1000)
    assert result is not None
    median = statistics.median(timings)
    p95 = sorted(timings)[int(0.95 * (len(timings) - 1))]
    ok = median < TARGET_MS
    print(f"{'case':<34} {'messages':>9} {'median ms':>10} {'p95 ms':>8} {'target':>8}  result")
    print(f"{'10 agents, 100 s, 12 types':<34} {len(messages):>9} {median:>10.1f} {p95:>8.1f} "
          f"{'<' + str(TARGET_MS):>8}  {'ok' if ok else 'MISS'}")
    print(f"total utility {result.total:.3f}; per type: "
          + ", ".join(f"{k}={v:.1f}" for k, v in result.per_type.items()))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
