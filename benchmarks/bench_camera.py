"""Speed of the synthetic camera: ms per 640x480 frame along a survey, versus the target.

Target: 4 drones at 10 fps each on one core, i.e. >= 40 frames/s single-threaded
(the issue asks for 5-10 fps per drone). Prints a table, writes CSV and a PNG contact
sheet of frames to --out, and exits non-zero on a miss.

    .venv/bin/python benchmarks/bench_camera.py [--frames 200] [--out artifacts/bench]
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sitl.camera import CameraPose, SyntheticCamera, red_share
from sitl.scenes import load_scene

TARGET_FPS = 40.0


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="demo")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--out", type=Path, default=Path("artifacts/bench"))
    args = p.parse_args(argv)
    scene = load_scene(args.scene)
    t0 = time.perf_counter()
    cam = SyntheticCamera(scene, seed=1)
    init_s = time.perf_counter() - t0
    rows = []
    sheet = []
    for alt in (15.0, 30.0, 60.0, 120.0):
        times = []
        for k in range(args.frames):
            s = k / max(1, args.frames - 1)
            pose = CameraPose(east_m=-100 + 200 * s, north_m=60 * math.sin(6 * s), up_m=alt,
                              roll_rad=0.05 * math.sin(k), pitch_rad=-0.1, yaw_rad=0.3 * s)
            t = time.perf_counter()
            frame = cam.render(pose, t_s=k * 0.2)
            times.append(time.perf_counter() - t)
            if k == args.frames // 2:
                sheet.append(frame)
                share = red_share(frame)
        ms = np.array(times) * 1000
        fps = 1000.0 / ms.mean()
        rows.append({"alt_m": alt, "mean_ms": ms.mean(), "p95_ms": np.percentile(ms, 95),
                     "fps": fps, "red_share_mid": share, "ok": fps >= TARGET_FPS})
        print(f"  altitude {alt:5.0f} m: {ms.mean():.2f} ms/frame", file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "bench_camera.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    cv2.imwrite(str(args.out / "bench_camera_frames.png"),
                cv2.resize(np.hstack(sheet), None, fx=0.5, fy=0.5))
    print(f"synthetic camera 640x480, scene {scene.name}, texture build {init_s:.2f} s")
    print(f"{'alt (m)':>8} {'mean ms':>8} {'p95 ms':>8} {'fps':>8} {'target':>8} {'ok':>4}")
    for r in rows:
        print(f"{r['alt_m']:8.0f} {r['mean_ms']:8.2f} {r['p95_ms']:8.2f} {r['fps']:8.1f} "
              f"{TARGET_FPS:8.0f} {'yes' if r['ok'] else 'NO':>4}")
    print(f"wrote {args.out / 'bench_camera.csv'} and {args.out / 'bench_camera_frames.png'}")
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
