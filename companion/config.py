"""The companion's TOML configuration, validated once at start.

Default location ``/etc/uav-companion/config.toml`` (``--config`` overrides). Every error is a
:class:`ConfigError` whose text names the file, the key and the expected value, e.g.
``/etc/uav-companion/config.toml: camera.rate_hz: expected a number > 0, got -1``.
Unknown keys are errors too (a typo must not silently fall back to a default).
See ``examples/companion.toml`` for every key with its default.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.config_table import ConfigError, Table, is_mavlink_url, is_number, is_sender_id
from companion.mavlink import DEFAULT_STREAM_RATES_HZ, MavlinkSettings
from companion.mavlink_commands import DEFAULT_MAVLINK_URL
from companion.peers import PeersSettings, parse_peers_settings
from companion.protocol.errors import LocalProtocolError
from companion.protocol.signing import (
    WrongKeyKind,
    decode_key_text,
    same_key,
)
from companion.protocol.wire import MAX_ID_BYTES, MIN_KEY_BYTES
from companion.scoring import SCORERS
from companion.secret_files import UnsafeKeyFile, read_key_file

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "BudgetConfig",
    "CameraConfig",
    "CompanionConfig",
    "ConfigError",
    "ConstraintConfig",
    "GroundStationConfig",
    "MissionConfig",
    "ScoringConfig",
    "TelemetryConfig",
    "load_config",
    "missing_keys",
    "parse_config",
]

DEFAULT_CONFIG_PATH = Path("/etc/uav-companion/config.toml")


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraConfig:
    enabled: bool = True
    source: str = "synthetic"
    width: int = 640
    height: int = 480
    rate_hz: float = 5.0
    jpeg_quality: int = 80
    versions: tuple[str, ...] = ("full", "half", "quarter")
    """Resolutions each image is offered in (eq. 4.33), best first."""
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, kw_only=True)
class ScoringConfig:
    scorers: tuple[str, ...] = ("red_share",)
    settings: Mapping[str, Any] = field(default_factory=dict)
    """Scorer name -> its settings from ``[scoring.NAME]`` (every registered scorer's table is
    read, so a typo is an error even for a scorer not listed); absent: its defaults."""


@dataclass(frozen=True, slots=True, kw_only=True)
class MissionConfig:
    spec: str = "builtin:image_streaming"
    """A spec file path, or ``builtin:NAME`` for one shipped with utility_specs."""
    log: str | None = None
    """Mission log (JSON Lines) path; None = no log."""
    wait_for_start: bool = False
    """Send only status until the ground station's ``start`` command (synchronised start)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class GroundStationConfig:
    host: str = "127.0.0.1"
    port: int = 14600
    fleet_key: bytes | None = None
    """HMAC key of the fleet (from ``fleet_key_file``); there is no built-in one."""
    command_public_key: bytes | None = None
    """The ground station's Ed25519 public key (``command_public_key_file``): only commands
    it verifies are obeyed."""
    fleet_id: int = 1
    listen_host: str = "0.0.0.0"
    listen_port: int = 0
    """Local UDP port for reports and commands (0 = any)."""
    link_rate_bytes_per_s: float = 0.0
    """The radio link's rate toward the station, when known (0: unknown). The transport
    never paces a message's datagrams faster than this (docs/protocol.md, pacing)."""
    key_files: tuple[str, ...] = ()
    """The key files the keys were read from: the service's user must read them too."""


@dataclass(frozen=True, slots=True, kw_only=True)
class BudgetConfig:
    mcts_iterations: int = 300
    time_budget_s: float = 0.05
    """Wall time the decision of one message may take (executor wait bound)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class ConstraintConfig:
    name: str = "adaptive"
    params: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, kw_only=True)
class TelemetryConfig:
    position_rate_hz: float = 1.0
    battery_period_s: float = 5.0
    status_period_s: float = 1.0
    """A status this often during the mission: before the vehicle has a position it is most
    of what the station hears, and its ``link_lost_s`` (3 s) must not pass between two (5 s
    raised "link lost" and "link back" over and over on a healthy link)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class CompanionConfig:
    drone_id: str
    mavlink: MavlinkSettings
    camera: CameraConfig = field(default_factory=CameraConfig)
    scoring: ScoringConfig = field(default_factory=ScoringConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)
    ground_station: GroundStationConfig = field(default_factory=GroundStationConfig)
    budgets: BudgetConfig = field(default_factory=BudgetConfig)
    constraint: ConstraintConfig = field(default_factory=ConstraintConfig)
    telemetry: TelemetryConfig = field(default_factory=TelemetryConfig)
    middleware: Mapping[str, Any] = field(default_factory=dict)
    """``policy`` (a name of ``companion.middleware.policies.DECIDERS``, default ``mcts``),
    ``seed``, ``fleet_size`` and ``dp_seed`` (mcts: drones in the mission, the width of
    the search's seeding programme, 0 for none; checked here) and the policy's
    own keys (``alpha``, ``drop_probability``...), checked when the policy is built."""
    peers: PeersSettings = field(default_factory=PeersSettings)
    """The ``[peers]`` table (shared medium, ADSB_VEHICLE, /peers endpoint: docs/peers.md)."""
    source: str = "<memory>"


def _check_policy(name: Any, source: str) -> None:
    """``[middleware] policy`` must name a registered decision policy."""
    from companion.middleware.policies import DECIDERS

    if not isinstance(name, str) or name not in DECIDERS:
        raise ConfigError(f"{source}: middleware.policy: expected one of "
                          f"{', '.join(sorted(DECIDERS))}, got {name!r}")


def _check_whole(middleware: Mapping[str, Any], key: str, minimum: int, source: str) -> None:
    """A whole-number ``[middleware]`` key of the mcts policy, checked here so a bad one is a
    one-line config error: ``fleet_size`` (>= 1, the drones the mission declares: the share
    of the budget at the mission start, issue 18) and ``dp_seed`` (>= 0, the width of the
    search's seeding programme; 0 turns it off, alg. 2's rule alone)."""
    if key not in middleware:
        return
    value = middleware[key]
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{source}: middleware.{key}: expected an integer >= {minimum}, "
                          f"got {value!r}")


def _resolve(path: str, base: Path) -> Path:
    """A path from the file, relative to the file's folder."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else base / p


def _command_public_key(t: Table, base: Path, fleet_key: bytes | None) -> bytes | None:
    key_file = t.string("command_public_key_file", None)
    key_text = t.string("command_public_key", None)
    name = "command_public_key_file" if key_file is not None else "command_public_key"
    if key_file is not None:
        try:
            raw = read_key_file(_resolve(key_file, base), "command public key", key_file)
        except WrongKeyKind as exc:
            raise ConfigError(f"{t.source}: {t.key(name)}: {exc}") from None
        except OSError as exc:
            t.fail(name, "a readable key file", f"{key_file} ({exc.strerror})")
    elif key_text is not None:
        raw = str(key_text).encode()
    else:
        return None
    what = f"{key_file}" if key_file is not None else "the key"
    try:
        key = decode_key_text(raw, what, kind="command public key")
    except WrongKeyKind as exc:
        raise ConfigError(f"{t.source}: {t.key(name)}: {exc}") from None
    except LocalProtocolError as exc:
        t.fail(name, "command.pub as written by uav-ground-station keygen", str(exc))
    if fleet_key is not None and same_key(fleet_key, key):  # untagged files look alike
        raise ConfigError(f"{t.source}: {t.key(name)}: {what} is the same key as "
                          f"{t.key('fleet_key_file')}: the fleet key is fleet.key, the ground "
                          "station's command public key command.pub")
    return key


def missing_keys(config: CompanionConfig) -> str | None:
    """Why ``run`` cannot start without keys (one line with the commands), or None."""
    gs = config.ground_station
    if gs.fleet_key is not None and gs.command_public_key is not None:
        return None
    which = ("ground_station.fleet_key_file" if gs.fleet_key is None
             else "ground_station.command_public_key_file")
    return (f"{config.source}: {which} is not set (there is no built-in key): make the "
            "fleet's keys on the ground station with `uav-ground-station keygen --out keys`, "
            "copy keys/fleet.key and keys/command.pub to this drone and set "
            "ground_station.fleet_key_file and ground_station.command_public_key_file")


def _fleet_key(t: Table, base: Path) -> bytes | None:
    key_file = t.string("fleet_key_file", None)
    key_text = t.string("fleet_key", None)
    if key_file is not None:
        try:
            key = read_key_file(_resolve(key_file, base), "fleet key", key_file).strip()
        except WrongKeyKind as exc:
            raise ConfigError(f"{t.source}: {t.key('fleet_key_file')}: {exc}") from None
        except UnsafeKeyFile as exc:
            t.fail("fleet_key_file", "a key file only its owner can read", str(exc))
        except OSError as exc:
            t.fail("fleet_key_file", "a readable key file", f"{key_file} ({exc.strerror})")
    elif key_text is not None:
        key = str(key_text).encode()
    else:
        return None
    if len(key) < MIN_KEY_BYTES:
        t.fail("fleet_key_file" if key_file is not None else "fleet_key",
               f"a key of at least {MIN_KEY_BYTES} bytes", f"{len(key)} bytes")
    return key


def parse_config(raw: Mapping[str, Any], *, source: str = "<memory>") -> CompanionConfig:
    """Validate a parsed TOML mapping into a :class:`CompanionConfig`."""
    root = Table(raw, source, "")
    base = Path(source).parent if source != "<memory>" else Path.cwd()

    drone = root.table("drone")
    drone_id = str(drone.string("id", None, required=True))
    if not is_sender_id(drone_id):  # what the wire carries; `run` would refuse it later
        drone.fail("id", f"a printable sender id of 1..{MAX_ID_BYTES} UTF-8 bytes", drone_id)
    drone.done()

    mav = root.table("mavlink")
    url = mav.get("url", DEFAULT_MAVLINK_URL, "a pymavlink URL: udpin:HOST:PORT, "
                  "udpout:HOST:PORT, tcp:HOST:PORT (port 1..65535) or a serial device "
                  "path like /dev/serial0", is_mavlink_url)
    rates = mav.get("stream_rates_hz", dict(DEFAULT_STREAM_RATES_HZ),
                    "a table of MAVLink message names (defaults: "
                    f"{', '.join(DEFAULT_STREAM_RATES_HZ)}; any other, e.g. HIGHRES_IMU = 0 "
                    "to turn off a stream the companion does not use) to Hz >= 0",
                    lambda v: isinstance(v, Mapping) and all(
                        is_message_name(k) and is_number(x) and x >= 0
                        for k, x in v.items()))
    mavlink = MavlinkSettings(
        url=url,
        source_system=mav.integer("source_system", 1, low=1, high=255),
        source_component=mav.integer("source_component", 191, low=1, high=255),
        heartbeat_timeout_s=mav.number("heartbeat_timeout_s", 3.0),
        reconnect_delay_s=mav.number("reconnect_delay_s", 1.0),
        stream_ack_timeout_s=mav.number("stream_ack_timeout_s", 1.5),
        baud=mav.integer("baud", 115200, low=1200, high=12_000_000),
        # A listed message overrides its default, 0 turns it off; the unlisted keep their
        # defaults: a short table must not drop EKF_STATUS_REPORT / ESTIMATOR_STATUS, which
        # tell whether a position may be used (the shipped example's table lacked them).
        stream_rates_hz={**DEFAULT_STREAM_RATES_HZ, **{k: float(v) for k, v in rates.items()}},
    )
    mav.done()

    cam = root.table("camera")
    camera = CameraConfig(
        enabled=cam.boolean("enabled", True),
        source=cam.string("source", "synthetic"),
        width=cam.integer("width", 640, low=16, high=8192),
        height=cam.integer("height", 480, low=16, high=8192),
        rate_hz=cam.number("rate_hz", 5.0),
        jpeg_quality=cam.integer("jpeg_quality", 80, low=1, high=100),
        versions=tuple(sorted(
            cam.get("versions", ["full", "half", "quarter"],
                    "a non-empty list of full | half | quarter",
                    lambda v: isinstance(v, list) and bool(v) and len(set(v)) == len(v)
                    and all(x in ("full", "half", "quarter") for x in v)),
            key=["full", "half", "quarter"].index)),
        options=cam.mapping("options"),
    )
    cam.done()

    sc = root.table("scoring")
    known = list(SCORERS)
    names = sc.get("scorers", ["red_share"], f"a list of {' | '.join(known)}",
                   lambda v: isinstance(v, list) and all(x in known for x in v))
    settings: dict[str, Any] = {}
    for name in known:
        table = sc.table(name)
        try:
            settings[name] = SCORERS[name].read_settings(table)
        except (ValueError, TypeError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"{source}: scoring.{name}: {exc}") from None
        table.done()
    sc.done()
    scoring = ScoringConfig(scorers=tuple(names), settings=settings)

    mi = root.table("mission")
    spec = mi.string("spec", "builtin:image_streaming")
    if not spec.startswith("builtin:"):
        spec = str(_resolve(spec, base))
    log_path = mi.string("log", None)
    mission = MissionConfig(spec=spec,
                            log=None if log_path is None else str(_resolve(log_path, base)),
                            wait_for_start=mi.boolean("wait_for_start", False))
    mi.done()

    gs = root.table("ground_station")
    ground = GroundStationConfig(
        host=gs.string("host", "127.0.0.1"),
        port=gs.integer("port", 14600, low=1, high=65535),
        fleet_key=(fleet_key := _fleet_key(gs, base)),
        command_public_key=_command_public_key(gs, base, fleet_key),
        fleet_id=gs.integer("fleet_id", 1, low=0, high=0xFFFF_FFFF),
        listen_host=gs.string("listen_host", "0.0.0.0"),
        listen_port=gs.integer("listen_port", 0, low=0, high=65535),
        link_rate_bytes_per_s=gs.number("link_rate_bytes_per_s", 0.0, strict=False),
        key_files=tuple(str(_resolve(name, base)) for name in (
            gs.string("fleet_key_file", None), gs.string("command_public_key_file", None))
            if name is not None),
    )
    gs.done()

    bu = root.table("budgets")
    budgets = BudgetConfig(
        mcts_iterations=bu.integer("mcts_iterations", 300, low=1, high=1_000_000),
        time_budget_s=bu.number("time_budget_s", 0.05),
    )
    bu.done()

    co = root.table("constraint")
    constraint = ConstraintConfig(name=co.string("name", "adaptive"), params=co.mapping("params"))
    co.done()

    te = root.table("telemetry")
    telemetry = TelemetryConfig(
        position_rate_hz=te.number("position_rate_hz", 1.0, strict=False),
        battery_period_s=te.number("battery_period_s", 5.0),
        status_period_s=te.number("status_period_s", 1.0),
    )
    te.done()

    middleware = root.mapping("middleware")
    _check_policy(middleware.get("policy", "mcts"), source)
    _check_whole(middleware, "fleet_size", 1, source)
    _check_whole(middleware, "dp_seed", 0, source)
    try:
        peers = parse_peers_settings(root.mapping("peers"))
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    root.done()
    return CompanionConfig(
        drone_id=drone_id, mavlink=mavlink, camera=camera, scoring=scoring, mission=mission,
        ground_station=ground, budgets=budgets, constraint=constraint, telemetry=telemetry,
        middleware=middleware, peers=peers, source=source,
    )


def is_message_name(name: object) -> bool:
    """A message of the MAVLink dialect the companion speaks (common + ardupilotmega): the
    companion asks for streams by id, and PX4's onboard link sends ~400 messages/s by
    default, most of them (HIGHRES_IMU, ...) of no use on a Raspberry Pi."""
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    return isinstance(name, str) and name.isupper() and \
        isinstance(getattr(dialect, f"MAVLINK_MSG_ID_{name}", None), int)


def load_config(path: str | Path = DEFAULT_CONFIG_PATH) -> CompanionConfig:
    """Read and validate the configuration file (the only function here touching a file)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such configuration file (use --config PATH)") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a configuration file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text file (byte {exc.start} is not UTF-8); "
                          "expected TOML") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML (arrays or tables nested too deeply)") \
            from None
    return parse_config(raw, source=str(path))
