"""Isolated points: a 2-8 px object of either polarity standing alone on a smooth background.

A 3-6 px white drone against the sky is one or two pixels in GAD's down-scaled input, the local
network barely answers to it (it learned dark drones), and while it hovers there is no motion to
find. What it still is: a small spot brighter or darker than its surroundings, with nothing like
it around (sky, haze). Here: the morphological top-hat and black-hat (spots smaller than
``kernel_px``) and, per spot, its response over the largest response in a ring around it; a spot
on textured ground or a cloud edge has neighbours as strong as itself and scores low. What passes
is a candidate only: the scan hands it to the classifier at the lock bar, and the lock verifier
judges the track before anything is reported. Not in the paper.
"""

import cv2
import numpy as np

from payload.types import GAD, Detections

_RING_PX = 25  # the neighbourhood a spot must stand alone in
_HOLE_PX = 9  # ... not counting itself


class PointDetector:
    """``detect(image, offset_xy, module)`` -> Detections of isolated spots, strongest first."""

    def __init__(self, kernel_px: int = 11, min_contrast: float = 8.0, min_isolation: float = 1.5,
                 max_points: int = 8) -> None:
        self.kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel_px, kernel_px))
        self.ring = np.ones((_RING_PX, _RING_PX), np.uint8)
        lo = (_RING_PX - _HOLE_PX) // 2
        self.ring[lo:lo + _HOLE_PX, lo:lo + _HOLE_PX] = 0
        self.min_contrast, self.min_isolation = float(min_contrast), float(min_isolation)
        self.max_points = int(max_points)

    def detect(self, image_bgr: np.ndarray, offset_xy=(0.0, 0.0), module: str = GAD) -> Detections:
        """``module``: whose hits they are (GAD on the scan's tiles, LAD in a search region)."""
        grey = image_bgr if image_bgr.ndim == 2 else cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        if min(grey.shape[:2]) < _RING_PX:
            return Detections.empty()
        response = np.maximum(cv2.morphologyEx(grey, cv2.MORPH_TOPHAT, self.kernel),
                              cv2.morphologyEx(grey, cv2.MORPH_BLACKHAT, self.kernel)).astype(np.float32)
        # +4 grey levels: a faint spot on a perfectly flat patch is not infinitely isolated
        isolation = response / (cv2.dilate(response, self.ring) + 4.0)
        spots = ((response >= self.min_contrast) & (isolation >= self.min_isolation)).astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(spots, connectivity=8)
        if n <= 1:
            return Detections.empty()
        boxes, scores = [], []
        for x, y, w, h, _area in stats[1:]:
            if w > self.kernel.shape[1] or h > self.kernel.shape[0]:
                continue  # larger than a spot: not this detector's object
            boxes.append((x - 1, y - 1, x + w + 1, y + h + 1))
            scores.append(float(isolation[y:y + h, x:x + w].max()))
        if not boxes:
            return Detections.empty()
        order = np.argsort(-np.asarray(scores))[: self.max_points]
        xyxy = np.asarray(boxes, np.float32)[order] + np.float32([offset_xy[0], offset_xy[1]] * 2)
        # score: the isolation mapped into (0, 1) so that it ranks beside network scores
        score = 1.0 - 1.0 / np.asarray(scores, np.float32)[order]
        return Detections(xyxy, score, module)
