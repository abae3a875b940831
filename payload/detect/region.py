"""The adaptive search region (paper Sec. III): where the local detector looks next.

The target's own image velocity and acceleration (camera motion removed) are tracked by a
Kalman filter over x = (vx, vy, ax, ay), in pixels per second. The predicted centre is

    p_t = H(p_{t-1}) + v * dt

with H the frame-to-frame camera motion (payload.detect.ego_motion). On a miss the filter is not updated:
its prediction carries the centre, and the side grows as L = L0 + k * T_lost.
With ``adaptive: false`` the region is the authors' published variant: a fixed L0 square
at the last detected centre.
"""

import logging
from typing import Optional, Tuple

import numpy as np
from filterpy.kalman import KalmanFilter

from payload.config import SearchRegionConfig
from payload.detect.ego_motion import CameraMotion

log = logging.getLogger(__name__)


class SearchRegion:
    def __init__(self, cfg: SearchRegionConfig) -> None:
        self.cfg = cfg
        self.center: Optional[Tuple[float, float]] = None  # last known/predicted target centre
        self.size_wh: Tuple[float, float] = (0.0, 0.0)  # last measured box size
        self.score = 0.0  # the lock's confidence: local scores blended over its hits
        self.misses = 0  # T_lost: consecutive frames without a detection
        self._kf = self._new_filter()
        self._carried: Optional[Tuple[float, float]] = None
        self._dt_s = 1.0

    def update_config(self, cfg: SearchRegionConfig) -> None:
        self.cfg = cfg
        self._kf.Q = self._process_noise(1.0)
        self._kf.R = np.eye(2) * cfg.measurement_noise**2

    def _process_noise(self, dt_s: float) -> np.ndarray:
        # White-noise acceleration model: noise enters through the acceleration terms.
        q = self.cfg.process_noise**2
        g = np.array([[0.5 * dt_s], [0.5 * dt_s], [1.0], [1.0]])
        return np.diag((g * g).ravel()) * q

    def _new_filter(self) -> KalmanFilter:
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])  # we measure velocity
        kf.P = np.diag([1e4, 1e4, 1e5, 1e5])
        kf.R = np.eye(2) * self.cfg.measurement_noise**2
        kf.Q = self._process_noise(1.0)
        return kf

    @property
    def active(self) -> bool:
        return self.center is not None

    @property
    def velocity_px_s(self) -> Tuple[float, float]:
        return float(self._kf.x[0, 0]), float(self._kf.x[1, 0])

    @property
    def side_px(self) -> float:
        return self.cfg.side_px + self.cfg.growth_px_per_miss * self.misses

    def reset(self) -> None:
        self.center = None
        self.misses = 0
        self._kf = self._new_filter()
        self._carried = None

    def start(self, center_xy: Tuple[float, float], size_wh: Tuple[float, float], score: float) -> None:
        """A fresh target (found by the global detector): no velocity known yet."""
        self.reset()
        self.center = (float(center_xy[0]), float(center_xy[1]))
        self.size_wh = (float(size_wh[0]), float(size_wh[1]))
        self.score = float(score)

    def predict(self, camera: CameraMotion, dt_s: float) -> Tuple[float, float]:
        """Carry the centre into the new frame: camera motion, then the target's own motion."""
        if self.center is None:
            raise RuntimeError("SearchRegion.predict before start()")
        if not self.cfg.adaptive:
            return self.center  # the fixed region stays where the target was last seen
        carried = camera.apply(self.center)
        self._carried = carried
        dt_s = max(dt_s, 1e-3)
        self._kf.F = np.array(
            [[1.0, 0, dt_s, 0], [0, 1.0, 0, dt_s], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
        )
        self._kf.Q = self._process_noise(dt_s)
        self._kf.predict()
        vx, vy = self.velocity_px_s
        self._dt_s = dt_s
        self.center = (carried[0] + vx * dt_s, carried[1] + vy * dt_s)
        return self.center

    def hit(self, center_xy: Tuple[float, float], size_wh: Tuple[float, float], score: float) -> None:
        """A detection in the region: measure the target's own velocity, recentre, and blend
        its size and score into the tracked ones (``size_smoothing``, ``score_smoothing``)."""
        if self.cfg.adaptive and self._carried is not None:
            z = np.array([[center_xy[0] - self._carried[0]], [center_xy[1] - self._carried[1]]]) / self._dt_s
            self._kf.update(z)
        self.center = (float(center_xy[0]), float(center_xy[1]))
        # the drone's size changes slowly and the detector's box jitters around it
        a = self.cfg.size_smoothing
        self.size_wh = (a * float(size_wh[0]) + (1 - a) * self.size_wh[0],
                        a * float(size_wh[1]) + (1 - a) * self.size_wh[1])
        b = self.cfg.score_smoothing
        self.score = b * float(score) + (1 - b) * self.score
        self.misses = 0

    def miss(self) -> None:
        """No detection: keep the prediction (no filter update) and grow the region."""
        self.misses += 1

    def region_xyxy(self, image_wh: Tuple[int, int]) -> np.ndarray:
        """The square L x L region around the centre, clipped to the image (integer pixels)."""
        if self.center is None:
            raise RuntimeError("SearchRegion.region_xyxy before start()")
        w, h = image_wh
        side = int(round(self.cfg.side_px if not self.cfg.adaptive else self.side_px))
        side_w, side_h = min(side, w), min(side, h)
        x1 = int(round(self.center[0] - side_w / 2.0))
        y1 = int(round(self.center[1] - side_h / 2.0))
        # Shift (not shrink) the square to stay inside the image, so the crop keeps its size.
        x1 = min(max(x1, 0), w - side_w)
        y1 = min(max(y1, 0), h - side_h)
        return np.array([x1, y1, x1 + side_w, y1 + side_h], np.int32)

    def predicted_box(self) -> np.ndarray:
        """The last measured box size at the current (predicted) centre, for coasting output."""
        cx, cy = self.center
        bw, bh = self.size_wh
        return np.array([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], np.float32)
