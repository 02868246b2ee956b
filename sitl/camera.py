"""Synthetic downward camera: what a drone sees of a scene from its position and attitude.

The ground (fields, tracks, red objects, ArUco targets) is rendered once into a texture
(with a mip pyramid); each frame is one ``cv2.warpPerspective`` of the right mip level by the
ground-plane homography ``K [r1 r2 t]`` of a pinhole camera with the given field of view and
mount pitch, then lighting (cloud shadows drifting with the wind, a slow global gain and
vignetting), and sensor noise from a precomputed, seeded noise bank. Pixels whose ray does
not hit the ground show sky.

Conventions: scene positions are local ENU metres around the scene's home; the vehicle
attitude is roll/pitch/yaw (rad, FRD body, NED world, yaw 0 = north) as in MAVLink ATTITUDE;
``mount_pitch_deg`` is -90 for a nadir camera, 0 for one looking forward. Output frames are
BGR ``uint8`` arrays of shape (height, width, 3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.scoring import RedShareScorer
from sitl.geo import GeoPoint, enu_from_geo
from sitl.scenes import Scene

__all__ = [
    "CameraPose",
    "SyntheticCamera",
    "build_cloud_shadows",
    "build_ground_texture",
    "pose_from_geo",
    "red_share",
]

SKY_BGR = (235, 200, 170)
GROUND_BGR = (70, 125, 85)
_RED_SCORER = RedShareScorer()
_FIELD_PALETTE = np.array([
    (62, 122, 78), (54, 110, 92), (72, 140, 102), (80, 150, 150), (66, 132, 118),
    (88, 128, 120), (58, 100, 70), (96, 160, 170),
], dtype=np.float32)


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraPose:
    """Where the camera's vehicle is: local ENU metres (up = height above ground), attitude."""

    east_m: float
    north_m: float
    up_m: float
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0


def pose_from_geo(origin: GeoPoint, *, lat_deg: float, lon_deg: float, alt_rel_m: float,
                  roll_rad: float = 0.0, pitch_rad: float = 0.0, yaw_rad: float = 0.0
                  ) -> CameraPose:
    """A pose from MAVLink telemetry (GLOBAL_POSITION_INT + ATTITUDE) in the scene's frame."""
    local = enu_from_geo(GeoPoint(lat_deg=lat_deg, lon_deg=lon_deg, alt_m=origin.alt_m), origin)
    return CameraPose(east_m=local.east_m, north_m=local.north_m, up_m=alt_rel_m,
                      roll_rad=roll_rad, pitch_rad=pitch_rad, yaw_rad=yaw_rad)


def red_share(frame_bgr: np.ndarray) -> float:
    """The red share the companion computes for this frame (its default red_share scorer)."""
    return float(_RED_SCORER.score(frame_bgr)["red"])


def _enu_to_px(scene: Scene, east_m: float, north_m: float) -> tuple[float, float]:
    return ((east_m + scene.width_m / 2) * scene.px_per_m,
            (scene.height_m / 2 - north_m) * scene.px_per_m)


def build_ground_texture(scene: Scene) -> np.ndarray:
    """The scene's ground as a BGR image (``px_per_m`` resolution, north up, east right)."""
    rng = np.random.default_rng(scene.seed)
    w = max(16, round(scene.width_m * scene.px_per_m))
    h = max(16, round(scene.height_m * scene.px_per_m))
    # Fields: a coarse grid of palette colours, each field 25-40 m, slightly irregular.
    cell_m = 30.0
    gw, gh = max(2, math.ceil(scene.width_m / cell_m)), max(2, math.ceil(scene.height_m / cell_m))
    fields = _FIELD_PALETTE[rng.integers(0, len(_FIELD_PALETTE), size=(gh, gw))]
    tex = np.asarray(cv2.resize(fields, (w, h), interpolation=cv2.INTER_NEAREST),
                     dtype=np.float32)
    # Low-frequency brightness variation and row texture inside fields, then fine grain.
    low = cv2.resize(rng.normal(1.0, 0.08, size=(12, 12)).astype(np.float32), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    rows = 1.0 + 0.05 * np.sin(np.arange(h, dtype=np.float32) * (2 * np.pi / (1.5 *
                                                                           scene.px_per_m)))
    tex *= (low * rows[:, None])[..., None]
    tex += rng.standard_normal(size=tex.shape, dtype=np.float32) * np.float32(6.0)
    # Dirt tracks along some field borders.
    track = (120, 140, 150)
    for k in range(1, gw):
        if rng.random() < 0.4:
            x = round(k * w / gw)
            cv2.line(tex, (x, 0), (x, h - 1), track, max(1, round(2.5 * scene.px_per_m)))
    for k in range(1, gh):
        if rng.random() < 0.3:
            y = round(k * h / gh)
            cv2.line(tex, (0, y), (w - 1, y), track, max(1, round(2.5 * scene.px_per_m)))
    tex = np.clip(tex, 0, 255).astype(np.uint8)
    ppm = scene.px_per_m
    for obj in scene.red_objects:
        cx, cy = _enu_to_px(scene, obj.east_m, obj.north_m)
        if obj.shape == "disc":
            cv2.circle(tex, (round(cx * 16), round(cy * 16)), round(obj.radius_m * ppm * 16),
                       obj.bgr, -1, cv2.LINE_AA, shift=4)
        else:
            box = ((cx, cy), (obj.width_m * ppm, obj.length_m * ppm), obj.heading_deg)
            pts = cv2.boxPoints(box)
            cv2.fillPoly(tex, [np.round(pts * 16).astype(np.int32)], obj.bgr, cv2.LINE_AA,
                         shift=4)
    if scene.targets:
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        for tgt in scene.targets:
            _paste_marker(tex, scene, dictionary, tgt.id, tgt.east_m, tgt.north_m, tgt.size_m,
                          tgt.heading_deg)
    return tex


def _paste_marker(tex: np.ndarray, scene: Scene, dictionary: cv2.aruco.Dictionary,
                  marker_id: int,
                  east_m: float, north_m: float, size_m: float, heading_deg: float) -> None:
    """Lay a marker (with a white quiet zone of one module) flat on the ground."""
    side = max(12, round(size_m * scene.px_per_m))
    marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side)
    pad = max(2, side // 6)
    board = cv2.copyMakeBorder(marker, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    board = cv2.cvtColor(board, cv2.COLOR_GRAY2BGR)
    n = board.shape[0]
    cx, cy = _enu_to_px(scene, east_m, north_m)
    m = cv2.getRotationMatrix2D((n / 2, n / 2), -heading_deg, 1.0)
    m[0, 2] += cx - n / 2
    m[1, 2] += cy - n / 2
    h, w = tex.shape[:2]
    warped = cv2.warpAffine(board, m, (w, h), flags=cv2.INTER_LINEAR)
    mask = cv2.warpAffine(np.full((n, n), 255, np.uint8), m, (w, h), flags=cv2.INTER_NEAREST)
    tex[mask > 0] = warped[mask > 0]


def build_cloud_shadows(rng: np.random.Generator, *, period_m: float = 400.0,
                        m_per_px: float = 2.0, cloud_size_m: float = 60.0,
                        coverage: float = 0.3, strength: float = 0.35) -> np.ndarray:
    """A periodic (tileable) map of light gain in [1 - strength, 1]: soft cloud shadows.

    Low-pass filtered white noise (FFT, so it wraps seamlessly), thresholded so that about
    ``coverage`` of the ground is in shadow, with soft edges.
    """
    n = max(8, round(period_m / m_per_px))
    spectrum = np.fft.fft2(rng.standard_normal((n, n)))
    k = np.fft.fftfreq(n, d=m_per_px)
    k2 = k[:, None] ** 2 + k[None, :] ** 2
    field = np.real(np.fft.ifft2(spectrum * np.exp(-k2 * (cloud_size_m / 2) ** 2)))
    field = (field - field.mean()) / (field.std() + 1e-12)
    threshold = float(np.quantile(field, 1.0 - coverage))
    soft = np.clip((field - threshold) / 0.6 + 0.5, 0.0, 1.0)
    return np.asarray(255.0 * (1.0 - strength * soft), dtype=np.uint8)


def _rotation_body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([
        [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
        [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
        [-sp, sr * cp, cr * cp],
    ])


def _rotation_camera_to_body(mount_pitch_rad: float) -> np.ndarray:
    """Columns are the OpenCV camera axes (x right, y down, z optical) in body FRD."""
    c, s = math.cos(mount_pitch_rad), math.sin(mount_pitch_rad)
    x_c = np.array([0.0, 1.0, 0.0])
    z_c = np.array([c, 0.0, -s])
    y_c = np.cross(z_c, x_c)
    return np.column_stack([x_c, y_c, z_c])


class SyntheticCamera:
    """Renders frames of one scene; build one per drone (the texture can be shared)."""

    def __init__(
        self,
        scene: Scene,
        *,
        width_px: int | None = None,
        height_px: int | None = None,
        hfov_deg: float | None = None,
        mount_pitch_deg: float | None = None,
        gimbal_stabilised: bool = False,
        noise_std: float = 3.0,
        lighting: bool = True,
        clouds: bool = True,
        cloud_drift_en_m_s: tuple[float, float] = (2.0, 1.0),
        seed: int = 0,
        texture: np.ndarray | None = None,
    ) -> None:
        spec = scene.camera
        self.scene = scene
        self.width_px = width_px or spec.width_px
        self.height_px = height_px or spec.height_px
        self.hfov_deg = spec.hfov_deg if hfov_deg is None else hfov_deg
        self.mount_pitch_deg = spec.mount_pitch_deg if mount_pitch_deg is None else (
            mount_pitch_deg)
        if not 1.0 <= self.hfov_deg < 179.0:
            raise ValueError(f"hfov_deg must be in [1, 179), got {self.hfov_deg}")
        self.gimbal_stabilised = gimbal_stabilised
        self.lighting = lighting
        self.noise_std = noise_std
        fx = (self.width_px / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        self.K = np.array([[fx, 0.0, self.width_px / 2 - 0.5],
                           [0.0, fx, self.height_px / 2 - 0.5],
                           [0.0, 0.0, 1.0]])
        self._K_inv = np.linalg.inv(self.K)
        self._R_bc = _rotation_camera_to_body(math.radians(self.mount_pitch_deg))
        base = build_ground_texture(scene) if texture is None else texture
        self._pyramid = [base]
        while min(self._pyramid[-1].shape[:2]) > 128 and len(self._pyramid) < 6:
            self._pyramid.append(cv2.pyrDown(self._pyramid[-1]))
        self._rng = np.random.default_rng(seed)
        w, h = self.width_px, self.height_px
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        self._vignette = cv2.merge([(255 * (1.0 - 0.25 * r2)).astype(np.uint8)] * 3)
        self._noise_bank = np.clip(
            self._rng.normal(0.0, noise_std, size=(h + 61, w + 67, 3)), -127, 127
        ).astype(np.int16) if noise_std > 0 else None
        self._sky = np.empty((h, w, 3), np.uint8)
        self._sky[:] = SKY_BGR
        self.cloud_drift_en_m_s = cloud_drift_en_m_s
        self._cloud_m_per_px = 2.0
        self._clouds = build_cloud_shadows(np.random.default_rng(scene.seed + 1),
                                           m_per_px=self._cloud_m_per_px) if (
            clouds and lighting) else None

    @property
    def texture(self) -> np.ndarray:
        """The full-resolution ground texture (share it with other cameras of the scene)."""
        return self._pyramid[0]

    def _camera_to_ned(self, pose: CameraPose) -> np.ndarray:
        if self.gimbal_stabilised:
            r_nb = _rotation_body_to_ned(0.0, 0.0, pose.yaw_rad)
        else:
            r_nb = _rotation_body_to_ned(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
        return np.asarray(r_nb @ self._R_bc, dtype=np.float64)

    def _texture_to_ned(self, level: int) -> np.ndarray:
        """(col, row, 1) of mip ``level`` -> (north, east, 1)."""
        s = self.scene
        m_per_px = (2**level) / s.px_per_m
        return np.array([
            [0.0, -m_per_px, s.height_m / 2 - 0.5 * m_per_px],
            [m_per_px, 0.0, -s.width_m / 2 + 0.5 * m_per_px],
            [0.0, 0.0, 1.0],
        ])

    def ground_homography(self, pose: CameraPose) -> np.ndarray:
        """Homography from ground (north, east, 1) to image pixels (u, v, 1)."""
        r_cn = self._camera_to_ned(pose).T
        c = np.array([pose.north_m, pose.east_m, -max(pose.up_m, 0.05)])
        t = -r_cn @ c
        return np.asarray(self.K @ np.column_stack([r_cn[:, 0], r_cn[:, 1], t]),
                          dtype=np.float64)

    def project(self, pose: CameraPose, east_m: float, north_m: float) -> tuple[float, float
                                                                               ] | None:
        """Pixel (u, v) of a ground point, or None when it is behind or outside the image."""
        r_cn = self._camera_to_ned(pose).T
        p = r_cn @ np.array([north_m - pose.north_m, east_m - pose.east_m,
                             max(pose.up_m, 0.05)])
        if p[2] <= 1e-6:
            return None
        u, v, _ = self.K @ (p / p[2])
        if 0 <= u < self.width_px and 0 <= v < self.height_px:
            return float(u), float(v)
        return None

    def visible(self, pose: CameraPose) -> dict[str, list[int]]:
        """Indices of red objects and ids of targets whose centre is in the frame."""
        return {
            "red_objects": [i for i, o in enumerate(self.scene.red_objects)
                            if self.project(pose, o.east_m, o.north_m) is not None],
            "targets": [t.id for t in self.scene.targets
                        if self.project(pose, t.east_m, t.north_m) is not None],
        }

    def _cloud_gain(self, pose: CameraPose, t_s: float) -> np.ndarray:
        """The cloud-shadow gain (uint8, 255 = full sun) of every pixel, BGR-shaped.

        The tileable shadow map drifts with the wind; it is warped by the same ground
        homography at 1/8 resolution (shadows are soft) and scaled up.
        """
        assert self._clouds is not None
        m = self._cloud_m_per_px
        de, dn = (v * t_s for v in self.cloud_drift_en_m_s)
        shadow_to_ned = np.array([[0.0, -m, dn], [m, 0.0, de], [0.0, 0.0, 1.0]])
        w, h = self.width_px, self.height_px
        small = np.diag([1 / 8, 1 / 8, 1.0]) @ self.ground_homography(pose) @ shadow_to_ned
        gain = cv2.warpPerspective(self._clouds, small, (max(1, w // 8), max(1, h // 8)),
                                   flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        gain = cv2.resize(gain, (w, h), interpolation=cv2.INTER_LINEAR)
        return cv2.cvtColor(gain, cv2.COLOR_GRAY2BGR)

    def render(self, pose: CameraPose, *, t_s: float = 0.0) -> np.ndarray:
        """One BGR uint8 frame of the scene seen from ``pose`` at scene time ``t_s``."""
        w, h = self.width_px, self.height_px
        r_nc = self._camera_to_ned(pose)
        ray = r_nc @ self._K_inv  # ray(u, v) = ray @ (u, v, 1) in NED
        down = ray[2]
        # Ground sample distance at the image centre picks the mip level (no aliasing).
        centre = ray @ np.array([w / 2, h / 2, 1.0])
        height = max(pose.up_m, 0.05)
        dist = height / centre[2] * np.linalg.norm(centre) if centre[2] > 1e-3 else 10 * height
        gsd_m = dist / self.K[0, 0]
        level = int(np.clip(math.floor(math.log2(max(1.0, gsd_m * self.scene.px_per_m))), 0,
                            len(self._pyramid) - 1))
        hom = self.ground_homography(pose) @ self._texture_to_ned(level)
        frame = cv2.warpPerspective(self._pyramid[level], hom, (w, h), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=GROUND_BGR)
        if self._clouds is not None:
            frame = cv2.multiply(frame, self._cloud_gain(pose, t_s), scale=1.0 / 255.0)
        corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]],
                           float) @ down
        if corners.min() <= 0.02:  # part of the view is above the horizon
            yy, xx = np.mgrid[0:h, 0:w]
            sky = (down[0] * xx + down[1] * yy + down[2]) <= 0.02
            frame[sky] = self._sky[sky]
        if self.lighting:
            gain = 1.0 + 0.12 * math.sin(2 * math.pi * t_s / 37.0) + 0.06 * math.sin(
                2 * math.pi * t_s / 11.0 + 0.7)
            frame = cv2.multiply(frame, self._vignette, scale=gain / 255.0)
        if self._noise_bank is not None:
            dy = int(self._rng.integers(0, self._noise_bank.shape[0] - h + 1))
            dx = int(self._rng.integers(0, self._noise_bank.shape[1] - w + 1))
            frame = cv2.add(frame, self._noise_bank[dy:dy + h, dx:dx + w], dtype=cv2.CV_8U)
        return frame
