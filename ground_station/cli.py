"""``uav-ground-station``: run the station, drive missions from a terminal, export, token."""

from __future__ import annotations

import argparse
import asyncio
import errno
import logging
import math
import os
import shlex
import signal
import socket
import sys
from pathlib import Path

from companion.cli_help import DefaultsFormatter, DefaultsRawFormatter
from companion.secret_files import make_private_dir
from ground_station.config import ConfigError, GroundConfig, load_config, missing_keys
from ground_station.mission_input import HELP
from ground_station.token import ensure_token
from utility_specs.errors import UtilitySpecsError

__all__ = ["main"]

DEFAULT_CONFIG = Path("/etc/uav-ground-station/config.toml")


def _config(args: argparse.Namespace) -> GroundConfig:
    path: Path | None = args.config
    if path is None and DEFAULT_CONFIG.is_file():
        path = DEFAULT_CONFIG
    config = load_config(path) if path is not None else GroundConfig()
    overrides = {
        key: getattr(args, key)
        for key in ("data_dir", "mission", "udp_port", "http_host", "http_port")
        if getattr(args, key, None) is not None
    }
    if getattr(args, "public_read", False):
        overrides["public_read"] = True
    if getattr(args, "allowed_host", None):  # added to the config file's names
        overrides["allowed_hosts"] = (*config.allowed_hosts, *args.allowed_host)
    try:
        return config.with_overrides(**overrides) if overrides else config
    except ConfigError as exc:  # a bad value from the command line is named as its option
        if exc.key not in overrides or exc.key not in _OPTIONS:
            raise  # said "<config>: key 'udp_port'" for --udp-port 99999
        raise ConfigError(_OPTIONS[exc.key], "<option>", exc.expected, exc.got) from None


_OPTIONS = {"data_dir": "--data-dir", "mission": "--mission", "udp_port": "--udp-port",
            "http_host": "--http-host", "http_port": "--http-port",
            "allowed_hosts": "--allowed-host"}
"""The config keys `run`, `token` and `shell` take from options, as the options are typed."""


def data_dir_problem(data_dir: Path) -> str | None:
    """Why the station cannot keep its data in ``data_dir`` (None: it can), checked before
    anything is created, so a bad folder is one line and exit 2, not a traceback later."""
    if data_dir.exists() and not data_dir.is_dir():
        return f"data dir {data_dir}: is a file, not a folder (--data-dir or data_dir)"
    try:
        make_private_dir(data_dir)
        probe = data_dir / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        return f"data dir {data_dir}: not writable ({exc.strerror or exc})"
    return None


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", type=Path, help=f"TOML file (default {DEFAULT_CONFIG} if it exists; "
                                    "examples/ground_station.toml is the commented template)"
    )
    parser.add_argument("--data-dir", type=Path,
                        help="database, images, logs, token and keys/ (default: the config's "
                             "data_dir, else gs-data in the current folder)")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uav-ground-station", formatter_class=DefaultsRawFormatter,
        description="Receive, store and show a UAV fleet's prioritised images; manage missions.",
        epilog="First time:\n"
               "  uav-ground-station keygen     # the fleet's keys, in gs-data/keys\n"
               "  uav-ground-station run        # prints the dashboard's one-time login link\n"
               "Each command's options: uav-ground-station COMMAND --help. "
               "Documentation: docs/ground_station.md.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser(
        "run", help="run the ground station (UDP receiver + web dashboard)",
        formatter_class=DefaultsRawFormatter,
        description="Receive the fleet on UDP, store its images and serve the dashboard until\n"
                    "Ctrl-C or SIGTERM. Options override the config file's keys. Exit status:\n"
                    "0 stopped, 1 a port could not be opened, 2 bad configuration, no keys or\n"
                    "an unusable data folder.",
        epilog="example:\n  uav-ground-station run --config gs.toml --mission survey-1")
    _common(run)
    run.add_argument("--mission", help="mission name images and logs are grouped under "
                                       "(default: the config's mission, default)")
    run.add_argument("--udp-port", type=int,
                     help="UDP port the fleet sends to (default: the config's udp_port, 14600)")
    run.add_argument("--http-host", help="dashboard address (default 127.0.0.1)")
    run.add_argument("--http-port", type=int, help="dashboard port (default 8080)")
    run.add_argument("--public-read", action="store_true", help="dashboard readable without token")
    run.add_argument("--allowed-host", action="append", metavar="NAME",
                     help="a DNS name the dashboard is reached by (repeatable); requests for "
                          "other names are refused (DNS rebinding). IP addresses and "
                          "localhost always work")
    run.add_argument("-v", "--verbose", action="store_true", help="log DEBUG records too")
    shell = sub.add_parser(
        "shell", help="interactive mission manager (thesis fig. 3.7)",
        formatter_class=DefaultsRawFormatter,
        epilog=HELP + '\n\nScripted: -c "drones 3; start +5; params alpha=10" exits 1 when a '
                      "line failed or a drone did not answer done.")
    _common(shell)
    shell.add_argument("--url", help="ground station base URL (default from the config)")
    shell.add_argument("--token", help="control token (default: read from data_dir/token)")
    shell.add_argument("-c", "--commands", help="run these ';'-separated commands and exit")
    shell.add_argument("--timeout", type=float, default=30.0,
                       help="seconds any wait may take before it names who did not answer")
    export = sub.add_parser("export", help="images and a geotag CSV for photogrammetry",
                            formatter_class=DefaultsRawFormatter,
                            epilog="example:\n  uav-ground-station export survey-1 --out "
                                   "./survey-1")
    _common(export)
    export.add_argument("mission", help="mission name")
    export.add_argument("--out", type=Path, required=True, help="output folder")
    export.add_argument("--include-stale-poses", action="store_true",
                        help="also list images with a stale or no position in geotags.csv "
                             "(column 'pose' says which)")
    token = sub.add_parser("token", help="print the control token (created if missing)",
                           formatter_class=DefaultsFormatter)
    _common(token)
    token.add_argument("--url", action="store_true",
                       help="print a one-time dashboard login URL instead (valid 10 min)")
    token.add_argument("--http-host", help="with --url: the dashboard's address, when `run` "
                                           "got one on its command line")
    token.add_argument("--http-port", type=int,
                       help="with --url: the dashboard's port, when `run` got one on its "
                            "command line")
    keygen = sub.add_parser(
        "keygen", help="make the fleet key and the command key pair (default DATA_DIR/keys)",
        formatter_class=DefaultsFormatter,
        description="Make the fleet key (fleet.key), the station's command signing key\n"
                    "(command.key) and its public half (command.pub). Each drone gets fleet.key "
                    "and command.pub, never command.key.",
    )
    _common(keygen)
    keygen.add_argument("--out", type=Path, help="folder for fleet.key, command.key, command.pub "
                                                 "(default DATA_DIR/keys)")
    keygen.add_argument("--force", action="store_true", help="replace existing keys")
    return parser


def _keygen(args: argparse.Namespace, config: GroundConfig) -> int:
    from ground_station.keyfiles import generate_keys

    folder: Path = args.out or config.data_dir / "keys"
    try:
        files = generate_keys(folder, replace=args.force)
    except OSError as exc:
        print(f"uav-ground-station: keygen: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {files.fleet_key} (0600), {files.command_key} (0600), {files.command_pub}")
    print("ground station: keep all three (found in DATA_DIR/keys, or set fleet_key_file and "
          "command_key_file)")
    print(f"each drone: copy {files.fleet_key.name} and {files.command_pub.name} (never "
          f"{files.command_key.name}); in its companion.toml [ground_station]: "
          'fleet_key_file = "fleet.key" and command_public_key_file = "command.pub"')
    return 0


def _warn_every_interface(config: GroundConfig) -> None:
    for what, host in (("udp_host", config.udp_host), ("http_host", config.http_host)):
        if host in ("0.0.0.0", "::", ""):
            logging.getLogger("ground_station").warning(
                "%s is %r: listening on every network interface", what, host
            )
    listen_host = (config.mavlink_listen or "").rpartition(":")[0].strip("[]")
    if (config.mavlink_listen is not None and listen_host in ("0.0.0.0", "::", "")
            and config.mavlink_signing_key is None):
        logging.getLogger("ground_station").warning(
            "mavlink_listen is %r: every host that reaches this port and sends a HEARTBEAT "
            "gets the fleet's positions (unsigned MAVLink); bind it to an address only the "
            "GCS reaches, or set mavlink_signing_key_file", config.mavlink_listen)


def _login_url(config: GroundConfig, token: str, port: int | None = None) -> str:
    import time

    from ground_station.token import login_code

    host = "127.0.0.1" if config.http_host in ("0.0.0.0", "::", "") else config.http_host
    code = login_code(token, now=time.time())
    return f"http://{host}:{config.http_port if port is None else port}/?login={code}"


def _token_url_command(args: argparse.Namespace, config: GroundConfig, port: int) -> str:
    """The ``token --url`` line that makes a login link for this very station: its config,
    data dir and any address given on `run`'s command line (a hint without ``--http-port``
    sent a station started with ``--http-port 18091`` to 8080)."""
    words = ["uav-ground-station", "token", "--url"]
    if args.config is not None:
        words += ["--config", str(args.config)]
    words += ["--data-dir", str(config.data_dir)]
    if args.http_host is not None:
        words += ["--http-host", args.http_host]
    if args.http_port is not None or port != config.http_port:
        words += ["--http-port", str(port)]
    return shlex.join(words)


def _run(args: argparse.Namespace, config: GroundConfig) -> int:
    from companion.stop_signals import EarlyStop
    from ground_station.app import create_app
    from ground_station.http_guard import raise_open_file_limit, serve
    from ground_station.utility import image_utility_from_spec

    stop_signals = EarlyStop()  # a stop signal right after "dashboard:" is not lost
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    keyed = missing_keys(config)
    if isinstance(keyed, str):
        print(f"uav-ground-station: {keyed}", file=sys.stderr)
        return 2
    config = keyed
    _warn_every_interface(config)
    try:  # a broken spec stops us before a new token is made (it is shown only once)
        image_utility_from_spec(config.spec, alpha=config.alpha)
    except UtilitySpecsError as exc:
        print(f"uav-ground-station: mission spec {config.spec}: {exc}", file=sys.stderr)
        return 2
    if config.scene is not None:
        from ground_station.scene_map import SceneMapError, load_scene_map

        try:
            load_scene_map(config.scene)
        except SceneMapError as exc:
            print(f"uav-ground-station: scene: {exc}", file=sys.stderr)
            return 2
    problem = data_dir_problem(config.data_dir)
    if problem is not None:
        print(f"uav-ground-station: {problem}", file=sys.stderr)
        return 2
    token, created = ensure_token(config.token_path)
    limits = raise_open_file_limit()
    if limits is not None:
        logging.getLogger("ground_station").info("open-file limit %d (hard %d)", *limits)
    app = create_app(config, token=token)
    if created:
        print(f"control token (shown once, stored 0600 in {config.token_path}): {token}")
    sys.stdout.flush()

    def announce(port: int) -> None:  # once listening: a login code never goes to a port
        # another program holds, and --http-port 0 shows the port it got
        print(f"dashboard: {_login_url(config, token, port)} (one-time login link, valid "
              f"10 min; another: {_token_url_command(args, config, port)})", flush=True)

    try:
        serve(app, host=config.http_host, port=config.http_port,
              max_connections=config.http_max_connections,
              max_per_client=config.http_max_per_client,
              idle_timeout_s=config.http_idle_timeout_s, stop_signals=stop_signals,
              on_serving=announce)
    except OSError as exc:  # address in use, permission denied...
        print(f"uav-ground-station: {_serve_problem(exc, config)}", file=sys.stderr)
        return 1
    return 0


def _serve_problem(exc: OSError, config: GroundConfig) -> str:
    """One line for a port the station cannot open; a port in use names it and the option
    that moves it (aiohttp's own words named neither the dashboard nor the flag); so does a
    host name that does not resolve (``[Errno -2] Name or service not known`` named neither)."""
    udp = (exc.strerror or "").startswith("UDP ")  # the transport names its address
    if (exc.strerror or "").startswith("shared_medium "):  # says the setting and the fix
        return exc.strerror or ""
    if isinstance(exc, socket.gaierror) or (exc.errno is not None and exc.errno < 0):
        why = (exc.strerror or str(exc)).rpartition(": ")[2] if udp else exc.strerror or exc
        if udp:
            return (f"udp_host {config.udp_host!r} does not resolve ({why}): give this "
                    "computer's address on the fleet's link")
        return (f"http_host (--http-host) {config.http_host!r} does not resolve ({why}): give "
                "an address or a name of this computer")
    if exc.errno != errno.EADDRINUSE:
        return f"cannot serve: {exc}"
    if udp:
        return (f"UDP {config.udp_host}:{config.udp_port} is already in use (another ground "
                "station?): stop it, or pick another --udp-port")
    return (f"dashboard {config.http_host}:{config.http_port} is already in use (another "
            "program listens there): stop it, or pick another --http-port")


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        print("uav-ground-station: choose a command (start with: uav-ground-station run)",
              file=sys.stderr)
        return 2
    try:
        config = _config(args)
    except ConfigError as exc:
        what = "error" if exc.key == "<option>" else "configuration error"
        print(f"uav-ground-station: {what}: {exc}", file=sys.stderr)
        return 2
    if args.command == "run":
        return _run(args, config)
    if args.command == "keygen":
        return _keygen(args, config)
    if args.command == "token":
        if args.url and config.http_port == 0:  # "any free port" for run: no URL to give
            print("uav-ground-station: token --url needs the dashboard's real port: give the "
                  "--http-port that `run` printed in its dashboard line", file=sys.stderr)
            return 2
        problem = data_dir_problem(config.data_dir)
        if problem is not None:
            print(f"uav-ground-station: {problem}", file=sys.stderr)
            return 2
        token, created = ensure_token(config.token_path)
        print(_login_url(config, token) if args.url else token)
        if created:
            unused = not (config.data_dir / "ground_station.sqlite3").exists()
            print(f"(new token stored 0600 in {config.token_path}"
                  + ("; no station has run on this data folder yet: a running station's "
                     "token is in its own --data-dir" if unused else "") + ")", file=sys.stderr)
        return 0
    if args.command == "export":
        from ground_station.export import ExportError, export_mission

        try:
            result = export_mission(config.data_dir, args.mission, args.out,
                                    include_stale=args.include_stale_poses)
        except (KeyError, ExportError) as exc:
            print(f"uav-ground-station: {exc.args[0]}", file=sys.stderr)
            return 1
        except OSError as exc:  # an unwritable --out, a full disk...
            print(f"uav-ground-station: export to {args.out} failed: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:  # a line, not a traceback; not 0: the export is partial
            print(f"uav-ground-station: export interrupted; {args.out} is incomplete",
                  file=sys.stderr)
            return 130
        print(f"exported {result.images} images to {args.out} (geotags: {result.csv_path})")
        if result.missing:
            print(f"warning: {result.missing} indexed images had no file", file=sys.stderr)
        if result.untagged:
            print(f"{result.untagged} images with a stale or no position left out of "
                  f"{result.csv_path.name} (--include-stale-poses lists them)", file=sys.stderr)
        return 0
    # shell
    from ground_station.shell import run_shell
    from ground_station.token import read_token

    host = "127.0.0.1" if config.http_host in ("0.0.0.0", "::") else config.http_host
    url = args.url or f"http://{host}:{config.http_port}"
    try:
        token = args.token or read_token(config.token_path)
    except OSError as exc:  # the station's folder: its --data-dir or --config, or the token
        why = "no such file" if isinstance(exc, FileNotFoundError) else exc.strerror or exc
        print(f"uav-ground-station: no control token in {config.token_path} ({why}): give the "
              "station's --data-dir or --config (as `run` got them), or --token",
              file=sys.stderr)
        return 2
    lines = [c for c in args.commands.split(";")] if args.commands else None
    if not (math.isfinite(args.timeout) and args.timeout > 0):  # inf: a wait never ends
        print("uav-ground-station: --timeout must be a number of seconds > 0",
              file=sys.stderr)
        return 2
    if not (token.isascii() and token.isprintable() and " " not in token):  # a header value
        print("uav-ground-station: the token must be printable ASCII without spaces "
              "(as `uav-ground-station token` prints it)", file=sys.stderr)
        return 2
    if not url.startswith(("http://", "https://")):
        print(f"uav-ground-station: --url must start with http:// or https://, got {url!r}",
              file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # ends it like Ctrl-C
    try:
        return asyncio.run(run_shell(url, token, lines=lines, wait_timeout_s=args.timeout))
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: a line, not a traceback
        print("uav-ground-station shell: interrupted", file=sys.stderr)
        return 0 if lines is None else 130  # a script must not carry on as if it had run


if __name__ == "__main__":
    raise SystemExit(main())
