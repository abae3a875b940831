"""Synthetic ego-motion for real footage: a still camera's recording warped frame by frame as
if the camera had turned, rolled, zoomed and shaken, with the labelled boxes moved alike.

The Halmstad clips come from a tripod; air-to-air footage comes from a camera that never stops
moving. Turning a camera about its centre moves the whole image by one homography
``K_t R_t^T K^-1``, exact for any scene, so a warped clip is what a rotating camera would
have filmed (minus the parallax that translation adds). The camera zooms in a little (1.15-1.3x)
so that the turns stay inside the recorded frame; borders are mirrored where they do not.
"""

import dataclasses
import math
from typing import Dict, List, Tuple

import cv2
import numpy as np

from payload.synth.camera import Wander, attitude, intrinsics
from payload.types import Frame

# Smooth turns of a gimbal-stabilised camera on a hovering or slowly flying airframe, plus the
# airframe's vibration (the same shake as the synthetic scenes' camera).
YAW_STD_RAD = math.radians(1.2)
PITCH_STD_RAD = math.radians(0.8)
ROLL_STD_RAD = math.radians(0.8)
TURN_TAU_S = 1.5  # how long a turn lasts
ZOOM_RANGE = (1.15, 1.3)
SHAKE_STD_RAD = math.radians(0.08)
HFOV_RAD = math.radians(60.0)  # Halmstad's visible camera is about this wide at its widest zoom
#: A labelled box that the warp pushes this far out of the frame no longer counts as a target.
MIN_VISIBLE = 0.5


class EgoMotionWarp:
    """The warp of one clip: ``homography(i)`` maps frame i of the recording into the warped frame i.

    Reproducible: the same ``seed``, size and fps give the same camera path, whatever order the
    frames are asked for in.
    """

    def __init__(self, seed, size_wh: Tuple[int, int], fps: float = 30.0) -> None:
        self.size_wh = (int(size_wh[0]), int(size_wh[1]))
        self.dt_s = 1.0 / float(fps if fps and fps > 0 else 30.0)
        w, h = self.size_wh
        self._focal_px = (w / 2.0) / math.tan(HFOV_RAD / 2.0)
        self._k_inv = np.linalg.inv(intrinsics(self._focal_px, w / 2.0, h / 2.0))
        rng = np.random.default_rng(seed)
        self._yaw = Wander(rng, 0.0, YAW_STD_RAD, TURN_TAU_S, rng.normal(0.0, YAW_STD_RAD), smooth_s=0.3)
        self._pitch = Wander(rng, 0.0, PITCH_STD_RAD, TURN_TAU_S, rng.normal(0.0, PITCH_STD_RAD), smooth_s=0.3)
        self._roll = Wander(rng, 0.0, ROLL_STD_RAD, TURN_TAU_S, rng.normal(0.0, ROLL_STD_RAD), smooth_s=0.3)
        lz0, lz1 = math.log(ZOOM_RANGE[0]), math.log(ZOOM_RANGE[1])
        self._log_zoom = Wander(rng, (lz0 + lz1) / 2, (lz1 - lz0) / 4, 4.0, (lz0 + lz1) / 2)
        self._shake = [Wander(rng, 0.0, SHAKE_STD_RAD, 0.06, 0.0, smooth_s=0.0) for _ in range(3)]
        self._h: List[np.ndarray] = []

    def homography(self, index: int) -> np.ndarray:
        """3x3 map from recorded to warped pixels for frame ``index`` (0-based)."""
        if index < 0:
            raise ValueError("frame index %d: expected >= 0" % index)
        while len(self._h) <= index:
            self._h.append(self._step())
        return self._h[index]

    def _step(self) -> np.ndarray:
        dt = self.dt_s
        sy, sp, sr = (s.step(dt) for s in self._shake)
        rotation = attitude(self._roll.step(dt) + sr, self._pitch.step(dt) + sp, self._yaw.step(dt) + sy)
        zoom = float(np.clip(math.exp(self._log_zoom.step(dt)), *ZOOM_RANGE))
        w, h = self.size_wh
        return intrinsics(self._focal_px * zoom, w / 2.0, h / 2.0) @ rotation.T @ self._k_inv

    def image(self, index: int, image: np.ndarray) -> np.ndarray:
        """Recorded image ``index`` as the moving camera would have seen it."""
        return cv2.warpPerspective(image, self.homography(index), self.size_wh, flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REFLECT_101)

    def frame(self, frame: Frame) -> Frame:
        """The recorded frame as the moving camera would have seen it."""
        return dataclasses.replace(frame, image=self.image(frame.index, frame.image))

    def boxes(self, index: int, xyxy: np.ndarray) -> np.ndarray:
        """Labelled ``xyxy`` boxes of frame ``index`` moved into the warped frame: the box around
        the warped corners, clipped to the image; boxes left less than half visible are dropped."""
        xyxy = np.asarray(xyxy, np.float32).reshape(-1, 4)
        if not len(xyxy):
            return xyxy
        corners = np.stack([xyxy[:, [0, 1]], xyxy[:, [2, 1]], xyxy[:, [2, 3]], xyxy[:, [0, 3]]], axis=1)
        moved = cv2.perspectiveTransform(corners.reshape(-1, 1, 2).astype(np.float64), self.homography(index))
        moved = moved.reshape(-1, 4, 2)
        out = np.concatenate([moved.min(axis=1), moved.max(axis=1)], axis=1)
        w, h = self.size_wh
        clipped = np.clip(out, 0, [w, h, w, h])
        area = np.prod(out[:, 2:] - out[:, :2], axis=1)
        visible = np.prod(np.clip(clipped[:, 2:] - clipped[:, :2], 0, None), axis=1)
        keep = visible >= MIN_VISIBLE * np.maximum(area, 1e-6)
        return clipped[keep].astype(np.float32)

    def labels(self, labels: Dict[int, np.ndarray]) -> Dict[int, np.ndarray]:
        """A clip's labels (frame -> xyxy boxes) moved into the warped frames."""
        return {index: self.boxes(index, boxes) for index, boxes in labels.items()}
