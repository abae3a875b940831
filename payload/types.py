"""The data that flows between the stages: Frame -> Detections -> Target -> Bearing.

Boxes are always in full-frame pixels, ``xyxy`` = (x1, y1, x2, y2) with x2/y2 exclusive
edges as floats. Times are nanoseconds: ``t_capture_ns`` on the monotonic clock (for
intervals and latency), ``t_wall_ns`` on the wall clock (for logs and MAVLink).
"""

from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Sequence, Tuple

import numpy as np

#: Names of the four detection modules, in the paper's terms.
GAD = "GAD"  # global appearance detector
GMD = "GMD"  # global motion detector
LAD = "LAD"  # local appearance detector
LMD = "LMD"  # local motion detector
MODULES = (GAD, GMD, LAD, LMD)


@dataclass(frozen=True)
class Frame:
    """One camera image (BGR, uint8, HxWx3) with its index and capture times.

    ``prepared``: work on the image done ahead on the capture thread (``FrameSource.prepare``), by
    the consumer's key (GLAD: grey levels, camera motion, GAD's input); whoever uses it must do the same without it.
    """

    image: np.ndarray
    index: int
    t_capture_ns: int
    t_wall_ns: int
    prepared: Dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @property
    def size_wh(self) -> Tuple[int, int]:
        h, w = self.image.shape[:2]
        return int(w), int(h)


@dataclass(frozen=True)
class Detections:
    """A struct of arrays: N boxes (full-frame ``xyxy`` pixels), scores and source modules.

    Empty is a valid object (N = 0), never None. Index with a boolean mask or an index
    array to select; nothing here mutates its inputs.
    """

    xyxy: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    score: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.float32))
    module: np.ndarray = field(default_factory=lambda: np.zeros((0,), "<U3"))

    def __post_init__(self):
        xyxy = np.asarray(self.xyxy, np.float32).reshape(-1, 4)
        score = np.asarray(self.score, np.float32).reshape(-1)
        module = np.asarray(self.module, "<U3").reshape(-1)
        if module.size == 1 and len(xyxy) != 1:
            module = np.full(len(xyxy), module[0], "<U3")
        if not (len(xyxy) == len(score) == len(module)):
            raise ValueError(
                "Detections: xyxy, score and module must have the same length, got %d, %d, %d"
                % (len(xyxy), len(score), len(module))
            )
        object.__setattr__(self, "xyxy", xyxy)
        object.__setattr__(self, "score", score)
        object.__setattr__(self, "module", module)

    @classmethod
    def empty(cls) -> "Detections":
        return cls()

    @classmethod
    def from_xywh(cls, xywh, score, module) -> "Detections":
        xywh = np.asarray(xywh, np.float32).reshape(-1, 4)
        xyxy = np.concatenate([xywh[:, :2], xywh[:, :2] + xywh[:, 2:]], axis=1)
        return cls(xyxy, score, module)

    @classmethod
    def concat(cls, parts: Sequence["Detections"]) -> "Detections":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls()
        return cls(
            np.concatenate([p.xyxy for p in parts]),
            np.concatenate([p.score for p in parts]),
            np.concatenate([p.module for p in parts]),
        )

    def __len__(self) -> int:
        return len(self.score)

    def __getitem__(self, index) -> "Detections":
        """Select rows with a slice, an index array or a boolean mask; an int keeps one row."""
        if not isinstance(index, slice):
            index = np.asarray(index)
            if index.ndim == 0:
                index = index.reshape(1)
        return Detections(self.xyxy[index], self.score[index], self.module[index])

    @property
    def xywh(self) -> np.ndarray:
        return np.concatenate([self.xyxy[:, :2], self.xyxy[:, 2:] - self.xyxy[:, :2]], axis=1)

    @property
    def centers(self) -> np.ndarray:
        return (self.xyxy[:, :2] + self.xyxy[:, 2:]) / 2.0

    @property
    def areas(self) -> np.ndarray:
        wh = np.clip(self.xyxy[:, 2:] - self.xyxy[:, :2], 0, None)
        return wh[:, 0] * wh[:, 1]

    def shifted(self, dx: float, dy: float) -> "Detections":
        """The same boxes moved by (dx, dy): crop coordinates -> full-frame coordinates."""
        return Detections(self.xyxy + np.array([dx, dy, dx, dy], np.float32), self.score, self.module)

    def resized(self, size_wh) -> "Detections":
        """The same centres with every box ``size_wh`` (w, h) pixels."""
        half = np.asarray(size_wh, np.float32).reshape(-1, 2) / 2.0
        centers = self.centers
        return Detections(np.concatenate([centers - half, centers + half], axis=1), self.score, self.module)

    def rescored(self, score: float) -> "Detections":
        """The same boxes, every one with ``score``."""
        return Detections(self.xyxy, np.full(len(self), score, np.float32), self.module)

    def sorted_by_score(self) -> "Detections":
        return self[np.argsort(-self.score, kind="stable")]


@dataclass(frozen=True)
class Target:
    """The switcher's verdict for one frame: where the target is, and how we know.

    ``measured`` is True when a detector found it this frame, False when the box is the
    search region's prediction (coasting). ``region_xyxy`` is the local search region the
    frame was searched in (None in global mode).
    """

    frame_index: int
    t_capture_ns: int
    xyxy: np.ndarray
    score: float
    module: str
    measured: bool
    region_xyxy: Optional[np.ndarray] = None

    @property
    def center(self) -> Tuple[float, float]:
        return (float(self.xyxy[0] + self.xyxy[2]) / 2.0, float(self.xyxy[1] + self.xyxy[3]) / 2.0)


@dataclass(frozen=True)
class Bearing:
    """The ray to the target's centre.

    Body frame is FRD (x forward, y right, z down): azimuth positive to the right,
    elevation positive up. The level frame is the body frame with roll and pitch removed
    (yaw-referenced to the vehicle heading): None when no attitude was available.
    """

    t_capture_ns: int
    az_body_rad: float
    el_body_rad: float
    az_level_rad: Optional[float]
    el_level_rad: Optional[float]
    confidence: float
