"""Moving things that are not the target: birds in the air and cars on the ground.

Birds fly along directions at infinity (like the target, so the backdrop homography carries
them plus their own motion); cars drive on the backdrop's ground plane. Both are drawn behind
the target and are never labelled.
"""

import math
from typing import List, Optional

import cv2
import numpy as np

from payload.synth.camera import CameraPose, Lens, MotionLimits, direction


class Birds:
    """Flapping V-shaped silhouettes 3-25 px across, wandering through the camera's range."""

    def __init__(self, rng: np.random.Generator, limits: MotionLimits, count: int, fps: float):
        self.rng, self.lim, self.dt_s = rng, limits, 1.0 / fps
        self.state = [self._spawn() for _ in range(count)]
        self.t_s = 0.0

    def _spawn(self) -> np.ndarray:
        r, lim = self.rng, self.lim
        # yaw, pitch, d_yaw/dt, d_pitch/dt, span_px at zoom 1, flap Hz, phase
        return np.array([r.uniform(-lim.yaw_rad, lim.yaw_rad) * 1.2,
                         r.uniform(lim.pitch_min_rad, lim.pitch_max_rad + 0.1),
                         r.normal(0, 0.05), r.normal(0, 0.015), r.uniform(3, 25), r.uniform(2, 7),
                         r.uniform(0, 2 * math.pi)])

    def draw(self, image: np.ndarray, lens: Lens, pose: CameraPose) -> None:
        self.t_s += self.dt_s
        for i, b in enumerate(self.state):
            b[0] += b[2] * self.dt_s
            b[1] += b[3] * self.dt_s
            b[2] += self.rng.normal(0, 0.02) * self.dt_s
            if abs(b[0]) > self.lim.yaw_rad * 1.6 or not (-0.5 < b[1] < 0.5):
                self.state[i] = b = self._spawn()
            uv, depth = lens.project_directions(pose, direction(b[0], b[1])[None])
            if depth[0] <= 0:
                continue
            x, y = uv[0]
            span = b[4] * pose.zoom
            if not (-span < x < lens.width + span and -span < y < lens.height + span):
                continue
            flap = math.sin(2 * math.pi * b[5] * self.t_s + b[6])
            half = span / 2
            tip_dy = -flap * half * 0.6
            pts = np.array([[x - half, y + tip_dy], [x - half * 0.4, y - flap * half * 0.1], [x, y],
                            [x + half * 0.4, y - flap * half * 0.1], [x + half, y + tip_dy]])
            shift = 3
            thick = max(1, int(round(span / 10)))
            cv2.polylines(image, [(pts * (1 << shift)).astype(np.int32)], False, (35, 35, 40), thick,
                          cv2.LINE_AA, shift)


class Cars:
    """Small coloured boxes driving straight on the ground plane."""

    def __init__(self, rng: np.random.Generator, ground_to_backdrop: Optional[np.ndarray], count: int, fps: float):
        self.rng, self.dt_s = rng, 1.0 / fps
        self.G = ground_to_backdrop
        self.state: List[np.ndarray] = [self._spawn() for _ in range(count if self.G is not None else 0)]

    def _spawn(self) -> np.ndarray:
        r = self.rng
        z = r.uniform(60, 600)
        x = r.uniform(-0.6, 0.6) * z
        heading = r.uniform(-math.pi, math.pi)
        speed = r.uniform(4, 20)
        colour = [(30, 30, 160), (200, 200, 200), (40, 40, 40), (150, 90, 30), (60, 150, 200)][int(r.integers(5))]
        return np.array([x, z, heading, speed, *colour], np.float64)

    def draw(self, image: np.ndarray, backdrop_to_frame: np.ndarray) -> None:
        if not self.state:
            return
        H = backdrop_to_frame @ self.G
        h, w = image.shape[:2]
        for i, c in enumerate(self.state):
            c[0] += c[3] * math.sin(c[2]) * self.dt_s
            c[1] += c[3] * math.cos(c[2]) * self.dt_s
            if not (40 < c[1] < 800 and abs(c[0]) < c[1]):
                self.state[i] = c = self._spawn()
            box = cv2.boxPoints(((c[0], c[1]), (1.9, 4.5), -math.degrees(c[2])))
            q = np.concatenate([box, np.ones((4, 1))], 1) @ H.T
            if (q[:, 2] <= 0).any():
                continue
            uv = q[:, :2] / q[:, 2:3]
            if uv[:, 0].max() < 0 or uv[:, 1].max() < 0 or uv[:, 0].min() >= w or uv[:, 1].min() >= h:
                continue
            shift = 3
            cv2.fillConvexPoly(image, (uv * (1 << shift)).astype(np.int32), tuple(c[4:7].tolist()), cv2.LINE_AA, shift)
