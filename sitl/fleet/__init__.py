"""``uav-sitl fleet``: a whole simulated fleet on one machine, as the demo and the e2e backbone.

    uav-sitl fleet --drones N --scene SCENE --duration S [--netns] [--link-rate R]
                   [--link-delay MS] [--link-loss PCT] [--background B]
                   [--summary-json FILE] [--out DIR] [--policy mcts|random|...]

Starts one ``uav-sitl vehicle --count N`` process (N MAVLink vehicles flying a survey of the
scene), N ``uav-companion run`` processes (synthetic camera of the scene, mission spec
``image_streaming``, the run's fleet key, a goodput constraint) and one ``uav-ground-station
run``; waits until the ground station has heard every drone, starts the mission through the
mission manager's API (with the control token), shows a live progress line, and on Ctrl-C,
SIGTERM or after ``--duration`` stops everything (SIGTERM, wait, SIGKILL; each child in its own
process group, and with a parent-death signal, so nothing is left behind) and prints a summary:
per drone images generated/sent/received/stored, mean frame rate and latency, and the fleet's
total utility from ``uav-utility evaluate`` on the merged companion and ground-station logs.

With ``--netns`` (root) every drone (its companion) runs in its own network namespace, the
ground station in another, all on one shaped bridge (:class:`sitl.linkemu.SharedMedium`): the
drones contend for one radio-like channel; the vehicles run in a namespace of their own,
each reached from its drone over an unshaped link (the autopilot's serial line).

The launcher is a thin synchronous shell. Its modules: ``cli`` (argparse, exit codes),
``plan`` (ports, files, policy), ``run`` (the sequence of one run), ``processes`` (children,
stop flag), ``live`` (HTTP API, log tails, progress line), ``link`` (the relay), ``netns``
(namespaces), ``summary`` (the numbers, from ``utility_specs`` and ``ground_station``).
"""

from sitl.fleet.cli import main, parse_args
from sitl.fleet.link import Background, parse_background
from sitl.fleet.live import LogTail, StationTail, progress_line
from sitl.fleet.netns import FleetNetns
from sitl.fleet.plan import make_plan
from sitl.fleet.processes import FleetError, Processes
from sitl.fleet.run import run
from sitl.fleet.summary import (
    evaluate_utility,
    format_phases,
    format_summary,
    red_phases,
    summarize,
)

__all__ = [
    "Background",
    "FleetError",
    "FleetNetns",
    "LogTail",
    "Processes",
    "StationTail",
    "evaluate_utility",
    "format_phases",
    "format_summary",
    "main",
    "make_plan",
    "parse_args",
    "parse_background",
    "progress_line",
    "red_phases",
    "run",
    "summarize",
]
