"""The synthetic camera: a rotating, zooming pinhole on a moving drone.

The backdrop (sky, horizon, ground) is treated as distant, so the camera's rotation and zoom
move all of it by one homography ``K_t R_t^T R_ref K_ref^-1`` from the backdrop plane (the
image plane of a fixed reference camera) into frame t. Camera translation only shows in the
near clutter (parallax), which is projected with the full 3-D model.

World frame: level, x right, y down, z forward (OpenCV camera axes at zero attitude).
Camera attitude: ``R_wc = Ry(yaw) @ Rx(pitch) @ Rz(roll)``; pitch > 0 looks up, yaw > 0 looks
right, roll > 0 turns the image clockwise.
"""

import math
from dataclasses import dataclass
from typing import Tuple

import numpy as np


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def attitude(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Camera-to-world rotation for the given roll, pitch (up > 0) and yaw (right > 0)."""
    return rot_y(yaw_rad) @ rot_x(pitch_rad) @ rot_z(roll_rad)


def intrinsics(focal_px: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])


def direction(yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """Unit world direction for a bearing (yaw right > 0, pitch up > 0)."""
    cp = math.cos(pitch_rad)
    return np.array([cp * math.sin(yaw_rad), -math.sin(pitch_rad), cp * math.cos(yaw_rad)])


@dataclass(frozen=True)
class CameraPose:
    """One frame's camera: attitude, zoom and position (metres, world frame)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    zoom: float
    position_m: np.ndarray

    def rotation(self) -> np.ndarray:
        return attitude(self.roll_rad, self.pitch_rad, self.yaw_rad)


class Wander:
    """A random wander around ``mean`` with std ``std`` and time scale ``tau_s``.

    A plain Ornstein-Uhlenbeck process has white-noise velocity (it jitters frame to frame);
    a low-pass of ``smooth_s`` on top makes it move like a real gimbal or airframe. With
    ``smooth_s=0`` it stays raw (vibration).
    """

    def __init__(self, rng: np.random.Generator, mean: float, std: float, tau_s: float, x0: float,
                 smooth_s: float = 0.5):
        self.rng, self.mean, self.std, self.tau_s, self.smooth_s = rng, mean, std, tau_s, smooth_s
        self.raw = self.x = x0

    def step(self, dt_s: float) -> float:
        a = math.exp(-dt_s / self.tau_s)
        self.raw = self.mean + a * (self.raw - self.mean) + self.std * math.sqrt(1 - a * a) * self.rng.standard_normal()
        b = math.exp(-dt_s / self.smooth_s) if self.smooth_s > 0 else 0.0
        self.x = b * self.x + (1 - b) * self.raw
        return self.x


@dataclass(frozen=True)
class MotionLimits:
    """How far the synthetic camera may turn and zoom; the backdrop is rendered to cover it."""

    yaw_rad: float = math.radians(18.0)
    pitch_min_rad: float = math.radians(-14.0)
    pitch_max_rad: float = math.radians(8.0)
    roll_rad: float = math.radians(12.0)
    zoom_min: float = 0.85
    zoom_max: float = 1.6
    hfov_rad: float = math.radians(60.0)  # at zoom 1


class CameraPath:
    """A random but reproducible camera path that loosely follows an aim point.

    Each ``step(aim_yaw, aim_pitch)`` advances one frame: the camera looks near the aim point
    (the target) with a slowly wandering offset, rolls and zooms, shakes (vibration) and now and
    then jumps abruptly (a gust, a gimbal snap).
    """

    def __init__(self, rng: np.random.Generator, limits: MotionLimits, fps: float, shake: float = 1.0,
                 jump_rate_hz: float = 0.1, speed_mps: Tuple[float, float] = (2.0, 10.0)):
        self.rng, self.lim, self.dt_s = rng, limits, 1.0 / fps
        half = limits.hfov_rad / 2
        self.off_yaw = Wander(rng, 0.0, 0.4 * half, 3.0, rng.normal(0.0, 0.2 * half))
        self.off_pitch = Wander(rng, 0.0, 0.2 * half, 3.0, rng.normal(0.0, 0.1 * half))
        self.roll = Wander(rng, 0.0, 0.4 * limits.roll_rad, 2.5, rng.normal(0.0, 0.3 * limits.roll_rad))
        lz0, lz1 = math.log(limits.zoom_min), math.log(limits.zoom_max)
        self.log_zoom = Wander(rng, (lz0 + lz1) / 2, (lz1 - lz0) / 4, 5.0, rng.uniform(lz0, lz1))
        self.shake = [Wander(rng, 0.0, shake * math.radians(0.08), 0.06, 0.0, smooth_s=0.0) for _ in range(3)]
        self.jump_rate_hz = jump_rate_hz
        self.aim = None  # smoothed aim point (the operator lags behind the target)
        speed = rng.uniform(*speed_mps)
        heading = rng.uniform(-math.pi, math.pi)
        self.velocity_mps = speed * np.array([math.sin(heading), 0.0, math.cos(heading)])
        self.position_m = np.zeros(3)

    def step(self, aim_yaw_rad: float, aim_pitch_rad: float) -> CameraPose:
        dt, lim = self.dt_s, self.lim
        if self.aim is None:
            self.aim = np.array([aim_yaw_rad, aim_pitch_rad])
        a = math.exp(-dt / 0.6)
        self.aim = a * self.aim + (1 - a) * np.array([aim_yaw_rad, aim_pitch_rad])
        if self.rng.random() < self.jump_rate_hz * dt:
            half = lim.hfov_rad / 2
            jump_yaw = self.rng.choice([-1.0, 1.0]) * self.rng.uniform(0.15, 0.6) * half
            jump_pitch = self.rng.normal(0.0, 0.2 * half)
            for ou, jump in ((self.off_yaw, jump_yaw), (self.off_pitch, jump_pitch)):
                ou.x += jump  # abrupt: past the smoothing
                ou.raw += jump
        sy, sp, sr = (s.step(dt) for s in self.shake)
        yaw = float(np.clip(self.aim[0] + self.off_yaw.step(dt) + sy, -lim.yaw_rad, lim.yaw_rad))
        pitch = float(np.clip(self.aim[1] + self.off_pitch.step(dt) + sp, lim.pitch_min_rad, lim.pitch_max_rad))
        roll = float(np.clip(self.roll.step(dt) + sr, -lim.roll_rad, lim.roll_rad))
        zoom = float(np.clip(math.exp(self.log_zoom.step(dt)), lim.zoom_min, lim.zoom_max))
        # Slow turns of the ego-drone's own flight path (the clutter's parallax comes from this).
        turn = self.rng.normal(0.0, 0.05) * dt
        c, s = math.cos(turn), math.sin(turn)
        vx, _, vz = self.velocity_mps
        self.velocity_mps = np.array([c * vx + s * vz, 0.0, -s * vx + c * vz])
        self.position_m = self.position_m + self.velocity_mps * dt
        return CameraPose(roll, pitch, yaw, zoom, self.position_m.copy())


class Lens:
    """Projection of a camera pose: the frame's intrinsics and the backdrop homography."""

    def __init__(self, width: int, height: int, hfov_rad: float):
        self.width, self.height = width, height
        self.focal_px = (width / 2.0) / math.tan(hfov_rad / 2.0)

    def K(self, zoom: float) -> np.ndarray:
        return intrinsics(self.focal_px * zoom, self.width / 2.0, self.height / 2.0)

    def project(self, pose: CameraPose, points_w: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixels (N, 2) and depth (N,) along the optical axis."""
        cam = (np.asarray(points_w, np.float64) - pose.position_m) @ pose.rotation()
        depth = cam[:, 2]
        uvw = cam @ self.K(pose.zoom).T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, depth

    def project_directions(self, pose: CameraPose, dirs_w: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Directions at infinity (N, 3) -> pixels (N, 2) and depth sign (N,)."""
        cam = np.asarray(dirs_w, np.float64) @ pose.rotation()
        uvw = cam @ self.K(pose.zoom).T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = uvw[:, :2] / uvw[:, 2:3]
        return uv, cam[:, 2]
