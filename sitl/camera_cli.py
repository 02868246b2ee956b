"""``uav-sitl camera``: render synthetic camera frames of a scene at given poses to PNG files.

Each pose is ``EAST,NORTH,UP[,ROLL,PITCH,YAW]`` (metres in the scene's local frame, angles in
degrees). One JSON line per frame goes to stdout: file, pose, red share, what is in view.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from companion.cli_help import DefaultsRawFormatter
from sitl.argv import attach_negative_values

__all__ = ["MAX_SIDE", "main"]

MAX_SIDE = 8192
"""Largest frame side in pixels (an 8K frame)."""


def _pose(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected E,N,UP[,ROLL,PITCH,YAW], got {text!r}"
                                         ) from None
    if len(values) not in (3, 6):
        raise argparse.ArgumentTypeError(f"expected 3 or 6 numbers, got {text!r}")
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (16 <= w <= MAX_SIDE and 16 <= h <= MAX_SIDE):  # 100000x100000: a 149 GiB array
        raise argparse.ArgumentTypeError(f"width and height must be in 16..{MAX_SIDE}")
    return w, h


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(
        prog="uav-sitl camera", formatter_class=DefaultsRawFormatter,
        description="Render synthetic camera frames of a scene at given poses to PNG files.",
        epilog="example:\n  uav-sitl camera --scene demo --pose 20,30,30 --out frames/",
    )
    p.add_argument("--scene", default="demo", help="scene name or TOML path (default demo)")
    p.add_argument("--pose", type=_pose, action="append", default=[],
                   help="E,N,UP[,ROLL,PITCH,YAW] (m, deg); repeatable")
    p.add_argument("--poses", type=Path, default=None, help="file with one pose per line")
    p.add_argument("--out", type=Path, default=Path("frames"), help="output folder")
    p.add_argument("--size", type=_size, default=None, help="WIDTHxHEIGHT (default: scene)")
    p.add_argument("--hfov", type=float, default=None,
                   help="horizontal field of view (deg; default: the scene's camera)")
    p.add_argument("--mount-pitch", type=float, default=None,
                   help="camera pitch on the airframe (deg, -90 = straight down; default: the "
                        "scene's camera)")
    p.add_argument("--gimbal", action="store_true", help="gimbal-stabilised (ignore roll/pitch)")
    p.add_argument("--noise", type=float, default=3.0, help="sensor noise std (DN)")
    p.add_argument("--t", type=float, default=0.0, help="scene time (s) for lighting")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p.add_argument("--texture", action="store_true", help="also write the ground texture")
    args = p.parse_args(attach_negative_values(argv, ("--pose",)))
    if not 0 <= args.noise < math.inf:
        p.error(f"--noise must be a finite std >= 0, got {args.noise}")
    if args.mount_pitch is not None and not -180 <= args.mount_pitch <= 180:
        p.error(f"--mount-pitch must be in -180..180 degrees, got {args.mount_pitch}")
    if not math.isfinite(args.t):
        p.error(f"--t must be a finite scene time, got {args.t}")

    import cv2

    from sitl.camera import CameraPose, SyntheticCamera, red_share
    from sitl.scenes import SceneError, load_scene

    poses = list(args.pose)
    if args.poses:
        try:
            lines = args.poses.read_text().splitlines()
            poses += [_pose(x.strip()) for x in lines if x.strip() and not x.startswith("#")]
        except (OSError, UnicodeDecodeError, argparse.ArgumentTypeError) as exc:
            print(f"uav-sitl camera: {args.poses}: {exc}", file=sys.stderr)
            return 2
        if not poses:  # a file that was meant to list them: not one frame at the default
            print(f"uav-sitl camera: {args.poses}: no poses (one x,y,z per line)",
                  file=sys.stderr)
            return 2
    try:
        scene = load_scene(args.scene)
    except SceneError as exc:
        print(f"uav-sitl camera: {exc}", file=sys.stderr)
        return 2
    if not poses:
        poses = [(0.0, 0.0, scene.default_alt_m)]
    w, h = args.size or (None, None)
    try:
        cam = SyntheticCamera(scene, width_px=w, height_px=h, hfov_deg=args.hfov,
                              mount_pitch_deg=args.mount_pitch, gimbal_stabilised=args.gimbal,
                              noise_std=args.noise, seed=args.seed)
    except ValueError as exc:  # an option out of the camera's range (--hfov 200)
        print(f"uav-sitl camera: {exc}", file=sys.stderr)
        return 2
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"uav-sitl camera: cannot write to {args.out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 1
    if args.texture:
        cv2.imwrite(str(args.out / "ground_texture.png"), cam.texture)
    for i, v in enumerate(poses):
        roll, pitch, yaw = (math.radians(a) for a in v[3:6]) if len(v) == 6 else (0.0,) * 3
        pose = CameraPose(east_m=v[0], north_m=v[1], up_m=v[2], roll_rad=roll,
                          pitch_rad=pitch, yaw_rad=yaw)
        t0 = time.perf_counter()
        frame = cam.render(pose, t_s=args.t)
        render_ms = (time.perf_counter() - t0) * 1000
        path = args.out / f"frame_{i:04d}.png"
        if not cv2.imwrite(str(path), frame):
            print(f"uav-sitl camera: cannot write {path}", file=sys.stderr)
            return 1
        print(json.dumps({"file": str(path), "pose": list(v), "red_share": red_share(frame),
                          "visible": cam.visible(pose), "render_ms": round(render_ms, 2)}),
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
