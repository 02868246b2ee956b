"""A run's plan from the command line: ports, files, budgets and the companions' policy."""

from __future__ import annotations

import argparse
import socket
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sitl.fleet.link import RELAY_PRICE_RATE_S, relay_constraint_params
from sitl.fleet_config import DroneSlot, FleetPlan, free_port, mission_spec_path

POLICIES = ("mcts", "random", "send_all")
COMPANION_POLICY = {"mcts": "mcts", "random": "random_drop", "send_all": "send_all"}
"""``--policy`` -> the companion's ``[middleware] policy``."""
"""``mcts``: the companion's middleware (ch. 5); ``random``: drop each message with
``--drop-probability`` (the baseline of thesis fig. 5.7); ``send_all``: no optimisation."""


def _scene_arg(scene: str) -> str:
    from sitl.scenes import load_scene

    path = Path(scene)
    if path.suffix == ".toml" or path.exists():
        scene = str(path.resolve())
    load_scene(scene)  # fail early with the scene's own error
    return scene


def make_plan(args: argparse.Namespace, run_dir: Path, *, netns: bool = False) -> FleetPlan:
    """Ports, files and budgets of a run (loopback, or the namespaces' addresses)."""
    from sitl.linkemu import GROUND_ADDR, SharedMedium

    drones = tuple(
        DroneSlot(index=i, drone_id=f"drone{i + 1}", system_id=i + 1,
                  mavlink_port=free_port(), folder=run_dir / "drones" / f"drone{i + 1}",
                  mavlink_host=SharedMedium.vehicle_addrs(i)[1] if netns else None)
        for i in range(args.drones))
    params: dict[str, Any] = {}
    relay = getattr(args, "relay", False)
    if args.constraint == "constant":
        params = {"limit_bytes_per_s": float(args.goodput), "window_s": float(args.window)}
    elif relay:
        params = relay_constraint_params(args.constraint, args.relay_rate / 8.0)
    return FleetPlan(
        run_dir=run_dir, drones=drones, scene=_scene_arg(args.scene),
        spec_path=mission_spec_path(args.spec), gs_udp_port=free_port(),
        gs_http_port=args.http_port or free_port(kind=socket.SOCK_STREAM),
        gs_host=GROUND_ADDR if netns else "127.0.0.1",
        relay_port=free_port() if relay else None,
        gs_bind_host="0.0.0.0" if netns else "127.0.0.1",
        drone_bind_host="0.0.0.0" if netns else "127.0.0.1",
        drone_listen_host="0.0.0.0" if netns else "127.0.0.1",
        camera_rate_hz=args.rate, camera_width=args.width, camera_height=args.height,
        mcts_iterations=args.mcts_iterations, time_budget_s=args.time_budget,
        constraint=args.constraint, constraint_params=params, alpha=args.alpha, seed=args.seed,
        policy=COMPANION_POLICY[args.policy], drop_probability=args.drop_probability,
        fleet_share=args.fleet_share,
        price_rate_s=RELAY_PRICE_RATE_S if relay and args.constraint != "constant" else None,
        # every shaped link paces each message at its rate: a camera frame larger than the
        # relay's queue only gets through paced, and two drones' frames at once fill half
        # as much of it (docs/protocol.md, pacing; docs/adaptive.md, the narrow link)
        link_rate_bytes_per_s=(args.link_rate / 8.0 if netns
                               else args.relay_rate / 8.0 if relay else 0.0),
        **_peers_plan(args, drones, netns=netns))


def _peers_plan(args: argparse.Namespace, drones: Sequence[DroneSlot], *,
                netns: bool = False) -> dict[str, Any]:
    """the medium and /peers ports of ``--peers`` (sitl.fleet_peers)."""
    if not getattr(args, "peers", False):
        return {}
    from sitl.fleet_peers import loopback_medium, netns_medium

    return {"peers_medium": netns_medium(free_port()) if netns else loopback_medium(),
            "peers_http_ports": {d.drone_id: free_port(kind=socket.SOCK_STREAM)
                                 for d in drones}}
