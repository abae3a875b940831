"""Appearance detector (GAD / LAD): a stride-4 centre-point network on a letterboxed image.

The image (a full frame, or a search-region crop with its ``offset_xy``) is fitted into
``cfg.input_wh`` keeping its aspect: down-scaled only when larger, never up-scaled, so a
crop smaller than the input keeps its native resolution and small drones stay as many
pixels as the camera gave them. The rest of the input is grey padding (right and bottom). With
``fit`` (GAD), a network that takes any input size in steps of ``FIT_MULTIPLE`` (ours: fully
convolutional, on the CPU) gets the image's own size rounded up to that step instead of the
whole input: a 640x512 frame runs as 480x384, not 640x384 (~25 % of GAD's network), 1080p as
640x368. LAD keeps its whole input: its 300 px search region at 304x304 lost ir_val F 0.921 ->
0.916 and synthetic 100-109 F 0.607 -> 0.596 (docs/results.md, 2026-12-07), GAD's fit changed no
line.

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
from payload.detect.onnx_model import CPU, OnnxModel
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


#: The step of input sizes a network that takes any size is run at (GAD's and LAD's: their feature
#: pyramid adds maps of 1/8 and 1/16 scale, so the input must divide by 16).
FIT_MULTIPLE = 16


def _fitted(image_wh: Tuple[int, int], input_wh: Tuple[int, int]) -> Tuple[int, int]:
    """The image's size (w, h) fitted into ``input_wh`` keeping its aspect, down-scaled only."""
    w, h = int(image_wh[0]), int(image_wh[1])
    in_w, in_h = int(input_wh[0]), int(input_wh[1])
    scale = min(in_w / float(w), in_h / float(h), 1.0)
    return min(in_w, max(1, int(round(w * scale)))), min(in_h, max(1, int(round(h * scale))))


def input_size(image_wh: Tuple[int, int], input_wh: Tuple[int, int], multiple: int = 0) -> Tuple[int, int]:
    """The input size (w, h) an image of ``image_wh`` is run at: ``input_wh``, or with ``multiple``
    the image fitted into it (down-scale only) rounded up to that step."""
    in_w, in_h = int(input_wh[0]), int(input_wh[1])
    if not multiple:
        return in_w, in_h
    new_w, new_h = _fitted(image_wh, input_wh)
    return min(in_w, -(-new_w // multiple) * multiple), min(in_h, -(-new_h // multiple) * multiple)


def letterbox(image_bgr: np.ndarray, input_wh: Tuple[int, int],
              out: Optional[np.ndarray] = None, multiple: int = 0) -> Tuple[np.ndarray, Letterbox]:
    """The network's input for the image: fitted into input_wh (down-scale only), grey padding right
    and bottom, as [1, 3, H, W] float32 RGB in [0, 1] (written into ``out`` when it has that shape);
    and the mapping back to the image. With ``multiple``, H and W are the fitted image's rounded
    up to that step (``input_size``), not input_wh's."""
    h, w = image_bgr.shape[:2]
    new_w, new_h = _fitted((w, h), input_wh)
    in_w, in_h = input_size((w, h), input_wh, multiple)
    if (new_w, new_h) != (w, h):
        image_bgr = cv2.resize(image_bgr, (new_w, new_h), interpolation=cv2.INTER_AREA)
    # Written into a buffer the detector keeps (RGB planes, padding, then one scaling in place): no
    # padded uint8 copy and no fresh 3 MB a frame (cv2.dnn.blobFromImage on a padded copy took ~2 ms
    # of GAD's ~13 at 1080p, this ~0.5); the same float32 values bit for bit.
    blob = out if out is not None and out.shape == (1, 3, in_h, in_w) else np.empty((1, 3, in_h, in_w), np.float32)
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
    """GAD or LAD: ``detect(image, offset_xy)`` -> Detections in full-frame pixels. ``fit``: run the
    network at the image's own size where it takes any size (``FIT_MULTIPLE``)."""

    def __init__(self, model: OnnxModel, cfg: AppearanceConfig, module: str, fit: bool = False) -> None:
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
        self.multiple = self._fit_multiple(out.shape[2:]) if fit else 0

    def _fit_multiple(self, maps_hw) -> int:
        """FIT_MULTIPLE where the network runs on the CPU and takes an input FIT_MULTIPLE smaller
        each way with maps as much smaller, else 0 (always the whole input_wh: a model of fixed
        size; a GPU provider, where each new input size would build its engine again)."""
        w, h = self.input_wh
        if self.model.providers[0] != CPU or w <= FIT_MULTIPLE or h <= FIT_MULTIPLE:
            return 0
        stride_h, stride_w = h // int(maps_hw[0]), w // int(maps_hw[1])
        try:
            out = self.model.run({self._input_name: np.zeros((1, 3, h - FIT_MULTIPLE, w - FIT_MULTIPLE), np.float32)})[0]
        except Exception:  # noqa: BLE001 - ORT's own error types: a fixed-size model refuses other sizes
            return 0
        fits = out.ndim == 4 and tuple(out.shape[2:]) == ((h - FIT_MULTIPLE) // stride_h, (w - FIT_MULTIPLE) // stride_w)
        return FIT_MULTIPLE if fits else 0

    def letterbox(self, image_bgr: np.ndarray, out: Optional[np.ndarray] = None) -> Tuple[np.ndarray, Letterbox]:
        """This detector's input for the image (``letterbox`` at its input size and step)."""
        return letterbox(image_bgr, self.input_wh, out=out, multiple=self.multiple)

    def _fits(self, letterboxed, image_bgr: np.ndarray) -> bool:
        if not (isinstance(letterboxed, tuple) and len(letterboxed) == 2 and isinstance(letterboxed[1], Letterbox)):
            return False
        blob, box = letterboxed
        h, w = image_bgr.shape[:2]
        in_w, in_h = input_size((w, h), self.input_wh, self.multiple)
        return (isinstance(blob, np.ndarray) and blob.dtype == np.float32 and blob.shape == (1, 3, in_h, in_w)
                and box.image_wh == (w, h) and box.input_wh == (in_w, in_h))

    def update_config(self, cfg: AppearanceConfig) -> None:
        """Hot reload: thresholds only (the input size is fixed at start-up)."""
        if tuple(cfg.input_wh) != self.input_wh:
            log.warning("input_wh change ignored until restart module=%s now=%s", self.module, list(self.input_wh))
        self.cfg = cfg

    def detect(self, image_bgr: np.ndarray, offset_xy: Tuple[float, float] = (0, 0),
               letterboxed: Optional[Tuple[np.ndarray, Letterbox]] = None) -> Detections:
        """Hits on the image (a frame, or a crop at ``offset_xy``); ``letterboxed``: what
        ``self.letterbox(image_bgr)`` gave earlier (on the capture thread), used when it is that
        input for an image of this size."""
        if image_bgr is None or image_bgr.ndim != 3 or image_bgr.shape[0] < 1 or image_bgr.shape[1] < 1:
            return Detections.empty()
        if self._fits(letterboxed, image_bgr):
            blob, box = letterboxed
        else:
            blob, box = self.letterbox(image_bgr, out=self._blob)
            self._blob = blob  # reused while the input size holds (a search region's mostly does)
        maps = self.model.run({self._input_name: blob})[0]
        xyxy, score = decode(maps, self.cfg.confidence, box.input_wh)
        keep = nms(xyxy, score, self.cfg.nms_iou)
        if not len(keep):
            return Detections.empty()
        xyxy = box.to_image(xyxy[keep])
        dets = Detections(xyxy, score[keep], np.full(len(keep), self.module, "<U3"))
        return dets.shifted(float(offset_xy[0]), float(offset_xy[1]))
