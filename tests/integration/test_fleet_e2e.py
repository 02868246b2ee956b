"""``uav-sitl fleet`` end to end: real vehicle, companion and ground-station processes.

Default suite (about a minute): two drones for 15 s give a summary with images received and
a utility, the station stored every image it received, and no process is left behind after
the duration, after SIGTERM, or when the launcher itself is killed.

``-m slow``: the acceptance run of issue 7. Four drones share a constrained link (a fleet
goodput constraint of 10 kB/s in the companions, on loopback); one drone's survey strip is
covered with red, so its camera sees red. The optimiser delivers that drone's images at a
clearly higher rate than the others', and the fleet's evaluated utility beats a run with
random dropping (thesis fig. 5.7 baseline) at the same delivered volume. With root, the same
launcher also runs over network namespaces and a shaped link.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from sitl.fleet.live import PROGRESS_LEGEND
from tests.fleet_checks import (
    processes_of,
    summary_drones,
    warm_before_start,
    warm_up_progress,
)

FLEET = [sys.executable, "-m", "sitl.cli", "fleet"]
LIGHT = ["--rate", "3", "--mcts-iterations", "150"]
"""Three frames/s per drone and a smaller search keep the 2 shared cores usable."""

RED_STRIP_SCENE = """
name = "red-strip"
[home]
lat_deg = 47.397742
lon_deg = 8.545594
alt_m = 488.0
[ground]
width_m = 240.0
height_m = 200.0
px_per_m = 4.0
seed = 7
[flight]
default_alt_m = 30.0
[camera]
fps = 3.0
# The survey gives drone i the strip east -120 + 60 i .. -60 + 60 i: red fields cover the third
# strip (drone3) north and south of the take-off area, where nobody else flies.
[[red_objects]]
east_m = 30.0
north_m = 60.0
shape = "box"
width_m = 36.0
length_m = 70.0
[[red_objects]]
east_m = 30.0
north_m = -60.0
shape = "box"
width_m = 36.0
length_m = 70.0
"""


def _no_orphans(run_dir: Path, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while (left := processes_of(run_dir)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, f"processes left behind: {left}"


def _fleet(run_dir: Path, *args: str, timeout_s: float = 240.0) -> dict[str, Any]:
    summary_path = run_dir.parent / f"{run_dir.name}-summary.json"
    proc = subprocess.run([*FLEET, "--out", str(run_dir), "--summary-json", str(summary_path),
                           *args], capture_output=True, text=True, timeout=timeout_s,
                          check=False)
    print(proc.stdout[-3000:])
    assert proc.returncode == 0, f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"
    _no_orphans(run_dir)
    optimised = "--policy" not in args or args[args.index("--policy") + 1] == "mcts"
    for name in summary_drones(run_dir) if optimised else ():  # a baseline has no warm-up;
        warm_before_start(run_dir, name)  # an optimiser is warm before the mission starts
    warm_up_progress(proc.stdout, len(summary_drones(run_dir)))
    lines = proc.stdout.splitlines()  # the progress lines' fields are named once, up front
    started = next(i for i, line in enumerate(lines) if line.startswith("mission started"))
    assert lines[started + 1] == PROGRESS_LEGEND and lines[started + 2].startswith("[")
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    assert json.loads((run_dir / "summary.json").read_text()) == summary
    return summary


def _station_stored_what_it_received(summary: dict[str, Any]) -> None:
    """Every image in the station's own mission log has its database row and its file."""
    for name, drone in summary["drones"].items():
        assert drone["stored_total"] == drone["received_total"], name
        assert drone["stored_files"] == drone["stored_total"], name
        assert drone["stored"] == drone["received"], name  # the same mission window


@pytest.mark.timeout(200)
def test_two_drones_for_15_s(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    summary = _fleet(run_dir, "--drones", "2", "--duration", "15", *LIGHT)
    assert set(summary["drones"]) == {"drone1", "drone2"}
    assert summary["duration_s"] == pytest.approx(15.0, abs=1.5)
    for drone in summary["drones"].values():
        assert drone["generated"] > 0 and drone["received"] > 0
        assert drone["sent"] >= drone["received"]
        assert drone["latency_mean_s"] is not None and 0 < drone["latency_mean_s"] < 2.0
    assert summary["utility"]["total"] > 0, summary["utility"]
    assert set(summary["utility"]["per_type"]) >= {"image", "position"}
    _station_stored_what_it_received(summary)
    assert summary["exit_codes"] == {"ground_station": 0, "vehicles": 0, "drone1": 0,
                                     "drone2": 0, "relay": 0}
    # issue 12: the default link is the shaped relay, and it carried every byte received
    link = summary["link"]
    assert link["kind"] == "relay" and summary["constraint"]["name"] == "adaptive"
    assert link["bottleneck"]["sent_bytes"] >= summary["bytes_received"]
    assert (run_dir / "utility.png").read_bytes()[:4] == b"\x89PNG"
    # a clean run over the relay: the 1 Hz status heartbeat keeps every drone heard
    import sqlite3

    con = sqlite3.connect(f"file:{run_dir / 'gs-data' / 'ground_station.sqlite3'}?mode=ro",
                          uri=True)
    lost = con.execute("SELECT drone, text FROM alerts WHERE kind = 'link' AND text LIKE "
                       "'link lost%' AND t <= ?", (summary["t_end"],)).fetchall()
    # (after the end the launcher stops the drones before the station: they do fall silent)
    con.close()
    assert lost == []
    assert set(summary["phases"]["drones"]) == {"drone1", "drone2"}
    assert (run_dir / "fleet.key").stat().st_mode & 0o077 == 0
    assert (run_dir / "gs-data" / "token").stat().st_mode & 0o077 == 0


def _wait_for_line(proc: subprocess.Popen[bytes], out: Path, text: str, timeout_s: float
                   ) -> list[str]:
    """The lines of ``out`` (the process's stdout file) once one contains ``text``."""
    deadline = time.monotonic() + timeout_s
    lines: list[str] = []
    while time.monotonic() < deadline:
        lines = out.read_text().splitlines() if out.exists() else []
        if any(text in line for line in lines):
            return lines
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    raise AssertionError(f"no {text!r} within {timeout_s} s; output so far: {lines}")


def _start(tmp_path: Path, *args: str) -> tuple[subprocess.Popen[bytes], Path, Path]:
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("wb") as o, err.open("wb") as e:
        proc = subprocess.Popen([*FLEET, *args], stdout=o, stderr=e)
    return proc, out, err


@pytest.mark.timeout(200)
def test_sigterm_stops_the_fleet_cleanly(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc, out, err = _start(tmp_path, "--out", str(run_dir), "--drones", "2", "--duration", "0",
                            *LIGHT)
    try:
        lines = _wait_for_line(proc, out, "mission started", 120)
        # The dashboard address and the token come first, before anything is waited for.
        assert lines[1].startswith("dashboard:  http://127.0.0.1:") and "?login=" in lines[1]
        token = (run_dir / "gs-data" / "token").read_text().strip()
        assert lines[2].startswith(f"token:      {token}")
        time.sleep(5)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.read_text()[-3000:]
    assert "fleet summary" in out.read_text() and "total utility" in out.read_text()
    _no_orphans(run_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["duration_s"] > 3 and set(summary["drones"]) == {"drone1", "drone2"}


@pytest.mark.timeout(120)
def test_killed_launcher_leaves_no_processes(tmp_path: Path) -> None:
    """Even SIGKILL of the launcher (no cleanup code runs) takes its children down."""
    run_dir = tmp_path / "run"
    proc, out, _ = _start(tmp_path, "--out", str(run_dir), "--drones", "1", *LIGHT)
    try:
        _wait_for_line(proc, out, "waiting for 1 drone", 60)
        assert len(processes_of(run_dir)) >= 3  # station, vehicles, companion
    finally:
        proc.kill()
        proc.wait()
    _no_orphans(run_dir, timeout_s=20)


# -- the acceptance run (slow) -----------------------------------------------------------------


ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts" / "fleet_e2e"
"""The acceptance runs are kept here (run folders, summaries, a plot) for a look afterwards."""


def _constrained_run(folder: Path, name: str, *extra: str) -> dict[str, Any]:
    scene = folder / "red_strip.toml"
    scene.write_text(RED_STRIP_SCENE)
    return _fleet(folder / name, "--drones", "4", "--scene", str(scene), "--duration", "60",
                  "--goodput", "10000", "--window", "2", "--rate", "3", "--seed", "3",
                  "--relay-rate", "0", *extra,  # loopback, as this comparison was made on
                  timeout_s=400)


def _jsonl(path: Path) -> list[dict[str, Any]]:
    return [r for r in map(json.loads, path.read_text().splitlines()) if "sender" in r]


BIN_S = 2.0


def _red_time_rates(summary: dict[str, Any]) -> tuple[float, dict[str, float]]:
    """Seconds in which only drone3 sees red, and each drone's received frame rate then.

    The mission is cut into 2 s bins by image generation time; a bin counts when drone3's
    frames show red (mean share >= 0.2) and nobody else's do (< 0.05; drone4's transit to its
    strip crosses a red field). This is the comparison of thesis fig. 7.3: while one camera
    sees red, that stream gets the link.
    """
    run_dir = Path(summary["run_dir"])
    t0, t1 = summary["t_start"], summary["t_end"]
    n_bins = int((t1 - t0) // BIN_S)
    red: dict[str, list[list[float]]] = {}
    for name in summary["drones"]:
        bins: list[list[float]] = [[] for _ in range(n_bins)]
        for r in _jsonl(run_dir / "drones" / name / "mission_log.jsonl"):
            k = int((r["t_gen"] - t0) // BIN_S)
            if r["type"] == "image" and 0 <= k < n_bins:
                bins[k].append(r["data"]["red"])
        red[name] = bins

    def mean(xs: list[float]) -> float:
        return sum(xs) / len(xs) if xs else 0.0

    chosen = {k for k in range(n_bins) if mean(red["drone3"][k]) >= 0.2
              and all(mean(red[n][k]) < 0.05 for n in red if n != "drone3")}
    counts = dict.fromkeys(summary["drones"], 0)
    for r in _jsonl(run_dir / "gs-data" / "missions" / "fleet" / "mission_log.jsonl"):
        k = int((r["t_gen"] - t0) // BIN_S)
        if r["type"] == "image" and r["t_rcv"] is not None and k in chosen and r["t_gen"] >= t0:
            counts[r["sender"]] += 1
    seconds = BIN_S * len(chosen)
    return seconds, {n: c / seconds if seconds else 0.0 for n, c in counts.items()}


def _plot_rates(summary: dict[str, Any], path: Path) -> None:
    """Received images/s per drone (4 s bins) over the mission, and the red share each saw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(summary["run_dir"])
    t0, t1 = summary["t_start"], summary["t_end"]
    n = max(1, int((t1 - t0) // 4.0))
    fig, (ax_rate, ax_red) = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
    received = _jsonl(run_dir / "gs-data" / "missions" / "fleet" / "mission_log.jsonl")
    for name in summary["drones"]:
        counts = [0] * n
        for r in received:
            k = int((r["t_gen"] - t0) // 4.0)
            if r["sender"] == name and r["type"] == "image" and 0 <= k < n:
                counts[k] += 1
        own = [r for r in _jsonl(run_dir / "drones" / name / "mission_log.jsonl")
               if r["type"] == "image" and t0 <= r["t_gen"] <= t1]
        ax_rate.step([4.0 * k for k in range(n)], [c / 4.0 for c in counts], where="post",
                     label=name)
        ax_red.plot([r["t_gen"] - t0 for r in own], [r["data"]["red"] for r in own], ".",
                    markersize=3, label=name)
    ax_rate.set_ylabel("received images/s")
    ax_rate.set_title(f"{summary['policy']}: utility {summary['utility']['total']:.1f}")
    ax_rate.legend(fontsize=8)
    ax_red.set_ylabel("red share seen")
    ax_red.set_xlabel("mission time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_red_drone_prioritised_and_optimiser_beats_random() -> None:
    import shutil

    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    ARTIFACTS.mkdir(parents=True)
    mcts = _constrained_run(ARTIFACTS, "mcts")
    _plot_rates(mcts, ARTIFACTS / "mcts_rates.png")
    red = {name: d["mean_red"] for name, d in mcts["drones"].items()}
    seconds, fps = _red_time_rates(mcts)
    print(f"optimiser: mean red seen {red}; during the {seconds:.0f} s only drone3 saw red, "
          f"received fps {fps}; whole mission fps "
          f"{ {n: round(d['fps'], 2) for n, d in mcts['drones'].items()} }; utility "
          f"{mcts['utility']['total']:.2f} {mcts['utility']['per_type']}")
    assert red["drone3"] > 0.2 and seconds >= 10.0
    others = [v for k, v in fps.items() if k != "drone3"]
    # "Clearly higher than the others": 1.5 times each one of them, not just their mean.
    assert fps["drone3"] > 1.5 * max(others), fps
    _station_stored_what_it_received(mcts)

    # Random dropping (random version when sent) with the probability that delivers the same
    # volume (bytes) as the optimiser did: delivered bytes over what sending every message
    # in a uniformly random version would cost.
    p_send = mcts["bytes_received"] / mcts["bytes_generated_mean_version"]
    rnd = _constrained_run(ARTIFACTS, "random", "--policy", "random",
                           "--drop-probability", f"{1 - p_send:.6f}")
    _plot_rates(rnd, ARTIFACTS / "random_rates.png")
    ratio = rnd["bytes_received"] / mcts["bytes_received"]
    print(f"random (drop {1 - p_send:.4f}): received fps "
          f"{ {n: round(d['fps'], 2) for n, d in rnd['drones'].items()} }, volume ratio "
          f"{ratio:.2f}, utility {rnd['utility']['total']:.2f} {rnd['utility']['per_type']}")
    _station_stored_what_it_received(rnd)
    assert 0.75 < ratio < 1.33, "the baseline must deliver about the same volume"
    # Issue 7's criterion: the fleet's total utility (every type of the mission spec).
    # The image share alone is printed above, not asserted: at the same volume a random
    # baseline that may send full-size versions can match the optimiser on images (the
    # optimiser mostly picks quarter versions), and the total then wins on telemetry.
    assert mcts["utility"]["total"] > rnd["utility"]["total"]


def _netns_missing() -> str | None:
    from sitl.linkemu import missing_requirements

    return missing_requirements()


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.skipif(_netns_missing() is not None, reason=str(_netns_missing()))
def test_fleet_over_namespaces_with_background_traffic(tmp_path: Path) -> None:
    """--netns: each drone and the station in their own namespaces on one shaped medium,
    iperf3 background switched on during the mission; the namespaces are gone afterwards."""
    run_dir = tmp_path / "run"
    summary_path = tmp_path / "summary.json"
    proc = subprocess.Popen([*FLEET, "--out", str(run_dir), "--summary-json", str(summary_path),
                             "--netns", "--drones", "2", "--duration", "25",
                             "--link-rate", "2e6", "--background", "1.5e6@8+8", *LIGHT],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=240)
    print(out[-3000:])
    assert proc.returncode == 0, err[-3000:]
    _no_orphans(run_dir)
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                            check=True).stdout
    assert f"uavle{proc.pid}x" not in listed
    summary = json.loads(summary_path.read_text())
    assert summary["constraint"]["name"] == "adaptive"
    for drone in summary["drones"].values():
        assert drone["received"] > 0
    _station_stored_what_it_received(summary)
    assert summary["utility"]["total"] > 0
    link = summary["link"]
    assert len(set(link["namespaces"]["drones"])) == 2
    # The background (1.5 Mbit/s for 8 s = 1.5 MB) crossed the same shaped port as the images.
    assert link["bottleneck"]["sent_bytes"] > summary["bytes_received"] + 0.5 * 1.5e6
