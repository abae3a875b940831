"""Full-resolution tiled inference, the SAHI idea in a few lines: a baseline for GLAD.

The frame is cut into overlapping tiles the size of the detector's input, so the detector
sees every pixel at native resolution (no down-scaling, unlike GAD on the whole frame). Each
tile is a view into the frame (no copy); its boxes are shifted back to full-frame pixels and
the boxes of all tiles are merged by class-agnostic NMS, which removes the duplicates that
the overlap produces. Cost grows with the number of tiles: that is what GLAD avoids by
looking at full resolution only inside the search region.
"""

import numpy as np

from payload.boxes import DEFAULT_OVERLAP, nms, tile_starts, tiles_xyxy
from payload.detect.appearance import AppearanceDetector
from payload.types import Detections


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
