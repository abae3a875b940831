"""Appearance detector (GAD / LAD): a stride-4 centre-point network on a letterboxed image.

The image (a full frame, or a search-region crop with its ``offset_xy``) is fitted into
``cfg.input_wh`` keeping its aspect: down-scaled only when larger, never up-scaled, so a
crop smaller than the input keeps its native resolution and small drones stay as many
pixels as the camera gave them. The rest of the input is grey padding (right and bottom).

Network contract (training/net.py): input 'images' [N, 3, H, W] RGB in [0, 1]; output
[N, 5, H/s, W/s] with 0 = centre score (already reduced to 3x3 local maxima), 1-2 = centre
offset inside the cell (cells), 3-4 = box width, height in input pixels.
"""

import logging
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.boxes import nms
from payload.config import AppearanceConfig
from payload.detect.onnx_model import OnnxModel
from payload.errors import ModelError
from payload.types import Detections

log = logging.getLogger(__name__)

PAD_VALUE = 114
_UNIT = np.float32(1.0 / 255.0)
MAX_CANDIDATES = 100  # peaks kept (by score) before NMS; a frame holds a handful of drones at most


@dataclass(frozen=True)
class Letterbox:
    """How an image was placed in the network input: scaled by scale_xy, top-left aligned."""

    scale_xy: Tuple[float, float]
    image_wh: Tuple[int, int]
    input_wh: Tuple[int, int]

    def to_image(self, xyxy_input: np.ndarray) -> np.ndarray:
        """Input-pixel boxes -> image-pixel boxes, clipped to the image."""
        sx, sy = self.scale_xy
        xyxy = np.asarray(xyxy_input, np.float32).reshape(-1, 4) / np.array([sx, sy, sx, sy], np.float32)
        w, h = self.image_wh
        return np.clip(xyxy, 0, np.array([w, h, w, h], np.float32))

    def to_input(self, xyxy_image: np.ndarray) -> np.ndarray:
        """Image-pixel boxes -> input-pixel boxes."""
        sx, sy = self.scale_xy
        return np.asarray(xyxy_image, np.float32).reshape(-1, 4) * np.array([sx, sy, sx, sy], np.float32)


def letterbox(image_bgr: np.ndarray, input_wh: Tuple[int, int],
              out: Optional[np.ndarray] = None) -> Tuple[np.ndarray, Letterbox]:
    """The network's input for the image: fitted into input_wh (down-scale only), grey padding right
    and bottom, as [1, 3, H, W] float32 RGB in [0, 1] (written into ``out`` when given, that shape);
    and the mapping back to the image."""
    h, w = image_bgr.shape[:2]
    in_w, in_h = int(input_wh[0]), int(input_wh[1])
    scale = min(in_w / float(w), in_h / float(h), 1.0)
    new_w, new_h = min(in_w, max(1, int(round(w * scale)))), min(in_h, max(1, int(round(h * scale))))
    if (new_w, new_h) != (w, h):
        image_bgr = cv2.resize(image_bgr, (new_w, new_h), interpolation=cv2.INTER_AREA)
    # Written into a buffer the detector keeps (RGB planes, padding, then one scaling in place): no
    # padded uint8 copy and no fresh 3 MB a frame (cv2.dnn.blobFromImage on a padded copy took ~2 ms
    # of GAD's ~13 at 1080p, this ~0.5); the same float32 values bit for bit.
    blob = np.empty((1, 3, in_h, in_w), np.float32) if out is None else out
    blob[0, :, new_h:] = PAD_VALUE
    blob[0, :, :new_h, new_w:] = PAD_VALUE
    blob[0, :, :new_h, :new_w] = image_bgr[:, :, ::-1].transpose(2, 0, 1)
    np.multiply(blob, _UNIT, out=blob)
    return blob, Letterbox((new_w / float(w), new_h / float(h)), (int(w), int(h)), (in_w, in_h))


def decode(maps: np.ndarray, confidence: float, input_wh: Tuple[int, int]) -> Tuple[np.ndarray, np.ndarray]:
    """Network output [1, 5, h, w] -> boxes [K, 4] in input pixels and their scores."""
    score = maps[0, 0]
    stride_x = input_wh[0] / float(score.shape[1])
    stride_y = input_wh[1] / float(score.shape[0])
    ys, xs = np.nonzero(score >= confidence)
    s = score[ys, xs]
    if len(s) > MAX_CANDIDATES:
        keep = np.argsort(-s, kind="stable")[:MAX_CANDIDATES]
        ys, xs, s = ys[keep], xs[keep], s[keep]
    cx = (xs + maps[0, 1, ys, xs]) * stride_x
    cy = (ys + maps[0, 2, ys, xs]) * stride_y
    bw, bh = maps[0, 3, ys, xs], maps[0, 4, ys, xs]
    xyxy = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1).astype(np.float32)
    return xyxy.reshape(-1, 4), s.astype(np.float32)


class AppearanceDetector:
    """GAD or LAD: ``detect(image, offset_xy)`` -> Detections in full-frame pixels."""

    def __init__(self, model: OnnxModel, cfg: AppearanceConfig, module: str) -> None:
        self.model = model
        self.cfg = cfg
        self.module = module
        self.input_wh = (int(cfg.input_wh[0]), int(cfg.input_wh[1]))
        self._input_name = next(iter(model.input_shapes))
        self._blob = np.empty((1, 3, self.input_wh[1], self.input_wh[0]), np.float32)  # the input, reused
        # one run at the live input size: checks the output layout (and warms that shape)
        probe = np.zeros((1, 3, self.input_wh[1], self.input_wh[0]), np.float32)
        out = model.run({self._input_name: probe})[0]
        if out.ndim != 4 or out.shape[1] != 5 or self.input_wh[1] % out.shape[2] or self.input_wh[0] % out.shape[3]:
            raise ModelError(
                "%s: expected output [N,5,H/s,W/s] for input %dx%d, found %s"
                % (model.where, self.input_wh[0], self.input_wh[1], list(out.shape))
            )

    def _fits(self, letterboxed, image_bgr: np.ndarray) -> bool:
        if not (isinstance(letterboxed, tuple) and len(letterboxed) == 2 and isinstance(letterboxed[1], Letterbox)):
            return False
        blob, box = letterboxed
        h, w = image_bgr.shape[:2]
        return (isinstance(blob, np.ndarray) and blob.dtype == np.float32 and blob.shape == self._blob.shape
                and box.image_wh == (w, h) and box.input_wh == self.input_wh)

    def update_config(self, cfg: AppearanceConfig) -> None:
        """Hot reload: thresholds only (the input size is fixed at start-up)."""
        if tuple(cfg.input_wh) != self.input_wh:
            log.warning("input_wh change ignored until restart module=%s now=%s", self.module, list(self.input_wh))
        self.cfg = cfg

    def detect(self, image_bgr: np.ndarray, offset_xy: Tuple[float, float] = (0, 0),
               letterboxed: Optional[Tuple[np.ndarray, Letterbox]] = None) -> Detections:
        """Hits on the image (a frame, or a crop at ``offset_xy``); ``letterboxed``: what
        ``letterbox(image_bgr, input_wh)`` gave earlier (on the capture thread), used when it is
        that input for an image of this size."""
        if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[0] < 1 or image_bgr.shape[1] < 1:
            return Detections.empty()
        if self._fits(letterboxed, image_bgr):
            blob, box = letterboxed
        else:
            blob, box = letterbox(image_bgr, self.input_wh, out=self._blob)
        maps = self.model.run({self._input_name: blob})[0]
        xyxy, score = decode(maps, self.cfg.confidence, self.input_wh)
        keep = nms(xyxy, score, self.cfg.nms_iou)
        if not len(keep):
            return Detections.empty()
        xyxy = box.to_image(xyxy[keep])
        dets = Detections(xyxy, score[keep], np.full(len(keep), self.module, "<U3"))
        return dets.shifted(float(offset_xy[0]), float(offset_xy[1]))
