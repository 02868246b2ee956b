"""The run folder of a simulated fleet: per-drone companion configs, the ground-station config
and a fresh fleet key, all written by ``uav-sitl fleet`` before anything starts.

The layout (``--out DIR``, default ``out/fleet/RUN``)::

    RUN/fleet.key                      HMAC key of this run, mode 0600 (random per run)
    RUN/command.key, command.pub       the station's Ed25519 command key pair of this run
    RUN/ground_station.toml            uav-ground-station run --config ...
    RUN/gs-data/                       its data dir: SQLite, images, mission log, token (0600)
    RUN/drones/droneN/companion.toml   uav-companion run --config ...
    RUN/drones/droneN/mission_log.jsonl   the companion's decisions (JSON Lines)
    RUN/logs/*.log                     stdout/stderr of every process
    RUN/summary.json                   written at the end

Everything here is plain data and text: the TOML writers are pure functions of a
:class:`FleetPlan`, so tests can read back exactly what the processes get.
"""

from __future__ import annotations

import base64
import json
import math
import os
import secrets
import socket
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "DroneSlot",
    "FleetPlan",
    "companion_toml",
    "free_port",
    "ground_station_toml",
    "mavlink_host",
    "mission_spec_path",
    "toml_value",
    "write_fleet_key",
    "write_run_configs",
]


STATUS_PERIOD_S = 1.0
"""Every simulated drone sends a status this often (a few hundred bytes, counted in its
goodput window like any message), so the station hears each drone at a fixed rate."""
LINK_LOST_S = 5.0
"""The station flags a drone lost after this much silence: five missed statuses, well above
the queueing delay of the shaped link (under a second), so a clean run raises no alert."""


def mission_spec_path(name: str = "image_streaming") -> Path:
    """The shipped mission spec file ``utility_specs/missions/NAME.toml`` (or a path)."""
    path = Path(name)
    if path.suffix == ".toml":
        return path.resolve()
    import utility_specs

    return Path(utility_specs.__file__).resolve().parent / "missions" / f"{name}.toml"


def free_port(kind: int = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A port the kernel considers free right now (bind to 0, read it, release it).

    There is a short race until the user binds it; the launcher checks that every process
    came up and fails loudly otherwise.
    """
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def write_fleet_key(path: Path) -> bytes:
    """A fresh random fleet key (32 bytes, base64 text) in a new file created with 0600."""
    key = base64.b64encode(secrets.token_bytes(32))
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(key + b"\n")
    return key


def toml_value(value: Any) -> str:
    """One TOML value: strings, booleans, finite numbers, lists and inline tables."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"TOML cannot hold {value!r}")
        return repr(value)
    if isinstance(value, str | Path):
        return json.dumps(str(value))  # a JSON string is a valid TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {type(value).__name__}: {value!r}")


def _toml(tables: Mapping[str, Mapping[str, Any]], header: str) -> str:
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    for name, table in tables.items():
        lines.append("")
        lines.append(f"[{name}]")
        lines.extend(f"{key} = {toml_value(value)}" for key, value in table.items())
    return "\n".join(lines) + "\n"


@dataclass(frozen=True, slots=True, kw_only=True)
class DroneSlot:
    """One simulated drone: its vehicle, its companion and their files."""

    index: int
    drone_id: str
    system_id: int
    mavlink_port: int
    """Where the companion listens for its vehicle (the vehicle's ``--out``)."""
    folder: Path
    mavlink_host: str | None = None
    """The companion's address toward its vehicle when it differs per drone (``--netns``:
    the drone namespace's end of its autopilot link); None: the plan's ``drone_bind_host``."""

    @property
    def config_path(self) -> Path:
        return self.folder / "companion.toml"

    @property
    def log_path(self) -> Path:
        return self.folder / "mission_log.jsonl"


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetPlan:
    """Everything the launcher decided before starting a process (ports, files, budgets)."""

    run_dir: Path
    drones: tuple[DroneSlot, ...]
    scene: str
    """Scene name (``demo``) or an absolute path to a scene TOML."""
    spec_path: Path
    gs_udp_port: int
    gs_http_port: int
    gs_host: str = "127.0.0.1"
    """Where companions send (the receiver namespace's address with ``--netns``)."""
    relay_port: int | None = None
    """The shaped relay's port on ``gs_host`` (:mod:`sitl.relay_udp`): companions send
    there and it forwards to ``gs_udp_port``; None: straight to the station."""
    gs_bind_host: str = "127.0.0.1"
    """Where the station's UDP socket binds (its HTTP API is always on 127.0.0.1)."""
    drone_bind_host: str = "127.0.0.1"
    """Where vehicles bind and companions talk MAVLink unless a drone has its own
    ``mavlink_host`` (``--netns``: vehicles bind ``0.0.0.0`` in the vehicles namespace)."""
    drone_listen_host: str = "127.0.0.1"
    """Where companions receive reports and commands (``0.0.0.0`` across namespaces)."""
    mission: str = "fleet"
    fleet_id: int = 1
    camera_rate_hz: float = 5.0
    camera_width: int = 640
    camera_height: int = 480
    jpeg_quality: int = 80
    mcts_iterations: int = 300
    time_budget_s: float = 0.05
    constraint: str = "constant"
    constraint_params: Mapping[str, Any] = field(default_factory=dict)
    alpha: float | None = None
    seed: int = 0
    policy: str = "mcts"
    """The companions' ``[middleware] policy`` (``random_drop``: any version, status kept)."""
    drop_probability: float = 0.5
    fleet_share: bool = True
    """mcts: write ``[middleware] fleet_size`` = the number of drones (the share of the
    budget at the mission start, issue 18): measured on the demo fleet, the first seconds'
    full frames no longer overflow the relay's queue (docs/middleware.md, round 7)."""
    price_rate_s: float | None = None
    """mcts: write ``[middleware] price_rate_s`` (the relay fleet's: the price counts the
    other drones' frames they are expected to send, docs/adaptive.md); None: not written."""
    peers_medium: str | None = None
    """the shared medium of ``--peers`` (sitl.fleet_peers); None: unicast."""
    link_rate_bytes_per_s: float = 0.0
    """The ``--netns`` link's rate, written to every companion, which paces each message's
    datagrams at it (0: none written, unpaced; the relay fleet, docs/protocol.md)."""
    peers_http_ports: Mapping[str, int] = field(default_factory=dict)
    """drone id -> its companion's ``GET /peers`` port."""

    @property
    def key_path(self) -> Path:
        return self.run_dir / "fleet.key"

    @property
    def command_key_path(self) -> Path:
        return self.run_dir / "command.key"

    @property
    def command_pub_path(self) -> Path:
        return self.run_dir / "command.pub"

    @property
    def gs_config_path(self) -> Path:
        return self.run_dir / "ground_station.toml"

    @property
    def gs_data_dir(self) -> Path:
        return self.run_dir / "gs-data"

    @property
    def gs_log_path(self) -> Path:
        """The ground station's mission log (``DATA_DIR/missions/MISSION/mission_log.jsonl``)."""
        return self.gs_data_dir / "missions" / self.mission / "mission_log.jsonl"

    @property
    def gs_db_path(self) -> Path:
        return self.gs_data_dir / "ground_station.sqlite3"

    @property
    def logs_dir(self) -> Path:
        return self.run_dir / "logs"


def mavlink_host(plan: FleetPlan, drone: DroneSlot) -> str:
    """Where ``drone``'s companion listens for its vehicle (and the vehicle sends to)."""
    return drone.mavlink_host or plan.drone_bind_host


def companion_toml(plan: FleetPlan, drone: DroneSlot) -> str:
    """The ``uav-companion`` configuration of one simulated drone."""
    tables: dict[str, dict[str, Any]] = {
        "drone": {"id": drone.drone_id},
        "mavlink": {
            "url": f"udpin:{mavlink_host(plan, drone)}:{drone.mavlink_port}",
            "source_system": drone.system_id,
        },
        "camera": {
            "source": "synthetic",
            "width": plan.camera_width,
            "height": plan.camera_height,
            "rate_hz": plan.camera_rate_hz,
            "jpeg_quality": plan.jpeg_quality,
            "options": {"scene": plan.scene, "seed": plan.seed + drone.index},
        },
        "scoring": {"scorers": ["red_share"]},
        # data from the station's start on, which the launcher sends (retried until
        # acknowledged): the fleet's start share then counts from it (Middleware.mission_started)
        "mission": {"spec": str(plan.spec_path), "log": str(drone.log_path),
                    "wait_for_start": True},
        "ground_station": {
            "host": plan.gs_host,
            "port": plan.relay_port if plan.relay_port is not None else plan.gs_udp_port,
            "fleet_id": plan.fleet_id,
            "fleet_key_file": str(plan.key_path),
            "command_public_key_file": str(plan.command_pub_path),
            "listen_host": plan.drone_listen_host,
            "listen_port": 0,
        } | ({"link_rate_bytes_per_s": plan.link_rate_bytes_per_s}
             if plan.link_rate_bytes_per_s > 0 else {}),
        # the heartbeat: a status every second whatever the optimiser drops (the station
        # flags a drone lost after ``link_lost_s`` of silence)
        "telemetry": {"status_period_s": STATUS_PERIOD_S},
        "budgets": {"mcts_iterations": plan.mcts_iterations,
                    "time_budget_s": plan.time_budget_s},
        "constraint": {"name": plan.constraint, "params": dict(plan.constraint_params)},
        "middleware": {"seed": plan.seed + drone.index}
        | ({"alpha": plan.alpha} if plan.alpha is not None else {})
        | ({"policy": plan.policy} if plan.policy != "mcts" else {})
        | ({"fleet_size": len(plan.drones)} if plan.fleet_share and plan.policy == "mcts"
           else {})
        | ({"price_rate_s": plan.price_rate_s} if plan.price_rate_s is not None
           and plan.policy == "mcts" else {})
        | ({"drop_probability": plan.drop_probability, "any_version": True}
           if plan.policy == "random_drop" else {}),
    }
    if plan.peers_medium is not None:
        from sitl.fleet_peers import companion_peers_table

        tables["peers"] = companion_peers_table(plan.peers_medium,
                                                plan.peers_http_ports[drone.drone_id])
    return _toml(tables, f"uav-companion config of {drone.drone_id}, written by uav-sitl fleet")


def ground_station_toml(plan: FleetPlan) -> str:
    """The ``uav-ground-station`` configuration of the run."""
    from sitl.scenes import scene_path

    table: dict[str, Any] = {
        "station_id": "gs",
        "fleet_id": plan.fleet_id,
        "fleet_key_file": str(plan.key_path),
        "command_key_file": str(plan.command_key_path),
        "data_dir": str(plan.gs_data_dir),
        "mission": plan.mission,
        "udp_host": plan.gs_bind_host,
        "udp_port": plan.gs_udp_port,
        "http_host": "127.0.0.1",
        "http_port": plan.gs_http_port,
        "spec": str(plan.spec_path),
        "scene": str(scene_path(plan.scene).resolve()),  # the dashboard map draws it
        "link_lost_s": LINK_LOST_S,
    }
    if plan.alpha is not None:
        table["alpha"] = plan.alpha
    if plan.peers_medium is not None:
        table["shared_medium"] = plan.peers_medium
    return _toml({"ground_station": table}, "uav-ground-station config, written by uav-sitl fleet")


def write_run_configs(plan: FleetPlan) -> None:
    """Create the run folder: fresh keys (0600), the station's and every drone's config."""
    from ground_station.keyfiles import generate_keys

    plan.run_dir.mkdir(parents=True, exist_ok=True)
    plan.logs_dir.mkdir(exist_ok=True)
    generate_keys(plan.run_dir, replace=True)
    plan.gs_config_path.write_text(ground_station_toml(plan), encoding="utf-8")
    for drone in plan.drones:
        drone.folder.mkdir(parents=True, exist_ok=True)
        drone.config_path.write_text(companion_toml(plan, drone), encoding="utf-8")
