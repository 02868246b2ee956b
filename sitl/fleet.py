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

The launcher is a thin synchronous shell: processes, files and HTTP polls. The numbers come
from the mission logs (``utility_specs.log`` records) and the ground station's own database.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from sitl.fleet_config import (
    DroneSlot,
    FleetPlan,
    free_port,
    mavlink_host,
    mission_spec_path,
    write_run_configs,
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

POLICIES = ("mcts", "random", "send_all")
COMPANION_POLICY = {"mcts": "mcts", "random": "random_drop", "send_all": "send_all"}
"""``--policy`` -> the companion's ``[middleware] policy``."""
"""``mcts``: the companion's middleware (ch. 5); ``random``: drop each message with
``--drop-probability`` (the baseline of thesis fig. 5.7); ``send_all``: no optimisation."""
WIFI_G_RATE_BIT_S = 6_000_000.0
"""``--netns`` default link rate: what 802.11g delivers to UDP in practice with several
stations contending (well below its 54 Mbit/s PHY rate)."""
WIFI_G_DELAY_MS = 2.0
"""``--netns`` default one-way delay per crossing of the medium (802.11g channel access and
air time of a frame, a few ms); applied only where the kernel has netem."""
WIFI_G_LOSS_PERCENT = 0.1
"""``--netns`` default residual loss per datagram after 802.11 MAC retransmissions."""


RELAY_RATE_BIT_S = 400_000.0
"""Default rate of the shaped relay (no root): a narrow radio, so four camera streams must
share it and the adaptive constraint has something to adapt to (at 800 kbit/s the drones' ξ
hardly binds and drone3's share over the red was only 1.3x the others', at 400 kbit/s 1.8x)."""
RELAY_QUEUE_BYTES = 20_000
"""The relay's queue: 0.4 s at the default rate, like a radio modem's buffer."""
RELAY_BACKGROUND_SHARE = 0.4
"""Default background step on the relay: this share of its rate from mid-mission."""


class FleetError(RuntimeError):
    """The fleet could not be brought up (the text says which process and why)."""


# -- command lines -----------------------------------------------------------------------------


def _tool(script: str, module: str) -> list[str]:
    """The console script next to this interpreter, else ``python -m module``."""
    path = Path(sys.executable).parent / script
    return [str(path)] if path.exists() else [sys.executable, "-m", module]


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="uav-sitl fleet",
        description="Run N simulated drones (vehicle + synthetic camera + uav-companion) and a "
                    "uav-ground-station on one machine; print a summary at the end.")
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
    p.add_argument("--constraint", choices=("constant", "adaptive", "aimd"), default=None,
                   help="goodput constraint (default: constant on loopback, adaptive with "
                        "--netns)")
    p.add_argument("--goodput", type=float, default=None,
                   help="constant constraint: fleet goodput limit in bytes/s (default 40000; "
                        "given alone, it selects the constant constraint)")
    p.add_argument("--window", type=float, default=2.0,
                   help="constant constraint: window T in s (default 2)")
    p.add_argument("--rate", type=float, default=5.0, help="camera frames/s per drone")
    p.add_argument("--size", default="640x480", help="camera frame size WxH (default 640x480)")
    p.add_argument("--mcts-iterations", type=int, default=300)
    p.add_argument("--time-budget", type=float, default=0.05,
                   help="wall time per middleware decision in s (default 0.05)")
    p.add_argument("--alpha", type=float, default=None, help="α of eq. 7.1 (default: spec's)")
    p.add_argument("--spec", default="image_streaming", help="mission spec name or TOML path")
    p.add_argument("--speedup", type=float, default=1.0, help="vehicle simulation speed-up")
    p.add_argument("--flavour", choices=("px4", "ardupilot"), default="px4")
    p.add_argument("--first-fix", type=float, default=2.0, metavar="S",
                   help="vehicle seconds from boot to a GPS fix; until then no position and"
                        " no arming, as on a real autopilot (default 2; `uav-sitl vehicle`"
                        " defaults to an ArduCopter-like 15)")
    p.add_argument("--pattern", choices=("survey", "orbit"), default="survey")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--ready-timeout", type=float, default=90.0,
                   help="seconds to wait for every drone to be heard (default 90)")
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
    p.add_argument("--peers", action="store_true",
                   help="peer sharing (docs/peers.md): a loopback broadcast medium, each "
                        "drone's peers in its autopilot (ADSB_VEHICLE) and at GET /peers; "
                        "use a spec with receivers = [\"peers\"] (--spec peer_sharing)")
    args = p.parse_args(list(argv))
    if args.peers and args.netns:
        p.error("--peers runs on loopback; it does not combine with --netns yet")
    if not 1 <= args.drones <= 64:
        p.error("--drones must be in 1..64")
    if args.duration < 0:
        p.error("--duration must be >= 0")
    if not 0.0 <= args.first_fix < 1e6:
        p.error("--first-fix must be a number of seconds >= 0")
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
    if args.constraint is None:
        shaped = args.netns or args.relay
        args.constraint = "adaptive" if shaped and args.goodput is None else "constant"
    if args.goodput is None:
        args.goodput = 40_000.0
    return args


@dataclass(frozen=True, slots=True)
class Background:
    """iperf3 background traffic: ``rate_bit_s`` from ``start_s`` after the mission start."""

    rate_bit_s: float
    start_s: float = 0.0
    duration_s: float | None = None


def parse_background(text: str) -> Background:
    """``2e6``, ``2e6@20`` (from 20 s) or ``2e6@20+15`` (from 20 s for 15 s)."""
    rate, _, when = text.partition("@")
    start, _, length = when.partition("+")
    try:
        bg = Background(float(rate), float(start) if start else 0.0,
                        float(length) if length else None)
    except ValueError:
        raise ValueError(f"expected BITS[@START_S[+DURATION_S]], got {text!r}") from None
    if bg.rate_bit_s <= 0 or bg.start_s < 0 or (bg.duration_s is not None
                                                  and bg.duration_s <= 0):
        raise ValueError(f"rates and durations must be > 0, got {text!r}")
    return bg


# -- processes ---------------------------------------------------------------------------------


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM us if the launcher dies (Linux PR_SET_PDEATHSIG)."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)


@dataclass(slots=True)
class Child:
    name: str
    proc: subprocess.Popen[bytes]
    log_path: Path
    log: IO[bytes]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def tail(self, n_bytes: int = 2000) -> str:
        with contextlib.suppress(OSError):
            self.log.flush()
            data = self.log_path.read_bytes()[-n_bytes:]
            return data.decode("utf-8", "replace")
        return ""


@dataclass(slots=True)
class Processes:
    """Every child of the launcher, each in its own session (process group)."""

    logs_dir: Path
    children: list[Child] = field(default_factory=list)

    def start(self, name: str, argv: Sequence[str], *, env: dict[str, str] | None = None
              ) -> Child:
        log_path = self.logs_dir / f"{name}.log"
        log = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        try:
            proc = subprocess.Popen(list(argv), stdin=subprocess.DEVNULL, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True,
                                    preexec_fn=_die_with_parent, env=env)
        except OSError as exc:
            log.close()
            raise FleetError(f"{name}: cannot start {argv[0]}: {exc}") from None
        child = Child(name, proc, log_path, log)
        self.children.append(child)
        return child

    def stop(self, children: Iterable[Child], *, timeout_s: float = 10.0) -> None:
        """SIGTERM each child's process group, wait up to ``timeout_s``, then SIGKILL."""
        children = list(children)
        for child in children:
            _signal_group(child.proc, signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for child in children:
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        for child in children:
            _signal_group(child.proc, signal.SIGKILL)  # stragglers and their children
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.proc.wait(timeout=5.0)
            child.log.close()

    def stop_all(self, *, timeout_s: float = 10.0) -> None:
        self.stop(self.children, timeout_s=timeout_s)


def _signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)  # pgid == pid: start_new_session=True


# -- the ground station's API ------------------------------------------------------------------


@dataclass(slots=True)
class GroundStationApi:
    base_url: str
    token: str
    opener: Callable[..., Any] = urllib.request.urlopen

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None,
              timeout_s: float = 3.0) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            self.base_url + path, data=data, method=method,
            headers={"Authorization": f"Bearer {self.token}",
                     "Content-Type": "application/json"})
        with self.opener(request, timeout=timeout_s) as response:
            return json.loads(response.read().decode())

    def get(self, path: str) -> Any:
        return self._call("GET", path)

    def post(self, path: str, body: dict[str, Any]) -> Any:
        return self._call("POST", path, body)


# -- live counters from the companions' mission logs -------------------------------------------



def _new_lines(path: Path, offset: int) -> tuple[list[bytes], int]:
    """Whole lines appended to a growing log since ``offset``, and the offset after them."""
    try:
        with path.open("rb") as f:
            f.seek(offset)
            chunk = f.read()
    except OSError:
        return [], offset
    end = chunk.rfind(b"\n") + 1
    return chunk[:end].splitlines(), offset + end

@dataclass(slots=True)
class LogTail:
    """Counts image records of a growing companion log (complete lines only)."""

    path: Path
    generated: int = 0
    sent: int = 0
    _offset: int = 0

    def poll(self) -> None:
        lines, self._offset = _new_lines(self.path, self._offset)
        for line in lines:
            if b'"type":"image"' not in line:
                continue
            self.generated += 1
            if b'"t_sent":null' not in line:
                self.sent += 1


@dataclass(slots=True)
class StationTail:
    """Per sender, images the station logged as received, and their recent arrivals."""

    path: Path
    window_s: float = 5.0
    received: dict[str, int] = field(default_factory=dict)
    recent: dict[str, deque[tuple[float, float]]] = field(default_factory=dict)
    """sender -> (t_rcv, latency) of the images of the last ``window_s``."""
    _offset: int = 0

    def poll(self) -> None:
        lines, self._offset = _new_lines(self.path, self._offset)
        for line in lines:
            if b'"type": "image"' not in line and b'"type":"image"' not in line:
                continue
            with contextlib.suppress(ValueError, KeyError, TypeError):
                r = json.loads(line)
                if r.get("type") != "image" or r.get("t_rcv") is None:
                    continue
                sender = str(r["sender"])
                self.received[sender] = self.received.get(sender, 0) + 1
                self.recent.setdefault(sender, deque()).append(
                    (float(r["t_rcv"]), float(r["t_rcv"]) - float(r["t_gen"])))

    def rate(self, sender: str, now: float) -> tuple[float, float | None]:
        """Images/s received over the last ``window_s`` and their mean latency (s)."""
        q = self.recent.get(sender, deque())
        while q and q[0][0] < now - self.window_s:
            q.popleft()
        latency = sum(x for _, x in q) / len(q) if q else None
        return len(q) / self.window_s, latency


def progress_line(elapsed_s: float, drones: Sequence[DroneSlot], tails: dict[str, LogTail],
                  station: StationTail, now: float) -> str:
    """``[  12 s] drone1 g60 s20 r19 3.8/s 41ms | ...``: images generated, sent (companion
    log), received (station log), received frame rate and latency over the last seconds."""
    parts = []
    for slot in drones:
        tail = tails[slot.drone_id]
        fps, latency = station.rate(slot.drone_id, now)
        lat = "-" if latency is None else f"{1000 * latency:.0f}ms"
        parts.append(f"{slot.drone_id} g{tail.generated} s{tail.sent} "
                     f"r{station.received.get(slot.drone_id, 0)} {fps:.1f}/s {lat}")
    return f"[{elapsed_s:5.0f} s] " + " | ".join(parts)


# -- summary -----------------------------------------------------------------------------------


def _records(path: Path) -> list[dict[str, Any]]:
    out = []
    with contextlib.suppress(OSError), path.open(encoding="utf-8") as f:
        for line in f:
            with contextlib.suppress(json.JSONDecodeError):
                record = json.loads(line)
                if isinstance(record, dict) and "sender" in record:
                    out.append(record)
    return out


def _stored_images(db_path: Path, mission: str, t_start: float, t_end: float
                   ) -> dict[str, dict[str, int]]:
    """Per sender: image rows of the mission, rows generated in [t_start, t_end], and how many
    rows have their file on disk."""
    out: dict[str, dict[str, int]] = {}
    if not db_path.exists():
        return out
    con = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=10.0)
    try:
        # type = 'image': the station also files telemetry payloads in this table.
        rows = con.execute(
            "SELECT sender, path, t_gen FROM images WHERE mission = ? AND type = 'image'",
            (mission,))
        for sender, path, t_gen in rows:
            entry = out.setdefault(sender, {"rows": 0, "in_window": 0, "files": 0})
            entry["rows"] += 1
            entry["in_window"] += t_start <= t_gen <= t_end
            if path and (db_path.parent / path).is_file():  # relative to the data dir, or absolute
                entry["files"] += 1
    finally:
        con.close()
    return out


def _best_size(record: dict[str, Any]) -> int:
    """Bytes of a message in its best version (what sending everything would cost)."""
    versions = record.get("versions") or []
    return int(versions[0]["size"]) if versions else int(record.get("size", 0))


def _mean_size(record: dict[str, Any]) -> float:
    """Mean bytes over a message's versions (what a uniformly random version costs)."""
    versions = record.get("versions") or []
    if not versions:
        return float(record.get("size", 0))
    return sum(int(v["size"]) for v in versions) / len(versions)


def evaluate_utility(logs: Sequence[Path], *, spec: Path, t_start: float, t_end: float
                     ) -> dict[str, Any]:
    """The fleet's total utility (eq. 4.1/4.2) by ``uav-utility evaluate`` on merged logs."""
    argv = [*_tool("uav-utility", "utility_specs.cli"), "evaluate", *map(str, logs),
            "--spec", str(spec), "--json", "--ignore-unknown-types",
            "--t-start", repr(t_start), "--t-end", repr(t_end)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    if proc.returncode != 0:
        return {"error": (proc.stderr or proc.stdout).strip()[-2000:], "command": argv}
    result: dict[str, Any] = json.loads(proc.stdout)
    result["command"] = " ".join(argv)
    return result


def summarize(plan: FleetPlan, *, t_start: float, t_end: float, policy: str,
              utility: dict[str, Any] | None = None) -> dict[str, Any]:
    """Per drone: images generated/sent (companion log), received (station log), stored
    (station database + files), mean received frame rate and latency in the mission window."""
    window = max(t_end - t_start, 1e-9)
    first_copies: dict[str, dict[int, dict[str, Any]]] = {}
    image_bytes: dict[str, int] = {}  # every copy in the window: air time, not images
    bytes_received = 0
    for r in _records(plan.gs_log_path):
        if r.get("t_rcv") is None:
            continue
        in_window = t_start <= r["t_gen"] <= t_end
        if in_window:
            bytes_received += int(r.get("size", 0))
        if r.get("type") == "image":
            if in_window:
                image_bytes[r["sender"]] = image_bytes.get(r["sender"], 0) + int(r.get("size", 0))
            # an image counts once however many of its versions arrived (first copy's latency)
            seen = first_copies.setdefault(r["sender"], {})
            if r["seq"] not in seen or r["t_rcv"] < seen[r["seq"]]["t_rcv"]:
                seen[r["seq"]] = r
    received = {sender: list(copies.values()) for sender, copies in first_copies.items()}
    copies: list[tuple[str, float, int]] = [
        (str(r["sender"]), float(r["t_gen"]), int(r.get("size", 0)))
        for r in _records(plan.gs_log_path)
        if r.get("type") == "image" and r.get("t_rcv") is not None]
    seen: dict[str, list[tuple[float, float]]] = {}
    bytes_generated = 0
    bytes_generated_mean = 0.0
    stored = _stored_images(plan.gs_db_path, plan.mission, t_start, t_end)
    drones: dict[str, Any] = {}
    for slot in plan.drones:
        records = [r for r in _records(slot.log_path) if t_start <= r["t_gen"] <= t_end]
        bytes_generated += sum(_best_size(r) for r in records)
        bytes_generated_mean += sum(_mean_size(r) for r in records)
        in_window = [r for r in records if r.get("type") == "image"]
        seen[slot.drone_id] = [(float(r["t_gen"]), float(r["data"].get("red") or 0.0))
                               for r in in_window if isinstance(r.get("data"), dict)]
        sent = [r for r in in_window if r.get("t_sent") is not None]
        got_all = received.get(slot.drone_id, [])
        got = [r for r in got_all if t_start <= r["t_gen"] <= t_end]
        latencies = sorted(r["t_rcv"] - r["t_gen"] for r in got)
        reasons = [str(r["decision"].get("reason", "")) for r in records
                   if isinstance(r.get("decision"), dict)]
        fallbacks = sum(x.startswith("fallback") or x == "decision timeout" for x in reasons)
        drones[slot.drone_id] = {
            "generated": len(in_window),
            "sent": len(sent),
            "received": len(got),
            "received_total": len(got_all),
            "stored": stored.get(slot.drone_id, {}).get("in_window", 0),
            "stored_total": stored.get(slot.drone_id, {}).get("rows", 0),
            "stored_files": stored.get(slot.drone_id, {}).get("files", 0),
            "bytes_received": image_bytes.get(slot.drone_id, 0),
            "fps_generated": len(in_window) / window,
            "fps": len(got) / window,
            "latency_mean_s": sum(latencies) / len(latencies) if latencies else None,
            "latency_p95_s": latencies[min(len(latencies) - 1, int(0.95 * len(latencies)))]
            if latencies else None,
            "decisions": len(reasons),
            "fallback_share": fallbacks / len(reasons) if reasons else None,
            "mean_red": (sum(float(r["data"].get("red") or 0.0) for r in in_window)
                         / len(in_window)) if in_window else None,
            "log": str(slot.log_path),
        }
    total_bytes = sum(image_bytes.values())
    return {
        "policy": policy,
        "t_start": t_start,
        "t_end": t_end,
        "duration_s": window,
        "drones": drones,
        "image_bytes_received": total_bytes,
        "bytes_received": bytes_received,
        "bytes_generated": bytes_generated,
        "bytes_generated_mean_version": bytes_generated_mean,
        "utility": utility,
        "phases": red_phases(seen, copies, t_start=t_start, t_end=t_end),
        "run_dir": str(plan.run_dir),
        "data": {
            "ground_station_db": str(plan.gs_db_path),
            "ground_station_log": str(plan.gs_log_path),
            "images": str(plan.gs_data_dir / "missions" / plan.mission / "images"),
            "companion_logs": [str(s.log_path) for s in plan.drones],
            "process_logs": str(plan.logs_dir),
        },
    }


RED_SEEN = 0.02
"""A drone "sees red" in a phase bin when its frames there average at least this red share
(the red objects fill a few % of a frame; fields and trees stay well below 1 %)."""
PHASE_BIN_S = 5.0


def red_phases(seen: dict[str, list[tuple[float, float]]],
               received: Sequence[tuple[str, float, int]], *, t_start: float, t_end: float,
               bin_s: float = PHASE_BIN_S, red_seen: float = RED_SEEN) -> dict[str, Any]:
    """Per drone, its share of the image bytes that reached the station while it saw red
    and while it did not, against the mean share of the other drones in the same bins.

    ``seen``: per drone, (t_gen, red) of the frames it generated; ``received``: (sender,
    t_gen, bytes) of every image copy the station received. Bins of ``bin_s`` by t_gen.
    """
    n_bins = max(1, math.ceil((t_end - t_start) / bin_s))
    drones = list(seen)

    def index(t: float) -> int | None:
        i = int((t - t_start) // bin_s)
        return i if 0 <= i < n_bins else None

    red: dict[str, list[list[float]]] = {d: [[] for _ in range(n_bins)] for d in drones}
    for d, frames in seen.items():
        for t, r in frames:
            i = index(t)
            if i is not None:
                red[d][i].append(r)
    got = {d: [0] * n_bins for d in drones}
    for sender, t, size in received:
        i = index(t)
        if i is not None and sender in got:
            got[sender][i] += size
    totals = [sum(got[d][i] for d in drones) for i in range(n_bins)]
    out: dict[str, Any] = {"bin_s": bin_s, "red_seen": red_seen, "drones": {}}
    for d in drones:
        others = [o for o in drones if o != d]
        phases: dict[str, Any] = {}
        for phase, wanted in (("red", True), ("plain", False)):
            bins = [i for i in range(n_bins) if totals[i] > 0 and red[d][i]
                    and (sum(red[d][i]) / len(red[d][i]) >= red_seen) == wanted]
            if not bins:
                phases[phase] = None
                continue
            own = sum(got[d][i] / totals[i] for i in bins) / len(bins)
            rest = (sum(got[o][i] / totals[i] for i in bins for o in others)
                    / (len(bins) * len(others))) if others else None
            phases[phase] = {"seconds": len(bins) * bin_s, "share": own,
                             "others_mean_share": rest,
                             "ratio": own / rest if rest else None}
        out["drones"][d] = phases
    return out


def format_phases(phases: dict[str, Any]) -> list[str]:
    """``drone3 over red 35 s: share 48 % vs others' mean 17 % (2.8x); ...``"""
    lines = [f"goodput share per phase ({phases['bin_s']:g} s bins; over red: frames with "
             f">= {100 * phases['red_seen']:g} % red)"]
    for d, p in phases["drones"].items():
        parts = []
        for phase, label in (("red", "over red"), ("plain", "elsewhere")):
            x = p.get(phase)
            if x is None:
                parts.append(f"{label} -")
                continue
            ratio = "" if x["ratio"] is None else f" ({x['ratio']:.1f}x)"
            rest = ("" if x["others_mean_share"] is None
                    else f" vs others' mean {100 * x['others_mean_share']:.0f} %")
            parts.append(f"{label} {x['seconds']:.0f} s: share {100 * x['share']:.0f} %"
                         f"{rest}{ratio}")
        lines.append(f"  {d:<8} " + "; ".join(parts))
    return lines


def format_summary(summary: dict[str, Any]) -> str:
    lines = [f"fleet summary ({summary['policy']}, {summary['duration_s']:.1f} s of mission)",
             f"{'drone':<10} {'generated':>9} {'sent':>6} {'received':>8} {'stored':>6} "
             f"{'fps':>6} {'latency':>9} {'red':>6} {'fallback':>8}"]
    for name, d in summary["drones"].items():
        lat = "-" if d["latency_mean_s"] is None else f"{1000 * d['latency_mean_s']:.0f} ms"
        red = "-" if d["mean_red"] is None else f"{d['mean_red']:.3f}"
        share = d.get("fallback_share")
        fallback = "-" if share is None else f"{100 * share:.1f} %"
        lines.append(f"{name:<10} {d['generated']:>9} {d['sent']:>6} {d['received']:>8} "
                     f"{d['stored']:>6} {d['fps']:>6.2f} {lat:>9} {red:>6} {fallback:>8}")
    utility = summary.get("utility") or {}
    if "total" in utility:
        per_type = ", ".join(f"{k} {v:.2f}" for k, v in utility.get("per_type", {}).items())
        lines.append(f"total utility {utility['total']:.3f} ({per_type})")
    elif utility:
        lines.append(f"utility: not evaluated: {utility.get('error')}")
    if summary.get("phases"):
        lines.extend(format_phases(summary["phases"]))
    constraint = summary.get("constraint")
    if constraint:
        lines.append(f"constraint: {constraint.get('name')}")
    link = summary.get("link")
    if link:
        lines.append(f"link: {link['description']}")
        counters = link.get("bottleneck") or {}
        if counters:
            lines.append(f"  bottleneck sent {counters['sent_bytes']} B in "
                         f"{counters['sent_packets']} packets, dropped {counters['dropped']}")
    if summary.get("peers") is not None:
        from sitl.fleet_peers import format_peers
        lines.extend(format_peers(summary["peers"], list(summary["drones"]),
                                  summary.get("peers_age_bound_s")))
    data = summary["data"]
    lines.append(f"data: {summary['run_dir']}")
    if summary.get("report"):
        lines.append(f"  report   {summary['report']} (and {summary.get('dashboard', '')}"
                     "report while the station runs)")
    lines.append(f"  images   {data['images']}")
    lines.append(f"  database {data['ground_station_db']}")
    lines.append(f"  logs     {data['ground_station_log']} + drones/*/mission_log.jsonl")
    return "\n".join(lines)


# -- network namespaces (--netns) --------------------------------------------------------------

CLONE_NEWNET = 0x40000000


def _enter_netns(name: str) -> None:
    """Move the calling thread (only) into network namespace ``name`` (setns(2))."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(f"/var/run/netns/{name}", os.O_RDONLY)
    try:
        if libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns({name}): {os.strerror(err)}")
    finally:
        os.close(fd)


class _NsForwarder:
    """TCP 127.0.0.1:port here -> 127.0.0.1:port inside a namespace (the dashboard and API).

    Each connection is served by a thread that first enters the namespace, so the socket it
    opens lives there; the accepted socket stays in ours.
    """

    def __init__(self, ns: str, target_port: int) -> None:
        import threading

        self.ns = ns
        self.target_port = target_port
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind(("127.0.0.1", target_port))
        except OSError:
            self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(16)
        self.port = int(self.listener.getsockname()[1])
        self._closed = False
        threading.Thread(target=self._accept, name="ns-forward", daemon=True).start()

    def _accept(self) -> None:
        import threading

        while not self._closed:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._pipe, args=(conn,), daemon=True).start()

    def _pipe(self, conn: socket.socket) -> None:
        import select

        try:
            _enter_netns(self.ns)
            upstream = socket.create_connection(("127.0.0.1", self.target_port), timeout=5)
        except OSError:
            conn.close()
            return
        with conn, upstream:
            pair = {conn: upstream, upstream: conn}
            while not self._closed:
                readable, _, _ = select.select(list(pair), [], [], 1.0)
                for sock in readable:
                    data = sock.recv(65536)
                    if not data:
                        return
                    pair[sock].sendall(data)

    def close(self) -> None:
        self._closed = True
        self.listener.close()


class FleetNetns:
    """``--netns``: each drone's companion in its own namespace, the ground station in
    another, all on the shaped bridge of :class:`sitl.linkemu.SharedMedium` (``tc tbf`` rate
    and queue once, toward the station: the drones contend like stations on one radio
    channel; netem delay/loss where the kernel has it). The vehicles share a namespace, each
    reached from its drone over an unshaped veth. Optional ``iperf3`` background traffic from
    another host on the medium, on at a given time (thesis fig. 7.4).
    """

    def __init__(self, *, drones: int, rate_bit_s: float, delay_s: float = 0.0,
                 loss: float = 0.0) -> None:
        from sitl.linkemu import SharedMedium

        self.medium = SharedMedium(drones=drones, rate_bit_per_s=rate_bit_s, delay_s=delay_s,
                                   loss=loss,
                                   queue_limit_bytes=max(15_000, int(rate_bit_s / 8 * 0.05)))
        self._forwarder: _NsForwarder | None = None
        self._background: Any = None
        self._plan: tuple[Background, float] | None = None
        self._bg_on = False

    def open(self) -> None:
        from sitl.linkemu import LinkEmuError, cleanup_stale

        cleanup_stale()
        try:
            self.medium.open()  # removes what it built if it fails half-way
        except LinkEmuError as exc:
            raise FleetError(f"--netns: cannot build the shared link: {exc}") from None

    def wrap_drone(self, index: int, argv: Sequence[str]) -> list[str]:
        return self.medium.wrap(self.medium.ns_drones[index], argv)

    def wrap_vehicles(self, argv: Sequence[str]) -> list[str]:
        assert self.medium.ns_vehicles is not None
        return self.medium.wrap(self.medium.ns_vehicles, argv)

    def wrap_gs(self, argv: Sequence[str]) -> list[str]:
        return self.medium.wrap(self.medium.ns_ground, argv)

    def forward_http(self, port: int) -> str:
        self._forwarder = _NsForwarder(self.medium.ns_ground, port)
        return f"http://127.0.0.1:{self._forwarder.port}"

    def schedule_background(self, background: Background, t_start: float) -> None:
        from sitl.linkemu import Iperf3Background

        self._background = Iperf3Background(self.medium)
        self._background.start_server()
        self._plan = (background, t_start)

    def tick(self, now: float) -> None:
        """Switch the background traffic on/off at its times (called about once a second)."""
        if self._plan is None or self._background is None:
            return
        bg, t_start = self._plan
        t_on = t_start + bg.start_s
        t_off = math.inf if bg.duration_s is None else t_on + bg.duration_s
        if not self._bg_on and t_on <= now < t_off:
            self._background.start(rate_bit_per_s=bg.rate_bit_s,
                                   duration_s=min(t_off - now, 24 * 3600.0))
            self._bg_on = True
        elif self._bg_on and now >= t_off:
            self._background.stop()
            self._plan = None

    def describe(self) -> dict[str, Any]:
        """The link of the run for the summary: namespaces, shaping, what netem did, and the
        bottleneck's counters (call before :meth:`close`)."""
        from sitl.linkemu import LinkEmuError, parse_qdisc_counters

        m = self.medium
        counters = None
        with contextlib.suppress(LinkEmuError, OSError, subprocess.SubprocessError):
            counters = parse_qdisc_counters(m.qdisc_stats())
        return {
            "description": m.describe(),
            "rate_bit_s": m.rate_bit_per_s,
            "queue_limit_bytes": m.queue_limit_bytes,
            "delay_s": m.delay_s,
            "loss": m.loss,
            "netem": m.netem,
            "impairment_note": m.impairment_note,
            "namespaces": {"medium": m.ns_medium, "ground_station": m.ns_ground,
                           "vehicles": m.ns_vehicles, "background": m.ns_background,
                           "drones": list(m.ns_drones)},
            "addresses": {"ground_station": m.ground_addr, "background": m.background_addr,
                          "drones": [m.drone_addr(i) for i in range(m.drones)]},
            "bottleneck": counters,
        }

    def close(self) -> None:
        if self._forwarder is not None:
            self._forwarder.close()
        if self._background is not None:
            self._background.stop()
        self.medium.close()


class _Loopback:
    """The process wrappers of :class:`FleetNetns` for a run on 127.0.0.1: none."""

    def wrap_drone(self, index: int, argv: Sequence[str]) -> list[str]:
        return list(argv)

    def wrap_vehicles(self, argv: Sequence[str]) -> list[str]:
        return list(argv)

    def wrap_gs(self, argv: Sequence[str]) -> list[str]:
        return list(argv)


# -- the run -----------------------------------------------------------------------------------


class _Stop:
    """Set by SIGINT/SIGTERM/SIGHUP; the launcher polls it between short sleeps."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def __call__(self, signum: int, frame: object) -> None:
        self.reason = signal.Signals(signum).name

    def sleep(self, seconds: float) -> bool:
        """Sleep unless stopped; True when a stop was asked."""
        deadline = time.monotonic() + seconds
        while self.reason is None and time.monotonic() < deadline:
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        return self.reason is not None


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
        **_peers_plan(args, drones))


def _peers_plan(args: argparse.Namespace, drones: Sequence[DroneSlot]) -> dict[str, Any]:
    """the medium and /peers ports of ``--peers`` (sitl.fleet_peers)."""
    if not getattr(args, "peers", False):
        return {}
    from sitl.fleet_peers import loopback_medium

    return {"peers_medium": loopback_medium(),
            "peers_http_ports": {d.drone_id: free_port(kind=socket.SOCK_STREAM)
                                 for d in drones}}


def relay_constraint_params(name: str, rate_bytes_per_s: float) -> dict[str, Any]:
    """The adaptive (or AIMD) constraint scaled to the relay's rate: the parameters tuned on
    the 1 Mbit/s kernel link (``sitl.study.adaptive.REAL_LINK_CONSTRAINTS``) in units of the
    link, with a window that holds a few camera frames."""
    params: dict[str, Any] = {"window_s": 1.0, "alpha_bytes_per_s": 0.5 * rate_bytes_per_s,
                              "min_base_latency_s": 0.01,
                              "min_bytes_per_s": 0.05 * rate_bytes_per_s}
    if name == "adaptive":
        params |= {"learning_rate": 0.1, "min_coef": 0.3, "backlog_clip": 2.0,
                   "scale_bytes_per_s": rate_bytes_per_s,
                   "initial_intercept_bytes_per_s": 0.5 * rate_bytes_per_s}
    return params


def relay_description(args: argparse.Namespace) -> str:
    bg = args.background
    load = ("no background load" if bg is None else
            f"background {bg.rate_bit_s / 1e3:g} kbit/s from {bg.start_s:g} s"
            + ("" if bg.duration_s is None else f" for {bg.duration_s:g} s"))
    return (f"shaped UDP relay (user space, sitl.relay): {args.relay_rate / 1e3:g} kbit/s "
            f"token bucket, {args.relay_queue} B queue, {load}")


def _relay_argv(args: argparse.Namespace, plan: FleetPlan, stats: Path) -> list[str]:
    assert plan.relay_port is not None
    argv = [sys.executable, "-m", "sitl.relay_udp",
            "--listen", f"127.0.0.1:{plan.relay_port}", "--to", f"127.0.0.1:{plan.gs_udp_port}",
            "--rate", repr(args.relay_rate / 8.0), "--queue", str(args.relay_queue),
            "--stats", str(stats)]
    bg = args.background
    if bg is not None:
        argv += ["--background", f"{bg.rate_bit_s / 8.0!r}@{bg.start_s!r}"
                 + ("" if bg.duration_s is None else f"+{bg.duration_s!r}")]
    return argv


def _relay_link(args: argparse.Namespace, stats_path: Path) -> dict[str, Any]:
    """The relay's part of the summary: what ran and its counters."""
    stats: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        stats = json.loads(stats_path.read_text(encoding="utf-8"))
    return {"description": relay_description(args), "kind": "relay",
            "rate_bit_s": args.relay_rate, "queue_limit_bytes": args.relay_queue,
            "bottleneck": {"sent_bytes": stats.get("sent_bytes"),
                           "sent_packets": stats.get("sent_packets"),
                           "dropped": stats.get("dropped_packets"),
                           "max_backlog_bytes": stats.get("max_backlog_bytes"),
                           "background_sent_packets": stats.get("background_sent_packets"),
                           "background_dropped_packets":
                               stats.get("background_dropped_packets")} if stats else None}


def _wait(stop: _Stop, what: str, timeout_s: float, ready: Callable[[], bool],
          watch: Sequence[Child]) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        for child in watch:
            if not child.alive():
                raise FleetError(f"{child.name} exited ({child.proc.returncode}) while waiting "
                                 f"for {what}; its log ({child.log_path}) ends with:\n"
                                 f"{child.tail()}")
        if time.monotonic() > deadline:
            raise FleetError(f"timed out after {timeout_s:g} s waiting for {what}")
        if stop.sleep(0.2):
            raise FleetError(f"stopped ({stop.reason}) while waiting for {what}")


def _try(call: Callable[[], Any]) -> Any:
    try:
        return call()
    except (OSError, urllib.error.URLError, ValueError):
        return None


def run(args: argparse.Namespace, *, out: IO[str] = sys.stdout) -> int:
    run_dir = (args.out or Path("out") / "fleet" / time.strftime("%Y%m%d-%H%M%S")).resolve()
    netns = None
    if args.netns:
        netns = FleetNetns(drones=args.drones, rate_bit_s=args.link_rate,
                           delay_s=args.link_delay / 1000.0, loss=args.link_loss / 100.0)
    plan = make_plan(args, run_dir, netns=netns is not None)
    write_run_configs(plan)
    from ground_station.token import ensure_token, login_code

    token, _ = ensure_token(plan.gs_data_dir / "token")
    procs = Processes(plan.logs_dir)
    stop = _Stop()
    previous = {sig: signal.signal(sig, stop)
                for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    tty = out.isatty() and not args.quiet
    t_start = t_end = None
    companions: list[Child] = []
    vehicles: list[Child] = []
    station: list[Child] = []
    failure: str | None = None
    base_url = f"http://127.0.0.1:{plan.gs_http_port}"
    link_info: dict[str, Any] | None = None
    peers_known: dict[str, Any] | None = None
    relay_stats = run_dir / "relay.json"
    relay_signalled = False
    where: FleetNetns | _Loopback = netns or _Loopback()
    try:
        if netns is not None:
            netns.open()
            base_url = netns.forward_http(plan.gs_http_port)
        api = GroundStationApi(base_url, token)
        print(f"run folder: {run_dir}", file=out)
        print(f"dashboard:  {base_url}/?login={login_code(token, now=time.time())}", file=out)
        print(f"token:      {token}   (also: uav-ground-station token --data-dir "
              f"{plan.gs_data_dir})", file=out)
        if args.relay:
            print(f"link:       {relay_description(args)}", file=out)
        elif netns is None:
            print("link:       loopback, unshaped (no relay: --relay-rate 0)", file=out)
        print(f"constraint: {plan.constraint} {dict(plan.constraint_params)}", file=out)
        if netns is not None:
            print(f"link:       {netns.medium.describe()}", file=out)
            if netns.medium.netem is False:  # said on stderr too, where warnings go
                print(f"uav-sitl fleet: WARNING: link {netns.medium.impairment_note}",
                      file=sys.stderr)
        out.flush()

        station.append(procs.start("ground_station", where.wrap_gs(
            [*_tool("uav-ground-station", "ground_station.cli"), "run",
             "--config", str(plan.gs_config_path)])))
        relay: list[Child] = []
        if args.relay:
            relay.append(procs.start("relay", _relay_argv(args, plan, relay_stats)))
        ready_file = run_dir / "vehicles.json"
        vargv = [*_tool("uav-sitl", "sitl.cli"), "vehicle", "--count", str(args.drones),
                 "--port", "0", "--host", plan.drone_bind_host, "--scene", plan.scene,
                 "--pattern", args.pattern, "--autostart", "--speedup", str(args.speedup),
                 "--flavour", args.flavour, "--seed", str(args.seed),
                 "--first-fix", str(args.first_fix),
                 "--ready-file", str(ready_file)]
        if plan.peers_medium is not None:
            from sitl.fleet_peers import vehicle_args
            vargv += vehicle_args(args.flavour)
        for slot in plan.drones:
            vargv += ["--out", f"{mavlink_host(plan, slot)}:{slot.mavlink_port}"]
        vehicles.append(procs.start("vehicles", where.wrap_vehicles(vargv)))
        _wait(stop, "the vehicles", 30.0, ready_file.exists, vehicles)
        _wait(stop, "the ground station's API", 30.0,
              lambda: _try(lambda: api.get("/api/stats")) is not None, station)
        for slot in plan.drones:
            companions.append(procs.start(slot.drone_id, where.wrap_drone(
                slot.index, _companion_argv(slot))))
        print(f"waiting for {args.drones} drone(s) to be heard...", file=out)
        out.flush()

        def all_heard() -> bool:
            fleet = _try(lambda: api.get("/api/fleet")) or {}
            heard = {d.get("drone") for d in fleet.get("drones", [])}
            return all(s.drone_id in heard for s in plan.drones)

        _wait(stop, f"{args.drones} drones to be heard", args.ready_timeout, all_heard,
              [*station, *vehicles, *companions])
        t_exec = time.time() + args.start_delay
        if _try(lambda: api.post("/api/mission/start", {"t_exec": t_exec})) is None:
            raise FleetError(f"the ground station did not take the start command; see "
                             f"{station[0].log_path}")
        t_start = t_exec
        print(f"mission started at {time.strftime('%H:%M:%S', time.localtime(t_start))} "
              f"({args.policy}); {'Ctrl-C to stop' if args.duration == 0 else ''}"
              f"{'' if args.duration == 0 else f'running {args.duration:g} s'}", file=out)
        out.flush()
        if netns is not None and args.background is not None:
            netns.schedule_background(args.background, t_start)
        tails = {s.drone_id: LogTail(s.log_path) for s in plan.drones}
        station_tail = StationTail(plan.gs_log_path)
        last_plain = 0.0
        while True:
            now = time.time()
            if netns is not None:
                netns.tick(now)
            if relay and not relay_signalled and now >= t_start:
                _signal_group(relay[0].proc, signal.SIGUSR1)  # the background's origin
                relay_signalled = True
            if args.duration and now >= t_start + args.duration:
                break
            dead = [c for c in (*station, *vehicles, *companions, *relay) if not c.alive()]
            if dead:
                failure = (f"{dead[0].name} exited ({dead[0].proc.returncode}); its log "
                           f"({dead[0].log_path}) ends with:\n{dead[0].tail()}")
                break
            for tail in tails.values():
                tail.poll()
            station_tail.poll()
            line = progress_line(max(0.0, now - t_start), plan.drones, tails, station_tail, now)
            if tty:
                width = shutil.get_terminal_size((160, 20)).columns
                out.write("\r" + line[: width - 1].ljust(width - 1))
                out.flush()
            elif not args.quiet and now - last_plain >= 10.0:
                print(line, file=out)
                out.flush()
                last_plain = now
            if stop.sleep(1.0):
                break
        t_end = time.time()
        if tty:
            out.write("\n")
        if plan.peers_medium is not None:  # who knows whom, before stopping
            from sitl.fleet_peers import poll_peers
            peers_known = poll_peers(plan.peers_http_ports)
        _try(lambda: api.post("/api/mission/end", {"t_exec": t_end}))
    except FleetError as exc:
        failure = str(exc)
    finally:
        print("stopping: companions, vehicles, ground station...", file=out)
        out.flush()
        procs.stop(companions, timeout_s=15.0)
        procs.stop(vehicles, timeout_s=5.0)
        time.sleep(0.5)  # the last datagrams reach the station before it stops
        procs.stop(station, timeout_s=15.0)
        procs.stop_all(timeout_s=5.0)
        if args.relay:
            link_info = _relay_link(args, relay_stats)
        if netns is not None:
            if netns.medium.namespaces:
                link_info = netns.describe()
            netns.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if t_start is None or t_end is None or t_end <= t_start:
        print(f"uav-sitl fleet: {failure or 'stopped before the mission started'}",
              file=sys.stderr)
        return 1
    utility = evaluate_utility([plan.gs_log_path, *(s.log_path for s in plan.drones)],
                               spec=plan.spec_path, t_start=t_start, t_end=t_end)
    summary = summarize(plan, t_start=t_start, t_end=t_end, policy=args.policy, utility=utility)
    summary["drop_probability"] = args.drop_probability if args.policy == "random" else None
    summary["constraint"] = {"name": plan.constraint, **dict(plan.constraint_params)}
    summary["exit_codes"] = {c.name: c.proc.returncode for c in procs.children}
    summary["failure"] = failure
    summary["dashboard"] = f"{base_url}/"
    summary["link"] = link_info
    summary["peers"] = peers_known
    if peers_known is not None:
        from sitl.fleet_peers import position_age_bound
        summary["peers_age_bound_s"] = position_age_bound(plan.spec_path)
    summary["report"] = _write_report_png(plan)
    text = json.dumps(_finite(summary), indent=2, sort_keys=True, allow_nan=False)
    (run_dir / "summary.json").write_text(text + "\n", encoding="utf-8")
    if args.summary_json is not None:
        args.summary_json.parent.mkdir(parents=True, exist_ok=True)
        args.summary_json.write_text(text + "\n", encoding="utf-8")
    print(format_summary(summary), file=out)
    if failure:
        print(f"uav-sitl fleet: {failure}", file=sys.stderr)
        return 1
    return 0


def _write_report_png(plan: FleetPlan) -> str | None:
    """The end-of-mission report's plot (utility over time per drone) in the run folder."""
    from ground_station.report_page import write_png

    try:
        path = write_png(plan.gs_db_path, plan.mission, plan.run_dir / "utility.png")
    except (OSError, ValueError, sqlite3.Error) as exc:
        print(f"uav-sitl fleet: no utility plot: {exc}", file=sys.stderr)
        return None
    return None if path is None else str(path)


def _finite(value: Any) -> Any:
    """JSON-safe copy: NaN and infinities become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _companion_argv(slot: DroneSlot) -> list[str]:
    """``uav-companion run``: its ``[middleware] policy`` (written into the drone's config
    from ``--policy``) decides what goes out, so every policy runs the same app."""
    return [*_tool("uav-companion", "companion.cli"), "--log-format", "text", "run",
            "--config", str(slot.config_path)]


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

