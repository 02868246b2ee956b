"""Ground-station configuration: one frozen dataclass, read from TOML and validated at start.

A wrong file fails with :class:`ConfigError` naming the file, the key and what was expected
(ARCHITECTURE.md, "Configuration is TOML").
"""

from __future__ import annotations

import hashlib
import re
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from companion.config_table import described, known_key_expected
from companion.protocol.errors import LocalProtocolError
from companion.protocol.signing import (
    KEY_BYTES,
    KeyKind,
    WrongKeyKind,
    decode_key_text,
    public_key_of,
    same_key,
)
from companion.protocol.wire import MIN_KEY_BYTES
from companion.secret_files import UnsafeKeyFile, read_key_file, read_secret

__all__ = ["ConfigError", "GroundConfig", "load_config", "missing_keys"]

_PRIVATE = "a key file only its owner can read"
_HOST_NAME = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*\.?")
"""A DNS name (labels of letters, digits and inner hyphens); ``allowed_hosts`` entries."""


class ConfigError(ValueError):
    """A configuration value that cannot be used; the text names file, key and expectation."""

    def __init__(self, file: str, key: str, expected: str, got: object = None, *,
                 detail: str | None = None) -> None:
        self.file = file
        self.key = key
        self.expected = expected
        self.got = got
        self.detail = detail
        # "<file>"/"<syntax>": the whole file, not a key in it ("key '<file>'" read as noise)
        where = "" if key.startswith("<") else f" key {key!r}:"
        message = f"{file}:{where} expected {expected}"
        if detail is not None:  # a sentence of its own (a key file of the wrong kind)
            message = f"{file}:{where} {detail}"
        elif got is not None:
            message += f", got {described(key, got)}"
        super().__init__(message)


@dataclass(frozen=True, slots=True, kw_only=True)
class GroundConfig:
    """Everything the ground station needs; defaults suit a loopback demo."""

    station_id: str = "gs"
    """Receiver id written into the mission log (``receiver`` field)."""
    fleet_id: int = 1
    """Fleet id every datagram must carry (protocol header)."""
    fleet_key: bytes | None = None
    """HMAC key shared by the fleet (``fleet_key_file``); there is no built-in one. When unset,
    ``data_dir/keys/fleet.key`` is used if it exists (``uav-ground-station keygen``)."""
    command_key: bytes | None = None
    """The station's Ed25519 private key that signs commands (``command_key_file``); when
    unset, ``data_dir/keys/command.key`` if it exists."""
    data_dir: Path = Path("gs-data")
    """Where the SQLite database, images, mission logs and the control token live."""
    mission: str = "default"
    """Name of the current mission (images and log records are grouped by it)."""
    udp_host: str = "127.0.0.1"
    """Where the fleet's datagrams are received; set the radio link's address (or 0.0.0.0,
    which is logged as a warning) for real drones."""
    udp_port: int = 14600
    udp_rcvbuf_bytes: int = 16 << 20
    """Kernel receive buffer asked for (fragments of 100 images/s must not overflow it)."""
    http_host: str = "127.0.0.1"
    http_port: int = 8080
    allowed_hosts: tuple[str, ...] = ()
    """DNS names the dashboard answers to besides IP literals, ``localhost`` and
    ``http_host`` (``--allowed-host``); any other ``Host`` is refused (DNS rebinding)."""
    http_max_connections: int = 128
    """Concurrent HTTP connections served; more are closed at once, so browsers and scanners
    can never take the file descriptors the UDP receiver and the storage need."""
    http_max_per_client: int = 64
    """Of those, how many one client address may hold (a browser uses about six): one host
    cannot take them all. Behind a reverse proxy every client has the proxy's address."""
    http_idle_timeout_s: float = 15.0
    """An HTTP connection idle this long (also one that never sends a request) is closed."""
    report_interval_s: float = 0.25
    """Receiver report period (thesis ch. 6 needs a few samples per second)."""
    command_retry_s: float = 0.5
    """How often an unacknowledged mission command is sent again."""
    command_reply_timeout_s: float = 5.0
    """A drone without a done/error this long after a command's execution time: no reply."""
    command_ttl_s: float = 30.0
    """How long after its execution time a command still goes to drones that lack it."""
    link_lost_s: float = 3.0
    """A drone not heard for this long raises a link-loss alert."""
    reassembly_timeout_s: float = 2.0
    max_pending_messages: int = 256
    """Bound on partially received images held in memory by the decoder."""
    alpha: float = 10.0
    """α of eq. 7.1/7.2, weight of red share / object in image utility."""
    high_utility: float | None = None
    """Images at or above this utility weight get a red border (thesis fig. 7.5); default:
    derived from the spec's utility scale with ``high_utility_fraction``."""
    high_utility_fraction: float = 0.1
    """Share of the largest utility gain an image type can give (α of eq. 7.1/7.2) from
    which its images count as high: 1 + 0.1·α, a 10 % red share."""
    spec: Path | None = None
    """Mission spec TOML; when given, image utility follows its ``red_image``/``object_image``."""
    scene: Path | None = None
    """Scene TOML of the mission area (``uav-sitl`` format): the dashboard map draws its
    outline, targets and home, and local coordinates start at its home."""
    public_read: bool = False
    """Whether read-only views (dashboard, /api GETs, WebSocket) are open without the token."""
    ws_queue_size: int = 64
    """Per-browser queue of pending updates; the oldest is dropped when full."""
    ws_max_per_client: int = 8
    """Open WebSockets (dashboard tabs) one client address may hold; all of them together
    hold at most half of ``http_max_connections``, so plain requests always get through."""
    ws_send_timeout_s: float = 5.0
    """A dashboard whose update cannot be sent this long (it stopped reading) is dropped."""
    ws_heartbeat_s: float = 10.0
    """WebSocket ping period; a client without a pong within half of it is closed."""
    clock_tolerance_s: float = 30.0
    """Datagrams whose t_gen is further than this from our clock are stale."""
    fsync: bool = True
    """fsync every image file (and its folder) before it counts as stored."""
    token_file: Path | None = None
    """Control token location; default ``data_dir / "token"``."""
    mavlink_out: str | None = None
    """``HOST:PORT`` the fleet is re-emitted to as MAVLink 2 (e.g. QGC's
    ``127.0.0.1:14550``); off when unset (docs/peers.md)."""
    mavlink_listen: str | None = None
    """``HOST:PORT`` the MAVLink mirror binds for clients that connect."""
    mavlink_signing_key: bytes | None = None
    """MAVLink 2 signing key of the mirror (``mavlink_signing_key_file``: a passphrase, the
    key its SHA-256 as MAVProxy's ``signing setup`` makes it): every frame out is signed,
    and only signed clients are answered. None: unsigned (docs/peers.md)."""
    shared_medium: str | None = None
    """the fleet's shared medium (``broadcast:ADDR:PORT`` or
    ``multicast:GROUP:PORT[:IFACE]``) heard besides ``udp_port``; None: unicast only."""

    def __post_init__(self) -> None:
        checks: list[tuple[str, bool, str]] = [
            ("station_id", bool(self.station_id), "a non-empty string"),
            ("fleet_id", 0 <= self.fleet_id < 2**32, "an integer in 0..2**32-1"),
            ("fleet_key", self.fleet_key is None or len(self.fleet_key) >= MIN_KEY_BYTES,
             f"at least {MIN_KEY_BYTES} bytes"),
            ("command_key", self.command_key is None or len(self.command_key) == KEY_BYTES,
             f"{KEY_BYTES} bytes (an Ed25519 private key)"),
            ("mission", bool(self.mission) and "/" not in self.mission, "a name without '/'"),
            ("udp_port", 0 <= self.udp_port < 65536, "a port 0..65535"),
            ("http_port", 0 <= self.http_port < 65536, "a port 0..65535"),
            ("http_max_connections", self.http_max_connections >= 1, "an integer >= 1"),
            ("http_max_per_client", self.http_max_per_client >= 1, "an integer >= 1"),
            ("http_idle_timeout_s", self.http_idle_timeout_s > 0, "a number > 0"),
            ("udp_rcvbuf_bytes", self.udp_rcvbuf_bytes >= 65536, "an integer >= 65536"),
            ("report_interval_s", self.report_interval_s > 0, "a number > 0"),
            ("command_retry_s", self.command_retry_s > 0, "a number > 0"),
            ("command_reply_timeout_s", self.command_reply_timeout_s > 0, "a number > 0"),
            ("command_ttl_s", self.command_ttl_s > 0, "a number > 0"),
            ("link_lost_s", self.link_lost_s > 0, "a number > 0"),
            ("reassembly_timeout_s", self.reassembly_timeout_s > 0, "a number > 0"),
            ("max_pending_messages", self.max_pending_messages > 0, "an integer > 0"),
            ("alpha", self.alpha >= 0, "a number >= 0"),
            ("high_utility_fraction", 0 < self.high_utility_fraction <= 1,
             "a number in (0, 1]"),
            ("ws_queue_size", self.ws_queue_size > 0, "an integer > 0"),
            ("ws_max_per_client", self.ws_max_per_client >= 1, "an integer >= 1"),
            ("ws_send_timeout_s", self.ws_send_timeout_s > 0, "a number > 0"),
            ("ws_heartbeat_s", self.ws_heartbeat_s > 0, "a number > 0"),
            ("clock_tolerance_s", self.clock_tolerance_s > 0, "a number > 0"),
        ]
        for key, ok, expected in checks:
            if not ok:
                got = getattr(self, key)
                if key in ("fleet_key", "command_key"):  # a secret: its length, never bytes
                    got = f"{len(got)} bytes"
                raise ConfigError("<config>", key, expected, got)
        if self.fleet_key is not None and self.command_key is not None and (
                same_key(self.fleet_key, self.command_key)
                or same_key(self.fleet_key, public_key_of(self.command_key))):
            raise ConfigError("<config>", "fleet_key", "", detail=(
                "the fleet key is the same key as the command key or its public key (bare "
                "key files look alike): the fleet key is fleet.key, the command key "
                "command.key"))
        for name in self.allowed_hosts:
            if not _HOST_NAME.fullmatch(name) or len(name) > 253:
                raise ConfigError("<config>", "allowed_hosts",
                                  "DNS names like gs.example.org (no port, no scheme)", name)
        for key in ("mavlink_out", "mavlink_listen"):
            value = getattr(self, key)
            if value is not None:
                from ground_station.mavlink_out import parse_endpoint
                try:
                    parse_endpoint(value)
                except ValueError:
                    raise ConfigError("<config>", key, "HOST:PORT", value) from None
        if self.shared_medium is not None:
            from companion.medium import parse_medium
            try:
                medium = parse_medium(self.shared_medium)
            except ValueError:
                raise ConfigError("<config>", "shared_medium",
                                  "broadcast:ADDR:PORT or multicast:GROUP:PORT[:IFACE]",
                                  self.shared_medium) from None
            if medium.port == self.udp_port:  # run said "dashboard ... is already in use"
                raise ConfigError("<config>", "shared_medium", "", detail=(
                    f"{self.shared_medium!r} uses port {medium.port}, the station's udp_port "
                    "too: give the medium a port of its own, the same on every drone"))

    @property
    def token_path(self) -> Path:
        return self.token_file if self.token_file is not None else self.data_dir / "token"

    def with_overrides(self, **changes: Any) -> GroundConfig:
        return replace(self, **changes)


_TYPES: dict[str, tuple[type | tuple[type, ...], str]] = {
    "station_id": (str, "a string"),
    "fleet_id": (int, "an integer"),
    "fleet_key": (str, "a string"),
    "fleet_key_file": (str, "a path string"),
    "command_key_file": (str, "a path string"),
    "data_dir": (str, "a path string"),
    "mission": (str, "a string"),
    "udp_host": (str, "a host string"),
    "udp_port": (int, "an integer port"),
    "udp_rcvbuf_bytes": (int, "an integer number of bytes"),
    "http_host": (str, "a host string"),
    "http_port": (int, "an integer port"),
    "allowed_hosts": (list, "a list of DNS names"),
    "http_max_connections": (int, "an integer"),
    "http_max_per_client": (int, "an integer"),
    "http_idle_timeout_s": ((int, float), "a number of seconds"),
    "report_interval_s": ((int, float), "a number of seconds"),
    "command_retry_s": ((int, float), "a number of seconds"),
    "command_reply_timeout_s": ((int, float), "a number of seconds"),
    "command_ttl_s": ((int, float), "a number of seconds"),
    "link_lost_s": ((int, float), "a number of seconds"),
    "reassembly_timeout_s": ((int, float), "a number of seconds"),
    "max_pending_messages": (int, "an integer"),
    "alpha": ((int, float), "a number"),
    "high_utility": ((int, float), "a number"),
    "high_utility_fraction": ((int, float), "a number in (0, 1]"),
    "spec": (str, "a path string"),
    "scene": (str, "a path string"),
    "public_read": (bool, "true or false"),
    "ws_queue_size": (int, "an integer"),
    "ws_max_per_client": (int, "an integer"),
    "ws_send_timeout_s": ((int, float), "a number of seconds"),
    "ws_heartbeat_s": ((int, float), "a number of seconds"),
    "clock_tolerance_s": ((int, float), "a number of seconds"),
    "fsync": (bool, "true or false"),
    "token_file": (str, "a path string"),
    "mavlink_out": (str, "HOST:PORT"),
    "mavlink_listen": (str, "HOST:PORT"),
    "mavlink_signing_key_file": (str, "a path string"),
    "shared_medium": (str, "broadcast:ADDR:PORT or multicast:GROUP:PORT[:IFACE]"),
}


def config_from_mapping(raw: dict[str, Any], *, file: str = "<config>") -> GroundConfig:
    """Build a config from a parsed TOML table (``[ground_station]`` or top level)."""
    table = raw.get("ground_station", raw)
    if not isinstance(table, dict):
        raise ConfigError(file, "ground_station", "a table")
    known = ({f.name for f in fields(GroundConfig)} - {"command_key", "mavlink_signing_key"}) | {
        "fleet_key_file", "command_key_file", "mavlink_signing_key_file"}
    base = Path(file).parent if file != "<config>" else Path.cwd()
    values: dict[str, Any] = {}
    value: Any
    for key, value in table.items():
        if key not in known:
            raise ConfigError(file, key, known_key_expected(key, known))
        want, text = _TYPES[key]
        # bool is an int subclass: refuse true/false where a number is expected.
        if not isinstance(value, want) or (isinstance(value, bool) and want is not bool):
            raise ConfigError(file, key, text, value)
        if key in ("data_dir", "spec", "scene", "token_file"):
            path = Path(str(value)).expanduser()
            values[key] = path if path.is_absolute() else base / path
        elif key == "fleet_key":
            values[key] = str(value).encode()
        elif key == "allowed_hosts":
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise ConfigError(file, key, "a list of DNS names (strings)", value)
            values[key] = tuple(value)
        elif key == "fleet_key_file":
            values["fleet_key"] = _key_file(file, key, value, base, "fleet key").strip()
        elif key == "mavlink_signing_key_file":
            passphrase = _key_file(file, key, value, base, None).strip()
            if len(passphrase) < 8:
                raise ConfigError(file, key, "a passphrase of at least 8 bytes",
                                  f"{len(passphrase)} bytes")
            values["mavlink_signing_key"] = hashlib.sha256(passphrase).digest()
        elif key == "command_key_file":
            key_text = _key_file(file, key, value, base, "command key")
            try:
                values["command_key"] = decode_key_text(key_text, "command key",
                                                        kind="command key")
            except LocalProtocolError as exc:
                raise ConfigError(file, key, "a file written by uav-ground-station keygen",
                                  str(exc)) from exc
        elif isinstance(value, int) and not isinstance(value, bool) and want == (int, float):
            values[key] = float(value)
        else:
            values[key] = value
    try:
        return GroundConfig(**values)
    except ConfigError as exc:
        raise ConfigError(file, exc.key, exc.expected, exc.got, detail=exc.detail) from exc


def _key_file(file: str, key: str, value: Any, base: Path, kind: KeyKind | None) -> bytes:
    """A ``*_key_file``'s bytes (relative to the config's folder; private to this user),
    refused when ``keygen`` tagged it as another kind of key than ``kind``."""
    path = Path(str(value)).expanduser()
    path = path if path.is_absolute() else base / path
    try:
        return read_secret(path) if kind is None else read_key_file(path, kind, str(value))
    except WrongKeyKind as exc:
        raise ConfigError(file, key, exc.expected, detail=str(exc)) from None
    except UnsafeKeyFile as exc:
        raise ConfigError(file, key, _PRIVATE, str(exc)) from exc
    except OSError as exc:
        raise ConfigError(file, key, "a readable key file", str(exc)) from exc


def load_config(path: Path | str) -> GroundConfig:
    """Read and validate a TOML file; every problem names file, key and expectation."""
    file = str(path)
    try:
        with open(path, "rb") as handle:
            raw = tomllib.load(handle)
    except FileNotFoundError as exc:
        raise ConfigError(file, "<file>", "an existing TOML file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(file, "<syntax>", f"valid TOML ({exc})") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(file, "<syntax>", "a UTF-8 TOML text file",
                          f"byte {exc.start} is not UTF-8") from None
    except RecursionError:
        raise ConfigError(file, "<syntax>", "valid TOML", "arrays or tables nested too deeply") \
            from None
    except OSError as exc:  # a folder, no permission...
        raise ConfigError(file, "<file>", "a readable TOML file", exc.strerror) from None
    return config_from_mapping(raw, file=file)


def missing_keys(config: GroundConfig) -> GroundConfig | str:
    """The config with its keys filled in from ``data_dir/keys`` when the config names none,
    or a one-line reason (with the command that makes the keys) when there are none."""
    from ground_station.keyfiles import KeyFiles

    files = KeyFiles(config.data_dir / "keys")
    changes: dict[str, bytes] = {}
    try:
        if config.fleet_key is None and files.fleet_key.is_file():
            changes["fleet_key"] = read_key_file(files.fleet_key, "fleet key",
                                                 str(files.fleet_key)).strip()
        if config.command_key is None and files.command_key.is_file():
            changes["command_key"] = decode_key_text(
                read_key_file(files.command_key, "command key", str(files.command_key)),
                str(files.command_key), kind="command key")
        config = config.with_overrides(**changes) if changes else config
    except (OSError, LocalProtocolError, ConfigError) as exc:
        return f"cannot read the keys in {files.folder}: {exc}"
    if config.fleet_key is None or config.command_key is None:
        which = "fleet key" if config.fleet_key is None else "command key"
        return (f"no {which} (there is no built-in one): make the fleet's keys with "
                f"`uav-ground-station keygen --data-dir {config.data_dir}` "
                "(or set fleet_key_file and command_key_file in the config)")
    return config
