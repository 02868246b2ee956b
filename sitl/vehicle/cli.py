"""``uav-sitl vehicle``: run N simulated MAVLink vehicles on UDP until stopped.

Prints one ``READY {json}`` line per vehicle once its socket is bound (with the real port,
so ``--port 0`` works for tests and launchers), then serves until SIGINT/SIGTERM or
``--duration``. ``--serial`` puts one vehicle on a pseudo-terminal instead (a serial line:
``READY`` then names the ``/dev/pts/N`` a client opens, or ``--serial-link``'s symlink).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import errno
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from companion.cli_help import DefaultsRawFormatter
from companion.stop_signals import EarlyStop
from sitl.argv import attach_negative_values
from sitl.geo import Enu, GeoPoint, geo_from_enu

if TYPE_CHECKING:  # pymavlink is imported only after MAVLINK20 is set in main()
    from sitl.vehicle.core import VehicleConfig
    from sitl.vehicle.mission import MissionItem

__all__ = ["build_configs", "main", "parse_args"]


def _home(text: str) -> GeoPoint:
    try:
        parts = [float(x) for x in text.split(",")]
        if len(parts) not in (2, 3):
            raise ValueError
        return GeoPoint(lat_deg=parts[0], lon_deg=parts[1],
                        alt_m=parts[2] if len(parts) == 3 else 0.0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON[,ALT], got {text!r}") from None


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}") from None
    if not 1 <= number <= 65535:  # was accepted: every send then raised a traceback
        raise argparse.ArgumentTypeError(f"port must be in 1..65535, got {text!r}")
    return host or "127.0.0.1", number


def _param(text: str) -> tuple[str, float]:
    name, _, value = text.partition("=")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}") from None


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="uav-sitl vehicle", formatter_class=DefaultsRawFormatter,
        description="Simulated multicopters speaking MAVLink 2 on UDP (PX4- or ArduPilot-like).\n"
                    "Clients send to HOST:PORT; the vehicle answers the address it heard from\n"
                    "(and --out). Prints one READY {json} line per vehicle once bound, then\n"
                    "runs until Ctrl-C, SIGTERM or --duration.",
        epilog="examples:\n"
               "  uav-sitl vehicle --port 14580 --out 127.0.0.1:14550   # a companion's udpin\n"
               "  uav-sitl vehicle --count 4 --flavour ardupilot --pattern survey --autostart")
    p.add_argument("--port", type=int, default=14550,
                   help="UDP port of the first vehicle; vehicle i uses PORT+i (0: any free)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--count", type=int, default=1, help="number of vehicles (default 1)")
    p.add_argument("--sysid", type=int, default=1, help="system id of the first vehicle")
    p.add_argument("--flavour", choices=("px4", "ardupilot"), default="px4",
                   help="which autopilot's MAVLink dialect and habits it copies")
    p.add_argument("--speedup", type=float, default=1.0,
                   help="simulated seconds per wall second (default 1)")
    p.add_argument("--home", type=_home, default=None,
                   help="LAT,LON[,ALT] of home (default: the scene's home)")
    p.add_argument("--scene", default="demo",
                   help="scene name or TOML path: home, area and targets for patterns")
    p.add_argument("--pattern", nargs="+", metavar=("KIND", "FILE"), default=None,
                   help="preload a mission: survey | orbit | waypoints FILE")
    p.add_argument("--alt", type=float, default=None,
                   help="pattern altitude (m above home; default: the scene's)")
    p.add_argument("--spacing", type=float, default=None,
                   help="survey leg spacing (m; default: ~80 %% of the camera footprint)")
    p.add_argument("--radius", type=float, default=20.0, help="orbit radius (m)")
    p.add_argument("--speed", type=float, default=5.0, help="pattern cruise speed (m/s)")
    p.add_argument("--autostart", action="store_true",
                   help="arm and start the preloaded mission as soon as the vehicle can arm"
                        " (after its first fix)")
    p.add_argument("--first-fix", type=float, default=None, metavar="S",
                   help="simulated seconds from boot to a GPS fix and estimator origin; until"
                        " then positions are 0/0 and arming is refused, as on a real autopilot"
                        " (default 15; 0 for tests that fly at once)")
    p.add_argument("--out", type=_addr, action="append", default=None,
                   help="also send to HOST:PORT (one per vehicle; repeat or give once for"
                        " PORT+i)")
    p.add_argument("--param", type=_param, action="append", default=[],
                   help="NAME=VALUE parameter override (repeatable)")
    p.add_argument("--wind", type=float, nargs=2, metavar=("SPEED", "FROM_DEG"),
                   default=None, help="mean wind speed (m/s) and direction it blows from")
    p.add_argument("--reboot-s", type=float, default=None, metavar="S",
                   help="wall seconds MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN keeps the vehicle silent"
                        " before it boots again (default: ardupilot 2.1, as ArduCopter 4.5 SITL"
                        " measured, shorter than a client's 3 s heartbeat timeout; px4 4)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after S wall seconds (default: run until stopped)")
    p.add_argument("--seed", type=int, default=0, help="seed of the GPS noise")
    p.add_argument("--ready-file", type=Path, default=None,
                   help="write the list of READY records as JSON here once all are bound")
    p.add_argument("--serial", action="store_true",
                   help="serve one vehicle on a serial line (a pseudo-terminal) instead of UDP")
    p.add_argument("--serial-link", type=Path, default=None, metavar="PATH",
                   help="with --serial: also make PATH a symlink to the /dev/pts/N device")
    p.add_argument("--gcs-port", type=int, default=None, metavar="PORT",
                   help="with --serial: also serve a GCS on UDP HOST:PORT (0: any free), a"
                        " second link with its own streams, as a flight controller's radio or"
                        " USB port beside the companion's UART")
    p.add_argument("--baud", type=int, default=115200,
                   help="with --serial: line rate in bit/s; the vehicle sends at most baud/10"
                        " bytes per second like a real UART (default 115200)")
    args = p.parse_args(attach_negative_values(argv, ("--home",)))
    if args.count < 1 or args.count > 250:
        p.error("--count must be in 1..250")
    if args.first_fix is not None and not (0.0 <= args.first_fix < 1e6):
        p.error("--first-fix must be a number of seconds >= 0")
    if not 0 <= args.port <= 65535:
        p.error(f"--port must be in 0..65535, got {args.port}")
    if args.port and args.port + args.count - 1 > 65535:  # vehicle i binds PORT+i: a traceback
        p.error(f"--port must be in 1..{65536 - args.count} for {args.count} vehicle(s) "
                f"(vehicle i uses PORT+i), got {args.port}")
    if args.out and len(args.out) == 1 and args.out[0][1] + args.count - 1 > 65535:
        p.error(f"--out port must be in 1..{65536 - args.count} for {args.count} vehicle(s) "
                f"(vehicle i sends to PORT+i), got {args.out[0][1]}")
    if not 0 < args.speedup < math.inf:  # inf spun the loop, deaf to SIGTERM
        p.error(f"--speedup must be > 0 and finite, got {args.speedup}")
    if args.count + args.sysid - 1 > 255 or args.sysid < 1:
        p.error(f"--sysid must be in 1..{256 - args.count} for {args.count} vehicle(s), "
                f"got {args.sysid}")
    if args.wind is not None and not (math.isfinite(args.wind[0]) and args.wind[0] >= 0
                                      and math.isfinite(args.wind[1])):
        p.error("--wind: expected a speed >= 0 and a direction, both finite")
    for flag, value in (("--speed", args.speed), ("--radius", args.radius),
                        ("--spacing", args.spacing)):
        if value is not None and not 0 < value < math.inf:  # -1 flew nowhere, 0 divided
            p.error(f"{flag} must be a finite number > 0, got {value}")
    if args.alt is not None and not math.isfinite(args.alt):
        p.error(f"--alt must be a finite number of metres, got {args.alt}")
    if args.reboot_s is not None and not 0 <= args.reboot_s < 1e6:
        p.error(f"--reboot-s must be a number of seconds >= 0, got {args.reboot_s}")
    if args.duration is not None and not args.duration >= 0:
        p.error(f"--duration must be a number of seconds >= 0, got {args.duration}")
    if args.serial and args.count != 1:
        p.error("--serial serves one vehicle (--count 1)")
    if args.gcs_port is not None and not (args.serial and 0 <= args.gcs_port <= 65535):
        p.error("--gcs-port needs --serial and a port in 0..65535")
    if args.baud < 50 or args.baud > 12_000_000:
        p.error(f"--baud must be in 50..12000000, got {args.baud}")
    if args.pattern:
        kind = args.pattern[0]
        if kind not in ("survey", "orbit", "waypoints"):
            p.error("--pattern must be survey, orbit or waypoints FILE")
        if kind == "waypoints" and len(args.pattern) != 2:
            p.error("--pattern waypoints needs a FILE")
        if kind != "waypoints" and len(args.pattern) != 1:
            p.error(f"--pattern {kind} takes no file")
    return args


def build_configs(args: argparse.Namespace) -> list[VehicleConfig]:
    """One VehicleConfig per vehicle: homes 4 m apart eastwards, patterns split the area."""
    from sitl.scenes import load_scene
    from sitl.vehicle.core import ARDUPILOT_REBOOT_S, VehicleConfig
    from sitl.vehicle.flavour import FLAVOURS
    from sitl.vehicle.patterns import load_waypoints, orbit, survey

    scene = load_scene(args.scene)
    origin = args.home or scene.home
    flavour = FLAVOURS[args.flavour]
    alt = args.alt or scene.default_alt_m
    params = dict(args.param)
    if args.wind:
        params.setdefault("SIM_WIND_SPD", args.wind[0])
        params.setdefault("SIM_WIND_DIR", args.wind[1])
    ap = flavour.name == "ardupilot"
    configs = []
    for i in range(args.count):
        g = geo_from_enu(Enu(east_m=4.0 * i, north_m=0.0), origin)
        home = GeoPoint(lat_deg=g.lat_deg, lon_deg=g.lon_deg, alt_m=origin.alt_m)
        mission: list[MissionItem] = []
        if args.pattern:
            kind = args.pattern[0]
            if kind == "survey":
                strip = scene.width_m / args.count
                center = (-scene.width_m / 2 + strip * (i + 0.5), 0.0)
                spacing = args.spacing or max(5.0, 0.8 * 2 * alt * 0.7)  # ~80% of footprint
                # Pattern coordinates are scene-local; this vehicle's home is 4 m * i east.
                mission = survey(origin, center_en_m=center, width_m=max(strip - spacing, 1.0),
                                 height_m=scene.height_m * 0.9, spacing_m=spacing, alt_m=alt,
                                 speed_m_s=args.speed, item0_is_home=ap)
            elif kind == "orbit":
                tgt = scene.targets[0] if scene.targets else None
                center = (tgt.east_m, tgt.north_m) if tgt else (0.0, 0.0)
                mission = orbit(origin, center_en_m=center, radius_m=args.radius, alt_m=alt,
                                start_deg=360.0 * i / args.count, speed_m_s=args.speed,
                                item0_is_home=ap)
            else:
                mission = load_waypoints(Path(args.pattern[1]), home=home, default_alt_m=alt,
                                         item0_is_home=ap)
        fix = {} if args.first_fix is None else {"first_fix_s": args.first_fix}
        reboot_s = args.reboot_s if args.reboot_s is not None else \
            ARDUPILOT_REBOOT_S if ap else 4.0
        # GPS time is UTC, as a real autopilot's (SYSTEM_TIME): the host's clock at start,
        # then the simulated time (at --speedup 1, the host's clock). A fixed 2023 epoch made
        # every companion's clock look 3 years off the autopilot's GPS time.
        configs.append(VehicleConfig(system_id=args.sysid + i, flavour=flavour, home=home,
                                     params=params, mission=tuple(mission),
                                     seed=args.seed + i, autostart=args.autostart,
                                     reboot_s=reboot_s, boot_unix_s=time.time(), **fix))
    return configs


async def _serve(args: argparse.Namespace, stop_signals: EarlyStop) -> int:
    from sitl.vehicle.serial_pty import (
        PtySerialLink,
        start_serial_and_udp_vehicle,
        start_serial_vehicle,
    )
    from sitl.vehicle.shell import VehicleEndpoint, start_vehicles

    configs = build_configs(args)
    ports = [0 if args.port == 0 else args.port + i for i in range(args.count)]
    outs = None
    if args.out:
        if len(args.out) == 1:
            host, port = args.out[0]
            outs = [(host, port + i) for i in range(args.count)]
        elif len(args.out) == args.count:
            outs = list(args.out)
        else:
            print("uav-sitl vehicle: give --out once or once per vehicle", file=sys.stderr)
            return 2
    endpoints: list[VehicleEndpoint | PtySerialLink]
    gcs: VehicleEndpoint | None = None
    if args.serial and args.gcs_port is not None:
        serial, gcs = await start_serial_and_udp_vehicle(
            configs[0], baud=args.baud, link=args.serial_link, speedup=args.speedup,
            host=args.host, port=args.gcs_port, out=outs[0] if outs else None)
        endpoints = [serial]
    elif args.serial:
        endpoints = [start_serial_vehicle(configs[0], baud=args.baud, link=args.serial_link,
                                          speedup=args.speedup)]
    else:
        endpoints = list(await start_vehicles(configs, host=args.host, ports=ports,
                                              speedup=args.speedup, outs=outs))
    records = []
    for ep, cfg in zip(endpoints, configs, strict=True):
        where = ({"serial": ep.path, "tty": ep.tty_path, "baud": ep.baud}
                 if isinstance(ep, PtySerialLink) else
                 {"host": ep.address[0], "port": ep.address[1]})
        if gcs is not None:  # the second link (--gcs-port)
            where |= {"host": gcs.address[0], "port": gcs.address[1]}
        rec = {"sysid": cfg.system_id, **where,
               "flavour": cfg.flavour.name, "home": [cfg.home.lat_deg, cfg.home.lon_deg,
                                                     cfg.home.alt_m],
               "mission_items": len(cfg.mission), "speedup": args.speedup}
        records.append(rec)
        print("READY " + json.dumps(rec), flush=True)
    if args.ready_file:
        tmp = args.ready_file.with_suffix(".tmp")
        try:
            tmp.write_text(json.dumps(records))
            os.replace(tmp, args.ready_file)
        except OSError as exc:
            for ep in [*endpoints, *([gcs] if gcs else [])]:
                ep.close()
            print(f"uav-sitl vehicle: cannot write --ready-file {args.ready_file}: "
                  f"{exc.strerror or exc}", file=sys.stderr)
            return 1
    stop = asyncio.Event()
    stop_signals.attach(asyncio.get_running_loop(), stop.set)
    try:
        if args.duration is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.duration)
        else:
            await stop.wait()
    finally:
        for ep in [*endpoints, *([gcs] if gcs else [])]:
            ep.close()
    bad: dict[str, int] = {k: v for ep in endpoints for k, v in ep.core.counters.items()}
    bad.update({f"serial_{k}": v for ep in endpoints if isinstance(ep, PtySerialLink)
                for k, v in ep.counters.items() if k == "tx_dropped_frames" and v})
    if bad:
        print("counters: " + json.dumps(bad, sort_keys=True), file=sys.stderr)
    return 0


def _os_problem(args: argparse.Namespace, exc: OSError) -> str:
    """One line for a socket or serial line the vehicle cannot open; a port in use names the
    ports and the option that moves them ("[Errno 98] Address already in use" named neither)."""
    if args.serial:
        return f"cannot open the serial line: {exc}"
    if exc.errno != errno.EADDRINUSE:
        return f"cannot bind: {exc}"
    last = args.port + args.count - 1
    ports = f"{args.port}" if last == args.port else f"{args.port}..{last}"
    return (f"cannot bind UDP {args.host}:{ports}: address already in use (another vehicle or "
            "program listens there): stop it, or pick another --port")


def main(argv: list[str]) -> int:
    os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere
    args = parse_args(argv)
    stop_signals = EarlyStop()  # a stop signal right after READY is not lost
    from sitl.scenes import SceneError
    from sitl.vehicle.patterns import PatternError

    try:
        return asyncio.run(_serve(args, stop_signals))
    except (SceneError, PatternError) as exc:
        print(f"uav-sitl vehicle: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"uav-sitl vehicle: {_os_problem(args, exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
