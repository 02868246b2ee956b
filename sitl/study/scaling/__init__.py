"""Fleet-size scaling (issue 16): decide time, report size, memory and utility at 10..100 agents.

``uav-sitl study scaling --out DIR [--quick] [--agents 10,25,50,100] [--scheduler ADDR]``
runs every fleet size on the shared medium of :mod:`sitl.netsim` (one broadcast channel:
every agent overhears every delivery, as in the thesis' ch. 5.4 setup) in two workloads:

- ``images``: the companion's own configuration (``build_decider``'s defaults: 300
  iterations, horizon 3 s, adaptive constraint fed by simulated receiver reports), each drone
  5 frames/s in 3 versions (40/10/2.5 kB), 1 Hz position, 0.2 Hz battery, on a 1 Mbit/s link;
- ``battery``: the thesis' reference scenario (mostly-low, 2048-byte messages at ~1 Hz per
  agent, 1500 iterations, horizon 5 s), the message budget per window scaled with the fleet
  (9.25 per 10 agents: drop share ~0.75 at every size, measured).

Per cell: decide() wall and CPU time (mean, p99) after the first horizon (the fleet is known
by then); the receiver reports the ground station would send for that run
(:class:`~ground_station.reports.ReportScheduler` and the product's
:class:`~companion.protocol.encoder.Encoder`): bytes per report and the downlink they take,
one copy per drone; memory: how far the process's peak RSS rose above its RSS at the start
of the run (a lower bound: memory freed by an earlier cell of the same process is reused;
tracemalloc would slow the timed run ~3x) and each agent's retained state at the end
(pickled; the mission spec they share counts once, so tiny fleets look heavier); utility.
``optimum`` cells compare MCTS with the exact offline optimum on short missions; ``long``
cells measure whether decide time grows with mission length: the battery scenario made
periodic (every 10 s), decide CPU time in its last whole cycles against its first ones, so
both hold the same phases of the load pattern. Timing
cells run one at a time by default (``--workers 1``) so they do not compete for the CPU.
Writes ``scaling.csv`` (streamed, resumable), ``scaling.png`` and prints the table with the
goals of issue 16.

The package: ``workloads`` (the fleets and their reports), ``cell`` (one measured cell),
``goals`` (issue 16's goals, the table), ``cli`` (the sweep, CSV and plot).
"""

from sitl.study.scaling.cell import COLUMNS, growth, like_phase_blocks, scaling_cell, within
from sitl.study.scaling.cli import _agents, main, plan
from sitl.study.scaling.goals import (
    GOAL_AGENTS,
    Goal,
    check_goals,
    growth_goals,
    speed_goals,
    table,
)
from sitl.study.scaling.workloads import (
    CYCLE_S,
    FLEET_SIZES,
    RUNS,
    GrowingCost,
    ReportSizes,
    fleet_spec,
    image_agents,
    report_sizes,
)

__all__ = [
    "COLUMNS",
    "CYCLE_S",
    "FLEET_SIZES",
    "GOAL_AGENTS",
    "RUNS",
    "Goal",
    "GrowingCost",
    "ReportSizes",
    "_agents",
    "check_goals",
    "fleet_spec",
    "growth",
    "growth_goals",
    "image_agents",
    "like_phase_blocks",
    "main",
    "plan",
    "report_sizes",
    "scaling_cell",
    "speed_goals",
    "table",
    "within",
]
