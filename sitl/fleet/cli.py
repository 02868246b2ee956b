"""``uav-sitl fleet`` command line: argparse, and the exit codes of :func:`main`."""

from __future__ import annotations

import argparse
import math
import os
import socket
import sys
from collections.abc import Sequence
from pathlib import Path

from companion.cli_help import DefaultsRawFormatter
from companion.middleware.constraints.registry import CONSTRAINTS
from sitl.camera_cli import MAX_SIDE
from sitl.fleet.link import (
    RELAY_BACKGROUND_SHARE,
    RELAY_QUEUE_BYTES,
    RELAY_RATE_BIT_S,
    WIFI_G_DELAY_MS,
    WIFI_G_LOSS_PERCENT,
    WIFI_G_RATE_BIT_S,
    Background,
    parse_background,
)
from sitl.fleet.plan import POLICIES
from sitl.fleet.processes import FleetError
from sitl.fleet.run import run
from sitl.fleet_config import mission_spec_path


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="uav-sitl fleet", formatter_class=DefaultsRawFormatter,
        description="Run N simulated drones (vehicle + synthetic camera + uav-companion) and a\n"
                    "uav-ground-station on one machine; print the dashboard's login link first\n"
                    "and a summary at the end (Ctrl-C or --duration stops it).",
        epilog="examples:\n"
               "  uav-sitl fleet --duration 120                 # what `make demo` runs\n"
               "  uav-sitl fleet --drones 2 --relay-rate 0      # straight over loopback")
    p.add_argument("--drones", type=int, default=4, help="number of drones (default 4)")
    p.add_argument("--scene", default="demo", help="scene name (sitl/scenes) or TOML path")
    p.add_argument("--duration", type=float, default=0.0,
                   help="seconds of mission after the start; 0 = until Ctrl-C (default)")
    p.add_argument("--out", type=Path, default=None,
                   help="run folder (default out/fleet/YYYYmmdd-HHMMSS)")
    p.add_argument("--summary-json", type=Path, default=None, help="also write the summary here")
    p.add_argument("--policy", choices=POLICIES, default="mcts",
                   help="what decides which messages go out (default mcts)")
    p.add_argument("--drop-probability", type=float, default=0.5,
                   help="--policy random: probability of dropping each message (default 0.5)")
    p.add_argument("--constraint", choices=sorted(CONSTRAINTS), default=None,
                   help="goodput constraint (default: constant on loopback, adaptive with "
                        "--netns or the relay; adaptive-smooth: docs/adaptive.md)")
    p.add_argument("--goodput", type=float, default=None,
                   help="constant constraint: fleet goodput limit in bytes/s (default 40000; "
                        "given alone, it selects the constant constraint)")
    p.add_argument("--window", type=float, default=2.0,
                   help="constant constraint: window T in s (default 2)")
    p.add_argument("--rate", type=float, default=5.0, help="camera frames/s per drone")
    p.add_argument("--size", default="640x480", help="camera frame size WxH (default 640x480)")
    p.add_argument("--mcts-iterations", type=int, default=300,
                   help="optimiser iterations per decision, as in the thesis")
    p.add_argument("--time-budget", type=float, default=0.05,
                   help="wall time per middleware decision in s (default 0.05)")
    p.add_argument("--alpha", type=float, default=None, help="α of eq. 7.1 (default: spec's)")
    p.add_argument("--spec", default=None,
                   help="mission spec name or TOML path (default image_streaming; with --peers, "
                        "peer_sharing)")
    p.add_argument("--speedup", type=float, default=1.0, help="vehicle simulation speed-up")
    p.add_argument("--flavour", choices=("px4", "ardupilot"), default="px4",
                   help="the simulated autopilots' MAVLink habits")
    p.add_argument("--first-fix", type=float, default=2.0, metavar="S",
                   help="vehicle seconds from boot to a GPS fix; until then no position and"
                        " no arming, as on a real autopilot (default 2; `uav-sitl vehicle`"
                        " defaults to an ArduCopter-like 15)")
    p.add_argument("--pattern", choices=("survey", "orbit"), default="survey",
                   help="what the drones fly: survey strips or orbits")
    p.add_argument("--seed", type=int, default=0, help="seed of the vehicles and optimisers")
    p.add_argument("--ready-timeout", type=float, default=90.0,
                   help="seconds to wait for the vehicles, the ground station's API and then "
                   "every drone to be heard, each (default 90; a loaded host is slow)")
    p.add_argument("--warm-up-timeout", type=float, default=180.0, metavar="S",
                   help="then wait this long for every companion's optimiser to warm up "
                        "(numba compiles on a cold cache); after it, start anyway "
                        "(default 180)")
    p.add_argument("--start-delay", type=float, default=1.0,
                   help="the mission starts this many seconds after the command (default 1)")
    p.add_argument("--http-port", type=int, default=0,
                   help="dashboard port (default: a free one)")
    p.add_argument("--netns", action="store_true",
                   help="(root) each drone in its own network namespace, all joined to the "
                        "ground station's through one shaped shared link (tc)")
    p.add_argument("--link-rate", type=float, default=WIFI_G_RATE_BIT_S,
                   help="--netns: link rate in bit/s (default 6e6, 802.11g-like)")
    p.add_argument("--link-delay", type=float, default=WIFI_G_DELAY_MS, metavar="MS",
                   help=f"--netns: one-way delay in ms (default {WIFI_G_DELAY_MS:g}; needs "
                        "netem in the kernel, else reported as not emulated)")
    p.add_argument("--link-loss", type=float, default=WIFI_G_LOSS_PERCENT, metavar="PCT",
                   help=f"--netns: loss per datagram in %% (default {WIFI_G_LOSS_PERCENT:g}; "
                        "needs netem)")
    p.add_argument("--background", default=None, metavar="BITS[@T[+D]]",
                   help="background traffic of BITS bit/s from T s after the start for D s "
                        "(default from the start, to the end; thesis fig 7.4): iperf3 with "
                        "--netns, in the relay's queue otherwise (relay default: 40%% of its "
                        "rate from mid-mission; 'off' for none)")
    p.add_argument("--relay-rate", type=float, default=RELAY_RATE_BIT_S, metavar="BITS",
                   help="without --netns: the shaped relay's rate in bit/s between the drones "
                        f"and the station (default {RELAY_RATE_BIT_S:g}); 0 = no relay, "
                        "straight over loopback")
    p.add_argument("--relay-queue", type=int, default=RELAY_QUEUE_BYTES, metavar="BYTES",
                   help=f"the relay's queue limit in bytes (default {RELAY_QUEUE_BYTES})")
    p.add_argument("--quiet", action="store_true", help="no live progress line")
    p.add_argument("--fleet-share", action=argparse.BooleanOptionalAction, default=True,
                   help="mcts: give each companion the fleet's size ([middleware] fleet_size): "
                        "at the mission start it leaves unheard peers their share of the "
                        "budget (default on: the start's full frames no longer overflow the "
                        "relay; measured in docs/middleware.md, round 7)")
    p.add_argument("--peers", action="store_true",
                   help="peer sharing (docs/peers.md): a broadcast medium (loopback, or the "
                        "--netns bridge), each "
                        "drone's peers in its autopilot (ADSB_VEHICLE) and at GET /peers; "
                        "the spec defaults to peer_sharing (a spec with receivers = [\"peers\"])")
    args = p.parse_args(list(argv))
    if not 1 <= args.drones <= 64:
        p.error("--drones must be in 1..64")
    if not args.duration >= 0:  # nan too
        p.error("--duration must be >= 0")
    if not args.warm_up_timeout >= 0:
        p.error("--warm-up-timeout must be >= 0")
    if not 0.0 <= args.first_fix < 1e6:
        p.error("--first-fix must be a number of seconds >= 0")
    # checked here, not by each child after the launcher announced the run
    positive = {"--rate": args.rate, "--time-budget": args.time_budget,
                "--window": args.window, "--speedup": args.speedup,
                "--ready-timeout": args.ready_timeout}
    for flag, value in positive.items():
        if not 0 < value < math.inf:
            p.error(f"{flag} must be a finite number > 0, got {value}")
    if not 1 <= args.mcts_iterations <= 1_000_000:
        p.error(f"--mcts-iterations must be in 1..1000000, got {args.mcts_iterations}")
    if args.goodput is not None and not 0 <= args.goodput < math.inf:
        p.error(f"--goodput must be a finite number of bytes/s >= 0, got {args.goodput}")
    if not 0 <= args.start_delay < math.inf:
        p.error(f"--start-delay must be a number of seconds >= 0, got {args.start_delay}")
    if args.alpha is not None and not math.isfinite(args.alpha):
        p.error(f"--alpha must be a finite number, got {args.alpha}")
    if not 0.0 <= args.drop_probability <= 1.0:
        p.error("--drop-probability must be in [0, 1]")
    if args.link_rate <= 0:
        p.error("--link-rate must be > 0")
    if args.link_delay < 0:
        p.error("--link-delay must be >= 0")
    if not 0.0 <= args.link_loss < 100.0:
        p.error("--link-loss must be in [0, 100)")
    try:
        w, h = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        p.error(f"--size: expected WxH, got {args.size!r}")
    if not (16 <= w <= MAX_SIDE and 16 <= h <= MAX_SIDE):
        p.error(f"--size: width and height must be in 16..{MAX_SIDE}, got {args.size!r}")
    args.width, args.height = w, h
    if args.relay_rate < 0 or args.relay_queue <= 0:
        p.error("--relay-rate must be >= 0 and --relay-queue > 0")
    args.relay = not args.netns and args.relay_rate > 0
    if args.background == "off":
        args.background = None
    elif args.background is not None:
        try:
            args.background = parse_background(args.background)
        except ValueError as exc:
            p.error(f"--background: {exc}")
        if not (args.netns or args.relay):
            p.error("--background needs --netns or the relay (the traffic must share the "
                    "shaped link)")
    elif args.relay:  # thesis fig 7.4: a step of cross traffic at mid-mission
        args.background = Background(RELAY_BACKGROUND_SHARE * args.relay_rate,
                                     args.duration / 2 if args.duration else 60.0)
    if args.spec is None:  # --peers alone must share something: a spec with a peers type
        args.spec = "peer_sharing" if args.peers else "image_streaming"
    _check_spec(p, args.spec)
    if args.summary_json is not None:
        _check_summary_json(p, args.summary_json)
    if not 0 <= args.http_port <= 65535:
        p.error(f"--http-port must be in 0..65535, got {args.http_port}")
    if args.http_port and not args.netns and _tcp_port_taken(args.http_port):
        p.error(f"--http-port {args.http_port} is already in use on 127.0.0.1 (another "
                "program listens there): stop it, or pick another (0: a free one)")
    if args.constraint is None:
        shaped = args.netns or args.relay
        args.constraint = "adaptive" if shaped and args.goodput is None else "constant"
    if args.goodput is None:
        args.goodput = 40_000.0
    return args


def _tcp_port_taken(port: int) -> bool:
    """Whether the dashboard's 127.0.0.1:port is held. Checked before the launcher prints the
    run's login link: it printed one for a port another program held, then the station
    failed on it. SO_REUSEADDR as aiohttp binds, so a closing socket is not taken for one."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def _check_summary_json(p: argparse.ArgumentParser, path: Path) -> None:
    """--summary-json must be writable before the fleet starts: a parent that is a file
    failed with "[Errno 17] File exists" after the whole mission, and hid its summary."""
    flag = f"--summary-json {path}"
    if path.is_dir():
        p.error(f"{flag}: is a folder; give a file name")
    if path.exists():
        if not os.access(path, os.W_OK):
            p.error(f"{flag}: not writable")
        return
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        p.error(f"{flag}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        p.error(f"{flag}: cannot create files in {parent} (not writable)")


def _check_spec(p: argparse.ArgumentParser, spec: str) -> None:
    """A wrong --spec fails here, before the fleet starts and prints a dashboard link (the
    ground station used to find it, after the launcher had announced the run)."""
    from utility_specs import UtilitySpecsError
    from utility_specs.files import load_spec

    try:
        load_spec(mission_spec_path(spec))
    except UtilitySpecsError as exc:
        p.error(f"--spec {spec}: {exc}")


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if args.netns:
        from sitl.linkemu import missing_requirements

        reason = missing_requirements()
        if reason is not None:
            print(f"uav-sitl fleet: --netns: {reason}", file=sys.stderr)
            return 2
    try:
        return run(args)
    except FleetError as exc:
        print(f"uav-sitl fleet: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:  # scene errors, unwritable run folder...
        print(f"uav-sitl fleet: {exc}", file=sys.stderr)
        return 2
