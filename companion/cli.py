"""``uav-companion``: run the companion, check a setup, install the systemd service.

    uav-companion run [--config PATH]
    uav-companion check [--config PATH] [--timeout S] [--skip-mavlink] [--skip-camera]
    uav-companion install-service [--config PATH] [--unit-dir DIR] [--dry-run] [--no-enable]

Exit status: 0 success, 1 a probe or the service failed, 2 a bad configuration.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from companion.cli_help import DefaultsFormatter, DefaultsRawFormatter
from companion.mavlink_hint import sharing_hint, silence_hint

__all__ = ["main"]

DEFAULT_CONFIG = "/etc/uav-companion/config.toml"
CONFIG_HELP = (f"TOML file (default {DEFAULT_CONFIG}; examples/companion.toml is the "
               "commented template)")
_STD_ATTRS = frozenset(vars(logging.LogRecord("", 0, "", 0, "", (), None))) | {"message"}


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, logger, message and any ``extra`` fields."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "t": record.created,
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key, value in vars(record).items():
            if key not in _STD_ATTRS and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str)


def configure_logging(level: str, fmt: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uav-companion", formatter_class=DefaultsRawFormatter,
        description="The drone's companion app: run it, check a setup, install the systemd unit.",
        epilog="First time: copy examples/companion.toml, set drone.id, mavlink.url, camera.source,"
               "\nground_station.host and the two key files (README.md), then\n"
               "  uav-companion check --config companion.toml\n"
               "Each command's options: uav-companion COMMAND --help. "
               "Documentation: docs/companion.md.",
    )
    parser.add_argument("--log-level", default="info",
                        choices=["debug", "info", "warning", "error"],
                        help="least severe log record written to stderr")
    parser.add_argument("--log-format", default=None, choices=["json", "text"],
                        help="default: json for run (journald keeps it), text for the "
                             "commands a person reads (check, install-service)")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run", help="run the companion until SIGTERM or Ctrl-C", formatter_class=DefaultsFormatter,
        description="Read the autopilot, score camera frames and stream what the optimiser "
                    "chooses to the ground station, until SIGTERM or Ctrl-C. Logs go to stderr, "
                    "one JSON object per line. Exit status: 0 stopped, 1 a service failed (systemd "
                    "restarts it), 2 bad configuration.")
    run.add_argument("--config", default=DEFAULT_CONFIG, help=CONFIG_HELP)

    check = sub.add_parser(
        "check", help="validate the config, probe MAVLink and the camera",
        formatter_class=DefaultsRawFormatter,
        description="Validate the configuration, wait for an autopilot HEARTBEAT and grab one\n"
                    "camera frame; print what was found. Exit status: 0 all answered,\n"
                    "1 a probe failed (no HEARTBEAT, no frame), 2 bad configuration.",
        epilog="example:\n  uav-companion check --config companion.toml --timeout 10")
    check.add_argument("--config", default=DEFAULT_CONFIG, help=CONFIG_HELP)
    check.add_argument("--timeout", type=_seconds, default=5.0,
                       help="seconds to wait for the autopilot (default 5)")
    check.add_argument("--skip-mavlink", action="store_true",
                       help="do not wait for the autopilot (config and camera only)")
    check.add_argument("--skip-camera", action="store_true",
                       help="do not grab a camera frame")

    inst = sub.add_parser(
        "install-service", help="write and enable the systemd unit",
        formatter_class=DefaultsRawFormatter,
        description="Write a systemd unit that runs `uav-companion run` with this config and\n"
                    "restarts it on failure, then enable and start it (needs root). Exit\n"
                    "status: 0 done, 1 systemctl or the file failed, 2 bad configuration.",
        epilog="example (sudo drops the venv from PATH):\n"
               "  sudo .venv/bin/uav-companion install-service --dry-run")
    inst.add_argument("--config", default=DEFAULT_CONFIG, help=CONFIG_HELP)
    inst.add_argument("--unit-dir", default=None,
                      help="where to write the unit (default /etc/systemd/system)")
    inst.add_argument("--dry-run", action="store_true", help="print the unit, change nothing")
    inst.add_argument("--no-enable", action="store_true",
                      help="write the unit but do not run systemctl")
    inst.add_argument("--user", type=_user_name, default=None,
                      help="run the service as this user (default: systemd's, root)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    # pymavlink picks its wire version from the environment at import: set it before.
    os.environ.setdefault("MAVLINK20", "1")
    args = _parser().parse_args(list(argv) if argv is not None else None)
    # A JSON object between check's lines read as noise to a person at a terminal.
    configure_logging(args.log_level,
                      args.log_format or ("json" if args.command == "run" else "text"))
    if args.command == "run":
        return _run(args)
    if args.command == "check":
        try:
            return _check(args)
        except KeyboardInterrupt:  # a line, not a traceback; not 0: nothing was checked
            print("uav-companion check: interrupted", file=sys.stderr)
            return 130
    return _install(args)


def freeze_startup_heap() -> None:
    """What is alive once the optimiser is warm (the libraries, the compiled search) lives as
    long as the process: collected once and frozen out of the collector's reach, every later
    full collection scans only the mission's objects. Measured after the shipped
    ``examples/companion.toml``'s warm-up: 192 k objects, a full collection 143 ms (three
    times the 50 ms decision budget, if it lands in a decision), then 0.01 ms. Runs in the
    decider's thread, where the warm-up already held the interpreter."""
    import gc

    gc.collect()
    gc.freeze()


def _load(path: str) -> Any:
    from companion.config import ConfigError, load_config

    try:
        return load_config(path)
    except ConfigError as exc:
        print(f"configuration error: {exc}", file=sys.stderr)
        return None


def _run(args: argparse.Namespace) -> int:
    import asyncio

    from companion.app import AppSetupError, create_app
    from companion.stop_signals import EarlyStop

    stop_signals = EarlyStop()
    config = _load(args.config)
    if config is None:
        return 2

    async def main_async() -> int:
        try:
            app = create_app(config, clock=time.time)
        except AppSetupError as exc:
            print(f"cannot start: {exc}", file=sys.stderr)
            return 2
        app.dispatcher.after_warm_up = freeze_startup_heap
        stop_signals.attach(asyncio.get_running_loop(), app.stop)
        await app.run()
        return 0

    try:
        return asyncio.run(main_async())
    except ExceptionGroup as group:  # a service failed; systemd restarts us (on-failure)
        from companion.transport import TransportStartError

        opened, _ = group.split(TransportStartError)
        if opened is not None:  # a port in use, an interface not up yet: a line, no traceback
            problem = str(opened.exceptions[0])
            logging.getLogger("companion").error("cannot start: %s", problem)
            print(f"cannot start: {problem}", file=sys.stderr)
            return 1
        logging.getLogger("companion").error("companion failed", exc_info=group)
        print(f"companion failed: {group.exceptions[0]!r}", file=sys.stderr)
        return 1


def _check(args: argparse.Namespace) -> int:
    from companion.app import AppSetupError, check_setup
    from companion.remote_lookup import lookup_problem

    config = _load(args.config)
    if config is None:
        return 2
    try:  # all of it before "ok": "ok" then "configuration error: no key" read as a contradiction
        setup = check_setup(config)
    except AppSetupError as exc:
        print(f"configuration error: {exc}", file=sys.stderr)
        return 2
    print(f"config: {args.config}: ok (drone {config.drone_id})")
    for line in setup:
        print(line)
    failures = 0
    unresolved = lookup_problem(config.ground_station.host, config.ground_station.port,
                                "ground_station.host")
    if unresolved is not None:  # `run` would send nothing until it resolves
        print(f"ground station: {unresolved}")
        failures += 1
    if config.peers.medium is not None:  # `run` would stop at once: say so before the flight
        line, ok = _probe_medium(config.peers.medium)
        print(line)
        failures += not ok
    snapshot = None
    if not args.skip_mavlink:
        snapshot, lines, ok = _probe_mavlink(config, args.timeout)
        failures += not ok
        for line in lines:
            print(line)
    if config.camera.enabled and not args.skip_camera:
        lines, ok = _probe_camera(config, snapshot)
        failures += not ok
        for line in lines:
            print(line)
    print("check: ok" if failures == 0 else f"check: {failures} problem(s)")
    return 0 if failures == 0 else 1


def _probe_medium(text: str) -> tuple[str, bool]:
    """Open the shared medium's sockets as ``run`` does and close them again."""
    import socket

    from companion.medium import (
        medium_problem,
        open_medium_socket,
        parse_medium,
        prepare_medium_sender,
    )

    medium = parse_medium(text)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        try:
            prepare_medium_sender(sender, medium)
            open_medium_socket(medium).close()
        except OSError as exc:
            return f"peers: {medium_problem(exc, medium, 'peers.medium')}", False
    return f"peers: shared medium {medium} opened", True


def _probe_mavlink(config: Any, timeout_s: float) -> tuple[Any, list[str], bool]:
    import threading

    from companion.clock_check import clock_problem
    from companion.mavlink import MavlinkReader
    from companion.telemetry import SystemTimeSample, TelemetryState

    state = TelemetryState()
    lock = threading.Lock()

    times: list[SystemTimeSample] = []

    def post(sample: Any) -> None:
        with lock:
            state.apply(sample)
            if isinstance(sample, SystemTimeSample):
                times.append(sample)

    reader = MavlinkReader(config.mavlink, clock=time.time, post=post)
    reader.start()
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            with lock:
                snap = state.snapshot()
            if snap.connected and snap.lat_deg is not None and snap.battery_v is not None \
                    and snap.gps_fix_type is not None:
                break
            time.sleep(0.1)
    finally:
        reader.stop()
        reader.join(5.0)
    with lock:
        snap = state.snapshot()
    url = config.mavlink.url
    if not snap.connected and snap.t_heartbeat is None:
        if reader.last_error is not None:
            return snap, [f"mavlink: {url}: cannot open: {reader.last_error}"], False
        hint = silence_hint(url, unparsable=reader.counters["bad_messages"],
                            baud=config.mavlink.baud)
        return snap, [f"mavlink: {url}: no autopilot HEARTBEAT within {timeout_s:g} s "
                      f"({hint})"], False
    lines = [f"mavlink: {url}: {snap.autopilot} autopilot, vehicle type {snap.vehicle_type}, "
             f"mode {snap.mode}, {'armed' if snap.armed else 'disarmed'}"]
    shared = sharing_hint(url)
    if shared is not None:  # it answered this time; `run` would keep losing it
        lines.append(f"mavlink: warning: {shared}")
    if snap.lat_deg is not None and snap.position_problem is None:
        lines.append(f"mavlink: position {snap.lat_deg:.7f} {snap.lon_deg:.7f} "
                     f"alt_rel {snap.alt_rel_m:.1f} m")
    elif snap.lat_deg is not None:  # a warning, not a failure: the fix may come later
        lines.append(f"mavlink: no valid position yet: {snap.position_problem} "
                     "(no geotags until there is one)")
    else:
        lines.append("mavlink: no GLOBAL_POSITION_INT yet (streams requested)")
    if snap.battery_v is not None:
        remaining = ("?" if snap.battery_remaining is None
                     else f"{100 * snap.battery_remaining:.0f} %")
        lines.append(f"mavlink: battery {snap.battery_v:.2f} V, {remaining}")
    if times and (problem := clock_problem(times[-1].t, times[-1].unix_time_s)) is not None:
        return snap, [*lines, f"clock: {problem}"], False
    return snap, lines, True


def _probe_camera(config: Any, snapshot: Any) -> tuple[list[str], bool]:
    from companion.camera import CameraError, open_source
    from companion.telemetry import TelemetrySnapshot

    cam = config.camera
    pose = snapshot if snapshot is not None and snapshot.lat_deg is not None else \
        TelemetrySnapshot(lat_deg=0.0, lon_deg=0.0, alt_rel_m=30.0, roll_rad=0.0,
                          pitch_rad=0.0, yaw_rad=0.0)
    try:
        source = open_source(cam.source, width=cam.width, height=cam.height,
                             rate_hz=cam.rate_hz, pose=lambda: pose, options=dict(cam.options))
        try:
            image = source.read(timeout_s=3.0)
        finally:
            source.close()
    except (CameraError, OSError, ValueError, TypeError) as exc:
        return [f"camera: {cam.source}: {exc}"], False
    if image is None:
        return [f"camera: {cam.source}: opened but no frame"], False
    return [f"camera: {source.description}: frame {image.shape[1]}x{image.shape[0]}, "
            f"sent as {cam.width}x{cam.height} at {cam.rate_hz:g} Hz"], True


def _seconds(text: str) -> float:
    """A finite number of seconds > 0 (``inf`` waited forever, ``nan`` not at all)."""
    import math

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, got {text!r}")
    return value


def _user_name(text: str) -> str:
    """A POSIX user name: anything else (a space, a newline and a second ``ExecStart=``)
    went into the unit as written, and systemd refused the unit or ran what it said."""
    import re

    if not re.fullmatch(r"[a-z_][a-z0-9_-]{0,31}", text):
        raise argparse.ArgumentTypeError(f"expected a user name like pi, got {text!r}")
    return text


def _install(args: argparse.Namespace) -> int:
    from companion.service import DEFAULT_UNIT_DIR, install_service

    config = _load(args.config)
    if config is None:  # a unit that starts a broken config only restarts forever
        return 2
    from companion.config import missing_keys

    if (problem := missing_keys(config)) is not None:  # run would refuse it: exit 2, restart
        print(f"configuration error: {problem}", file=sys.stderr)
        return 2
    config_path = Path(args.config).resolve()
    unit_dir = Path(args.unit_dir) if args.unit_dir else DEFAULT_UNIT_DIR
    log = None if config.mission.log is None else Path(config.mission.log)
    if args.user and not args.dry_run:
        import pwd

        from companion.service import make_folder_for, unreadable_for

        try:
            pwd.getpwnam(args.user)
        except KeyError:
            print(f"install-service failed: no user {args.user!r} on this machine "
                  "(create it, or drop --user)", file=sys.stderr)
            return 1
        files = [config_path, *map(Path, config.ground_station.key_files)]
        if (problem := unreadable_for(args.user, files)) is not None:
            print(f"install-service failed: {problem}: the service could not start "
                  f"(chown {args.user} the file, or drop --user)", file=sys.stderr)
            return 1
        if log is not None:
            try:
                make_folder_for(args.user, log.parent)
            except OSError as exc:
                print(f"install-service failed: mission.log: {log.parent}: {exc.strerror}",
                      file=sys.stderr)
                return 1
    try:
        result = install_service(config_path=config_path, unit_dir=unit_dir,
                                 dry_run=args.dry_run, enable=not args.no_enable,
                                 user=args.user,
                                 writable=() if log is None else (log.parent,))
    except (OSError, RuntimeError) as exc:
        print(f"install-service failed: {exc}", file=sys.stderr)
        return 1
    if args.dry_run:
        print(f"# would write {result.unit_path}")
        print(result.text)
        for command in result.commands:
            print("# would run: " + " ".join(command))
    else:
        print(f"wrote {result.unit_path}")
        for command in result.commands:
            print("ran: " + " ".join(command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
