"""The run summary: per-drone counts from the mission logs (read through ``utility_specs.log``),
stored images from the ground station's database (``ground_station.storage_queries``), the
fleet's utility by ``uav-utility evaluate``, and the goodput share per red/plain phase."""

from __future__ import annotations

import json
import math
import sqlite3
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ground_station.storage_queries import StoredImages, stored_images
from sitl.fleet.processes import tool
from sitl.fleet_config import FleetPlan
from utility_specs.errors import LogError
from utility_specs.log import MissionLog, parse_log
from utility_specs.message import Message


def _read_log(path: Path) -> MissionLog:
    """A mission log through ``utility_specs.log`` (a torn last line is skipped); a log that
    is absent or unreadable counts as empty, with a warning."""
    try:
        with path.open(encoding="utf-8") as f:
            return parse_log(f, source=str(path), allow_torn_tail=True, keep=("decision",))
    except FileNotFoundError:
        return MissionLog()
    except (OSError, UnicodeDecodeError, LogError) as exc:
        print(f"uav-sitl fleet: summary: skipping {path}: {exc}", file=sys.stderr)
        return MissionLog()


def _best_size(m: Message) -> int:
    """Bytes of a message in its best version (what sending everything would cost)."""
    return m.versions[0].size if m.versions else m.size


def _mean_size(m: Message) -> float:
    """Mean bytes over a message's versions (what a uniformly random version costs)."""
    if not m.versions:
        return float(m.size)
    return sum(v.size for v in m.versions) / len(m.versions)


def _red(m: Message) -> float:
    return float(m.data.get("red") or 0.0)


def _reason(extras: dict[str, Any]) -> str | None:
    decision = extras.get("decision")
    return str(decision.get("reason", "")) if isinstance(decision, dict) else None


def evaluate_utility(logs: Sequence[Path], *, spec: Path, t_start: float, t_end: float,
                     timeout_s: float = 300.0) -> dict[str, Any]:
    """The fleet's total utility (eq. 4.1/4.2) by ``uav-utility evaluate`` on merged logs."""
    argv = [*tool("uav-utility", "utility_specs.cli"), "evaluate", *map(str, logs),
            "--spec", str(spec), "--json", "--ignore-unknown-types",
            "--t-start", repr(t_start), "--t-end", repr(t_end)]
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s,
                              check=False)
    except subprocess.TimeoutExpired:  # a loaded host: the summary goes on without it
        return {"error": f"uav-utility evaluate took over {timeout_s:g} s; rerun it by hand",
                "command": argv}
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
    first_copies: dict[str, dict[int, Message]] = {}
    image_bytes: dict[str, int] = {}  # every copy in the window: air time, not images
    bytes_received = 0
    copies: list[tuple[str, float, int]] = []
    for m in _read_log(plan.gs_log_path).messages:
        if m.t_rcv is None:
            continue
        in_mission = t_start <= m.t_gen <= t_end
        if in_mission:
            bytes_received += m.size
        if m.type == "image":
            copies.append((m.sender, m.t_gen, m.size))
            if in_mission:
                image_bytes[m.sender] = image_bytes.get(m.sender, 0) + m.size
            # an image counts once however many of its versions arrived (first copy's latency)
            first = first_copies.setdefault(m.sender, {})
            kept = first.get(m.seq)
            if kept is None or m.t_rcv < (kept.t_rcv or 0.0):
                first[m.seq] = m
    received = {sender: list(msgs.values()) for sender, msgs in first_copies.items()}
    seen: dict[str, list[tuple[float, float]]] = {}
    bytes_generated = 0
    bytes_generated_mean = 0.0
    stored = stored_images(plan.gs_db_path, plan.mission, t_start=t_start, t_end=t_end)
    drones: dict[str, Any] = {}
    for slot in plan.drones:
        log = _read_log(slot.log_path)
        indexed = [(i, m) for i, m in enumerate(log.messages) if t_start <= m.t_gen <= t_end]
        records = [m for _, m in indexed]
        bytes_generated += sum(_best_size(m) for m in records)
        bytes_generated_mean += sum(_mean_size(m) for m in records)
        in_window = [m for m in records if m.type == "image"]
        seen[slot.drone_id] = [(m.t_gen, _red(m)) for m in in_window]
        sent = [m for m in in_window if m.t_sent is not None]
        got_all = received.get(slot.drone_id, [])
        got = [m for m in got_all if t_start <= m.t_gen <= t_end]
        latencies = sorted((m.t_rcv or 0.0) - m.t_gen for m in got)
        reasons = [x for x in (_reason(log.extras.get(i, {})) for i, _ in indexed)
                   if x is not None]
        fallbacks = sum(x.startswith("fallback") or x == "decision timeout" for x in reasons)
        store = stored.get(slot.drone_id, StoredImages())
        drones[slot.drone_id] = {
            "generated": len(in_window),
            "sent": len(sent),
            "received": len(got),
            "received_total": len(got_all),
            "stored": store.in_window,
            "stored_total": store.rows,
            "stored_files": store.files,
            "bytes_received": image_bytes.get(slot.drone_id, 0),
            "fps_generated": len(in_window) / window,
            "fps": len(got) / window,
            "latency_mean_s": sum(latencies) / len(latencies) if latencies else None,
            "latency_p95_s": latencies[min(len(latencies) - 1, int(0.95 * len(latencies)))]
            if latencies else None,
            "decisions": len(reasons),
            "fallback_share": fallbacks / len(reasons) if reasons else None,
            "mean_red": (sum(_red(m) for m in in_window) / len(in_window))
            if in_window else None,
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
        lines.append(f"constraint: {constraint.get('name')}{unused_note(summary.get('policy'))}")
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
    if summary.get("report"):  # printed once the station stopped: how to open it again
        station = Path(summary["run_dir"]) / "ground_station.toml"
        lines.append(f"  report   {summary['report']} (the dashboard's /report page again: "
                     f"uav-ground-station run --config {station})")
    lines.append(f"  images   {data['images']}")
    lines.append(f"  database {data['ground_station_db']}")
    lines.append(f"  logs     {data['ground_station_log']} + drones/*/mission_log.jsonl")
    return "\n".join(lines)


def write_report_png(plan: FleetPlan) -> str | None:
    """The end-of-mission report's plot (utility over time per drone) in the run folder."""
    from ground_station.report_page import write_png

    try:
        path = write_png(plan.gs_db_path, plan.mission, plan.run_dir / "utility.png")
    except (OSError, ValueError, sqlite3.Error) as exc:
        print(f"uav-sitl fleet: no utility plot: {exc}", file=sys.stderr)
        return None
    return None if path is None else str(path)


def finite(value: Any) -> Any:
    """JSON-safe copy: NaN and infinities become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def unused_note(policy: object) -> str:
    """The baselines decide without the goodput constraint: a header or summary that named
    one for them (``constraint: adaptive`` for ``--policy send_all``) said otherwise."""
    return "" if policy in (None, "mcts") else f" (not used: policy {policy} ignores it)"
