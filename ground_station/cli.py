"""``uav-ground-station``: run the station, drive missions from a terminal, export, token."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path

from ground_station.config import ConfigError, GroundConfig, load_config
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
    return config.with_overrides(**overrides) if overrides else config


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", type=Path, help=f"TOML file (default {DEFAULT_CONFIG} if it exists)"
    )
    parser.add_argument("--data-dir", type=Path, help="override data_dir")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uav-ground-station",
        description="Receive, store and show a UAV fleet's prioritised images; manage missions.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser("run", help="run the ground station (UDP receiver + web dashboard)")
    _common(run)
    run.add_argument("--mission", help="mission name images and logs are grouped under")
    run.add_argument("--udp-port", type=int, help="UDP port the fleet sends to")
    run.add_argument("--http-host", help="dashboard address (default 127.0.0.1)")
    run.add_argument("--http-port", type=int, help="dashboard port (default 8080)")
    run.add_argument("--public-read", action="store_true", help="dashboard readable without token")
    run.add_argument("-v", "--verbose", action="store_true")
    shell = sub.add_parser("shell", help="interactive mission manager (thesis fig. 3.7)")
    _common(shell)
    shell.add_argument("--url", help="ground station base URL (default from the config)")
    shell.add_argument("--token", help="control token (default: read from data_dir/token)")
    shell.add_argument("-c", "--commands", help="run these ';'-separated commands and exit")
    export = sub.add_parser("export", help="images and a geotag CSV for photogrammetry")
    _common(export)
    export.add_argument("mission", help="mission name")
    export.add_argument("--out", type=Path, required=True, help="output folder")
    export.add_argument("--include-stale-poses", action="store_true",
                        help="also list images with a stale or no position in geotags.csv "
                             "(column 'pose' says which)")
    token = sub.add_parser("token", help="print the control token (created if missing)")
    _common(token)
    return parser


def _run(args: argparse.Namespace, config: GroundConfig) -> int:
    from aiohttp import web

    from ground_station.app import create_app
    from ground_station.utility import image_utility_from_spec

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:  # a broken spec stops us before a new token is made (it is shown only once)
        image_utility_from_spec(config.spec, alpha=config.alpha)
    except UtilitySpecsError as exc:
        print(f"uav-ground-station: mission spec {config.spec}: {exc}", file=sys.stderr)
        return 2
    token, created = ensure_token(config.token_path)
    app = create_app(config, token=token)
    if created:
        print(f"control token (shown once, stored 0600 in {config.token_path}): {token}")
        print(f"dashboard: http://{config.http_host}:{config.http_port}/?token={token}")
    else:
        print(
            f"dashboard: http://{config.http_host}:{config.http_port}/ "
            f"(token: uav-ground-station token --data-dir {config.data_dir})"
        )
    sys.stdout.flush()
    try:
        web.run_app(
            app, host=config.http_host, port=config.http_port, print=None, handle_signals=True
        )
    except OSError as exc:  # address in use, permission denied...
        print(f"uav-ground-station: cannot serve: {exc}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        config = _config(args)
    except ConfigError as exc:
        print(f"uav-ground-station: configuration error: {exc}", file=sys.stderr)
        return 2
    if args.command == "run":
        return _run(args, config)
    if args.command == "token":
        token, created = ensure_token(config.token_path)
        print(token)
        if created:
            print(f"(new token stored 0600 in {config.token_path})", file=sys.stderr)
        return 0
    if args.command == "export":
        from ground_station.export import export_mission

        try:
            result = export_mission(config.data_dir, args.mission, args.out,
                                    include_stale=args.include_stale_poses)
        except KeyError as exc:
            print(f"uav-ground-station: {exc.args[0]}", file=sys.stderr)
            return 1
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
    except OSError as exc:
        print(f"uav-ground-station: no token ({exc}); pass --token", file=sys.stderr)
        return 2
    lines = [c for c in args.commands.split(";")] if args.commands else None
    return asyncio.run(run_shell(url, token, lines=lines))


if __name__ == "__main__":
    raise SystemExit(main())
