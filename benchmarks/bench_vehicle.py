"""How much faster than real time the simulated vehicle runs, and a plot of a flown survey.

Runs the sans-I/O VehicleCore (physics at 50 Hz, all PX4 streams at their default rates per
simulated second, i.e. the worst case of speedup 1) through a whole lawnmower survey of the
demo scene, and reports simulated seconds per wall second on one core. Target: >= 40, so one
core carries 4 vehicles at 10x real time. Prints a table, writes CSV and a PNG of the path,
altitude and battery, exits non-zero on a miss.

    .venv/bin/python benchmarks/bench_vehicle.py [--out artifacts/bench]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from sitl.scenes import load_scene
from sitl.vehicle.core import VehicleConfig, VehicleCore
from sitl.vehicle.flavour import Mode
from sitl.vehicle.patterns import survey

TARGET_REALTIME_FACTOR = 40.0


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("artifacts/bench"))
    p.add_argument("--max-sim-s", type=float, default=1500.0)
    args = p.parse_args(argv)
    scene = load_scene("demo")
    mission = survey(scene.home, width_m=scene.width_m / 4, height_m=scene.height_m * 0.9,
                     spacing_m=30.0, alt_m=30.0, speed_m_s=8.0, center_en_m=(30.0, 0.0))
    core = VehicleCore(VehicleConfig(home=scene.home, mission=tuple(mission), first_fix_s=0.0),
                       now=0.0)
    core.fc.arm()
    core.fc.set_mode(Mode.MISSION)
    track: list[tuple[float, float, float, float, float]] = []
    frames = 0
    now = 0.0
    next_sample = 0.0
    t0 = time.perf_counter()
    while now < args.max_sim_s and (core.fc.state.armed or now < 5.0):
        now = core.get_timer()
        core.handle_timer(now)
        frames += len(core.datagrams_to_send())
        if now >= next_sample:
            st = core.fc.state
            track.append((now, st.position_ned_m[1], st.position_ned_m[0], st.alt_m,
                          100 * st.battery_remaining))
            next_sample = now + 1.0
    wall = time.perf_counter() - t0
    factor = now / wall
    ok = factor >= TARGET_REALTIME_FACTOR
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "bench_vehicle.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "east_m", "north_m", "alt_m", "battery_pct"])
        w.writerows(track)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    ax1.plot([r[1] for r in track], [r[2] for r in track], lw=1)
    for obj in scene.red_objects:
        ax1.plot(obj.east_m, obj.north_m, "o", color="red")
    for tgt in scene.targets:
        ax1.plot(tgt.east_m, tgt.north_m, "s", color="black")
    ax1.set(xlabel="east (m)", ylabel="north (m)", title="survey flown by the simulated PX4",
            aspect="equal")
    ax2.plot([r[0] for r in track], [r[3] for r in track], label="altitude (m)")
    ax2.plot([r[0] for r in track], [r[4] for r in track], label="battery (%)")
    ax2.set(xlabel="simulated time (s)", title="altitude and battery")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(args.out / "bench_vehicle.png", dpi=100)
    reached = len(mission)
    print("simulated vehicle (PX4 flavour, all default streams, physics 50 Hz)")
    print(f"{'sim s':>8} {'wall s':>8} {'x realtime':>11} {'target':>7} {'frames':>8} "
          f"{'items':>6} {'ok':>4}")
    print(f"{now:8.1f} {wall:8.2f} {factor:11.1f} {TARGET_REALTIME_FACTOR:7.0f} {frames:8d} "
          f"{reached:6d} {'yes' if ok else 'NO':>4}")
    print(f"landed and disarmed: {not core.fc.state.armed}; battery left "
          f"{100 * core.fc.state.battery_remaining:.1f} %")
    print(f"wrote {args.out / 'bench_vehicle.csv'} and {args.out / 'bench_vehicle.png'}")
    return 0 if ok and not core.fc.state.armed else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
