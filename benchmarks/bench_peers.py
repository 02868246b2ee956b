"""Peer sharing on a constrained shared medium (issue 15): MCTS against every baseline.

Four drones share positions (``swarm``, to every peer), images and batteries (to the ground)
over one 40 kB/s medium (``sitl.study.peers``); each baseline runs at the bytes MCTS
delivered. Goals: MCTS's total utility (at every receiver) is not below any baseline's, and
its peers' positions are at least as fresh (mean age). Prints the table and exits non-zero
on a miss. Run: ``.venv/bin/python benchmarks/bench_peers.py [--seeds 5] [--t-end 40]``
(about 40 s on a quiet 2-core machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

from sitl.study.peers import policy_means, run_seed, table


def goals(rows: list[dict[str, Any]]) -> list[tuple[str, str, bool]]:
    """(goal, measured, met) for the total utility and the peers' mean position age."""
    mean = policy_means(rows)
    ours = mean["mcts"]
    out = []
    for p, m in mean.items():
        if p == "mcts":
            continue
        out.append((f"total utility: mcts >= {p}",
                    f"{ours['utility_total_pct']:.1f} vs {m['utility_total_pct']:.1f} %",
                    ours["utility_total_pct"] >= m["utility_total_pct"]))
        out.append((f"peer age mean: mcts <= {p}",
                    f"{ours['peer_age_mean_s']:.2f} vs {m['peer_age_mean_s']:.2f} s",
                    ours["peer_age_mean_s"] <= m["peer_age_mean_s"]))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--t-end", type=float, default=40.0, help="mission length, s")
    args = parser.parse_args(argv)
    if args.seeds < 1 or not args.t_end > 2.0:
        parser.error("--seeds >= 1 and --t-end > 2 expected")
    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    for seed in range(1, args.seeds + 1):
        rows += run_seed(seed, t_end=args.t_end)
        print(f"seed {seed}/{args.seeds} done, {time.perf_counter() - started:.0f} s",
              flush=True)
    print()
    print(table(rows))
    results = goals(rows)
    for goal, measured, met in results:
        print(f"{goal:<36} {measured:>22}  {'ok' if met else 'MISS'}")
    print(f"\nload average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"{time.perf_counter() - started:.0f} s")
    return 0 if all(met for _, _, met in results) else 1


if __name__ == "__main__":
    sys.exit(main())
