"""Per-frame cost on the companion: scoring, JPEG versions, and the middleware's added latency.

Targets (issue 5): red-share scoring of a 640x480 frame well under 5 ms (median < 5 ms here),
and the end-to-end latency the middleware adds per image at 300 MCTS iterations < 20 ms
(the thesis measured about 0.1 s on a Raspberry Pi 4, ch. 7.2). ArUco, the HOG people
detector (default settings: half-scale; "n/a" on an OpenCV build without HOGDescriptor, i.e.
OpenCV 5 without contrib) and JPEG encoding are reported for information. Prints a table,
writes CSV and a PNG, exits 1 on a missed target.

    python benchmarks/bench_frame.py [--frames 200] [--iterations 300] [--out artifacts/bench]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.imaging import image_message
from companion.scoring import ArucoScorer, HogPeopleScorer, RedShareScorer, ScorerUnavailable


def scene(rng: np.random.Generator, i: int) -> np.ndarray:
    """A 640x480 outdoor-ish frame: textured ground, a few red objects, sometimes a marker."""
    base = rng.integers(60, 140, (60, 80, 3), dtype=np.uint8)
    image = cv2.resize(base, (640, 480), interpolation=cv2.INTER_CUBIC)
    image = cv2.add(image, rng.integers(0, 25, image.shape, dtype=np.uint8))
    for _ in range(int(rng.integers(0, 4))):
        x, y = int(rng.integers(0, 600)), int(rng.integers(0, 440))
        cv2.circle(image, (x, y), int(rng.integers(5, 40)), (20, 20, 200), -1)
    if i % 4 == 0:
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        marker = cv2.aruco.generateImageMarker(dictionary, i % 50, 96)
        padded = cv2.copyMakeBorder(marker, 12, 12, 12, 12, cv2.BORDER_CONSTANT, value=255)
        image[40:160, 40:160] = cv2.cvtColor(padded, cv2.COLOR_GRAY2BGR)
    return image


def timed(fn: Callable[[], Any], repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def hog_timings(frames: list[np.ndarray]) -> list[float] | str:
    """ms per frame of the HOG people scorer, or why it cannot run on this OpenCV."""
    try:
        hog = HogPeopleScorer()
    except ScorerUnavailable:
        return f"no HOGDescriptor in OpenCV {cv2.__version__}"
    it = iter(frames)
    return timed(lambda: hog.score(next(it)), len(frames))


def middleware_latency(frames: list[np.ndarray], iterations: int,
                       fleet: int = 1) -> list[float] | str:
    """ms from handing an image message to ``decide`` to having the decision.

    With ``fleet`` > 1 the drone also learns, as from receiver reports, the images of
    ``fleet - 1`` other drones streaming at the same rate (more items in every tree).
    """
    try:
        from companion.app import build_decider
        from companion.config import parse_config
    except ImportError as exc:
        return f"middleware unavailable: {exc}"
    config = parse_config({
        "drone": {"id": "d1"},
        "budgets": {"mcts_iterations": iterations, "time_budget_s": 1.0},
        "constraint": {"name": "constant", "params": {"limit_bytes_per_s": 60_000.0}},
    })
    try:
        decider = build_decider(config)
    except Exception as exc:  # report any setup failure as a missed measurement
        return f"middleware unavailable: {exc}"
    scorer = RedShareScorer()
    t0 = 1_700_000_000.0
    latencies = []
    for i, frame in enumerate(frames):
        now = t0 + 0.2 * i
        message = image_message(frame, sender="d1", seq=i, t_gen=now,
                                features=scorer.score(frame), geotag={}).message
        others = [dataclasses.replace(message.with_version(2), sender=f"d{k}", receiver="gs",
                                      t_gen=now - 0.3, t_sent=now - 0.3, t_rcv=now - 0.2)
                  for k in range(2, fleet + 1)]
        if others:
            decider.middleware.on_delivered(others, now)
        start = time.perf_counter()
        decider.decide(message, now)
        latencies.append((time.perf_counter() - start) * 1e3)
    return latencies[5:]  # the first decisions have no forecast yet


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--fleet", type=int, default=4, help="drones in the fleet case")
    parser.add_argument("--out", default="artifacts/bench_frame")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(7)
    frames = [scene(rng, i) for i in range(min(args.frames, 40))]
    cycle = [frames[i % len(frames)] for i in range(args.frames)]
    red, aruco = RedShareScorer(), ArucoScorer()
    it_red = iter(cycle)
    it_aruco = iter(cycle)
    it_jpeg = iter(cycle)
    print(f"measuring {args.frames} frames of 640x480 ...", file=sys.stderr, flush=True)
    rows: list[tuple[str, list[float] | str, float | None]] = [
        ("red_share scoring", timed(lambda: red.score(next(it_red)), args.frames), 5.0),
        ("aruco scoring", timed(lambda: aruco.score(next(it_aruco)), args.frames), None),
        ("hog_people scoring (half scale)", hog_timings(cycle[: min(len(cycle), 100)]), None),
        ("jpeg full+half+quarter", timed(
            lambda: image_message(next(it_jpeg), sender="d", seq=0, t_gen=0.0,
                                  features={}, geotag={}), args.frames), None),
    ]
    print(f"measuring middleware at {args.iterations} iterations ...", file=sys.stderr,
          flush=True)
    rows.append((f"middleware decide ({args.iterations} it.)",
                 middleware_latency(cycle[: min(len(cycle), 100)], args.iterations), 20.0))
    print(f"measuring middleware at {args.iterations} iterations, fleet of {args.fleet} ...",
          file=sys.stderr, flush=True)
    rows.append((f"  same, fleet of {args.fleet}",
                 middleware_latency(cycle[: min(len(cycle), 100)], args.iterations,
                                    fleet=args.fleet), 20.0))

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    failed = False
    print(f"{'stage':34} {'median ms':>10} {'p95 ms':>8} {'max ms':>8} {'target':>8}  result")
    with open(out / "bench_frame.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["stage", "median_ms", "p95_ms", "max_ms", "target_ms", "ok"])
        for name, values, target in rows:
            if isinstance(values, str):
                failed = failed or target is not None
                print(f"{name:34} {'-':>10} {'-':>8} {'-':>8} "
                      f"{target if target else '-':>8}  "
                      f"{'MISS' if target is not None else 'n/a'} ({values})")
                writer.writerow([name, "", "", "", target, False])
                continue
            med = statistics.median(values)
            p95 = float(np.percentile(values, 95))
            ok = target is None or med < target
            failed = failed or not ok
            verdict = "ok" if target is not None and ok else ("MISS" if not ok else "info")
            print(f"{name:34} {med:10.2f} {p95:8.2f} {max(values):8.2f} "
                  f"{target if target else '-':>8}  {verdict}")
            writer.writerow([name, f"{med:.3f}", f"{p95:.3f}", f"{max(values):.3f}", target, ok])
    _plot(rows, out / "bench_frame.png")
    print(f"wrote {out / 'bench_frame.csv'} and {out / 'bench_frame.png'}")
    return 1 if failed else 0


def _plot(rows: list[tuple[str, list[float] | str, float | None]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    measured = [(n, v, t) for n, v, t in rows if not isinstance(v, str)]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.boxplot([v for _, v, _ in measured], orientation="horizontal", showfliers=False)
    ax.set_yticks(range(1, len(measured) + 1), [n for n, _, _ in measured])
    for i, (_, _, target) in enumerate(measured, start=1):
        if target is not None:
            ax.plot([target, target], [i - 0.4, i + 0.4], "r--")
    ax.set_xlabel("ms per 640x480 frame (red dashes: targets)")
    ax.set_title("Companion per-frame cost")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
