"""Regenerate ``infdist_preset0_seed0.csv``: the thesis code's own message sequence (issue 18).

The reference implementation (github.com/zeroos/infdist, ``optimization/missions.py``,
``generate_simple_3D_reconstruction`` as called by the ``small`` DropRateVsUtility experiment:
10 agents, t_end 100 s, preset 0, seed 0) draws with numpy's legacy global generator, in this
order: per sender 0..9, the rate f ~ N(1, 0.1) Hz, t_start = int(U(0, 1)) = 0, the mean
depletion rate m ~ N(0.2, 0.2); then per message k (t = k / f < 100) the generation time
|N(t, 0.1)| and the depletion rate max(0.003, N(m, 0.001)). Every message is 2048 bytes with
battery level 1 (level_start = level_end = 1) and weight 3^(sender + 1). This script repeats
that draw (no code of the reference is used or shipped); the CSV is sorted by t_gen as the
reference's MessageSet is.

    .venv/bin/python benchmarks/data/make_infdist_preset0.py
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("infdist_preset0_seed0.csv")


def generate(n_agents: int = 10, t_end: float = 100.0, seed: int = 0) -> list[dict[str, float]]:
    np.random.seed(seed)
    rows = []
    for sender in range(n_agents):
        f = np.random.normal(1, 0.1)
        t_start = int(np.random.random())
        mi = np.random.normal(0.2, 0.2)
        for k, t in enumerate(np.arange(t_start, t_end, 1 / f)):
            t_gen = abs(np.random.normal(t, 0.1))
            rho = max(0.003, np.random.normal(mi, 0.001))
            rows.append({"sender": sender, "k": k, "t_gen": float(t_gen), "size": 2048,
                         "level": 1.0, "depletion_rate": float(rho)})
    rows.sort(key=lambda r: (r["t_gen"], r["sender"]))
    return rows


def main() -> None:
    rows = generate()
    with OUT.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        for r in rows:
            writer.writerow({**r, "t_gen": f"{r['t_gen']:.9f}",
                             "depletion_rate": f"{r['depletion_rate']:.9f}"})
    print(f"{len(rows)} messages -> {OUT}")


if __name__ == "__main__":
    main()
