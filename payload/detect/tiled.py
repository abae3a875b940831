"""Full-resolution tiled inference, the SAHI idea in a few lines: a baseline for GLAD.

The frame is cut into overlapping tiles the size of the detector's input, so the detector
sees every pixel at native resolution (no down-scaling, unlike GAD on the whole frame). Each
tile is a view into the frame (no copy); its boxes are shifted back to full-frame pixels and
the boxes of all tiles are merged by class-agnostic NMS, which removes the duplicates that
the overlap produces. Cost grows with the number of tiles: that is what GLAD avoids by
looking at full resolution only inside the search region.
"""

from typing import List, Tuple

import numpy as np

from payload.detect.appearance import AppearanceDetector, nms
from payload.types import Detections

#: Default share of a tile that overlaps its neighbour (SAHI's default is 0.2).
DEFAULT_OVERLAP = 0.2


def tile_starts(length_px: int, tile_px: int, overlap: float) -> List[int]:
    """Start offsets of tiles of ``tile_px`` along ``length_px`` with at least ``overlap`` shared.

    The last tile is aligned to the far edge, so the tiles cover the whole length; a length
    not longer than a tile gives one tile at 0.
    """
    if not 0.0 <= overlap < 1.0:
        raise ValueError("tile overlap %r: expected 0 <= overlap < 1" % (overlap,))
    if tile_px <= 0:
        raise ValueError("tile size %r px: expected > 0" % (tile_px,))
    if length_px <= tile_px:
        return [0]
    stride = max(1, int(tile_px * (1.0 - overlap)))
    starts = list(range(0, length_px - tile_px, stride))
    starts.append(length_px - tile_px)
    return sorted(set(starts))


def tiles_xyxy(size_wh: Tuple[int, int], tile_wh: Tuple[int, int], overlap: float = DEFAULT_OVERLAP) -> np.ndarray:
    """Tiles covering an image of ``size_wh``: (K, 4) int ``xyxy``, row by row."""
    w, h = int(size_wh[0]), int(size_wh[1])
    tw, th = min(int(tile_wh[0]), w), min(int(tile_wh[1]), h)
    tiles = [(x, y, x + tw, y + th) for y in tile_starts(h, th, overlap) for x in tile_starts(w, tw, overlap)]
    return np.array(tiles, np.int64).reshape(-1, 4)


class TiledDetector:
    """An appearance detector run on every tile of the full-resolution frame; boxes merged by NMS."""

    def __init__(self, detector: AppearanceDetector, overlap: float = DEFAULT_OVERLAP, nms_iou: float = 0.4) -> None:
        self.detector = detector
        self.overlap = float(overlap)
        self.nms_iou = float(nms_iou)
        self.tile_wh = detector.input_wh
        tile_starts(1, 1, self.overlap)  # validates overlap now, not on the first frame

    def detect(self, image_bgr: np.ndarray) -> Detections:
        """Every box the tiles found, in full-frame pixels, duplicates from the overlap merged."""
        h, w = image_bgr.shape[:2]
        parts = [
            self.detector.detect(image_bgr[y1:y2, x1:x2], offset_xy=(float(x1), float(y1)))
            for x1, y1, x2, y2 in tiles_xyxy((w, h), self.tile_wh, self.overlap)
        ]
        found = Detections.concat(parts)
        if len(found) < 2:
            return found
        return found[nms(found.xyxy, found.score, self.nms_iou)]
