"""Study: the adaptive goodput constraint against AIMD (thesis figure 6.5) and RFC 8867 5.1.

``uav-sitl study adaptive-vs-aimd --out DIR`` runs, on a seeded packet-level model of a
bottleneck link, (a) the figure 6.5 scenario (on/off application demand, background traffic
stepping up half-way) with the adaptive constraint and with AIMD, and (b) the capacity
schedule of RFC 8867 test 5.1 (1 -> 2.5 -> 0.6 -> 1 x capacity at 0/40/60/80 s) with adaptive,
AIMD and a fixed constraint; it writes one CSV per run and PNG panels (constraint,
application goodput, background / capacity). With ``--real`` (root, iproute2, iperf3) it also
runs the RFC schedule on a real kernel link between network namespaces (see
:func:`~sitl.study.adaptive.reallink.run_link_experiment`).

The link model (:func:`simulate`) is a FIFO bottleneck with a byte-bounded queue, fed by
Poisson application and background packets (uncoordinated traffic, ch. 6.1): queueing delay
and hence ‖W‖_Δ grow with load and background as in figures 6.1/6.2. Deliveries come back to
the sender as periodic receiver reports, which is when the constraint learns (not at send).

Modules: :mod:`~sitl.study.adaptive.model` (the link model), :mod:`~sitl.study.adaptive.reallink`
(real-link runs and their metrics), :mod:`~sitl.study.adaptive.figures` (the command, CSVs,
plots). Everything public is re-exported here.
"""

from __future__ import annotations

from sitl.study.adaptive.figures import (
    MBIT,
    figure_6_5_runs,
    main,
    plot_link_runs,
    plot_model_runs,
    rfc8867_model_runs,
    write_link_csv,
    write_trace_csv,
)
from sitl.study.adaptive.model import (
    ObservedConstant,
    Rate,
    SimLink,
    SimTrace,
    Step,
    equilibrium_rate,
    mean_backlog_at_rate,
    simulate,
    steps,
)
from sitl.study.adaptive.reallink import (
    LINK_CONSTRAINT_KINDS,
    MESSAGE_BYTES,
    REAL_LINK_CONSTRAINTS,
    LinkRun,
    LinkScenario,
    PhaseMetrics,
    background_step,
    phase_metrics,
    rfc8867_5_1,
    run_link_experiment,
)

__all__ = [
    "LINK_CONSTRAINT_KINDS",
    "MBIT",
    "MESSAGE_BYTES",
    "REAL_LINK_CONSTRAINTS",
    "LinkRun",
    "LinkScenario",
    "ObservedConstant",
    "PhaseMetrics",
    "Rate",
    "SimLink",
    "SimTrace",
    "Step",
    "background_step",
    "equilibrium_rate",
    "figure_6_5_runs",
    "main",
    "mean_backlog_at_rate",
    "phase_metrics",
    "plot_link_runs",
    "plot_model_runs",
    "rfc8867_5_1",
    "rfc8867_model_runs",
    "run_link_experiment",
    "simulate",
    "steps",
    "write_link_csv",
    "write_trace_csv",
]
