"""Isolated points: a 2-8 px object of either polarity standing alone on a smooth background.

A 3-6 px white drone against the sky is one or two pixels in GAD's down-scaled input, the local
network barely answers to it (it learned dark drones), and while it hovers there is no motion to
find. What it still is: a small spot brighter or darker than its surroundings in some colour
channel, with nothing like it around (sky, haze). Here: the morphological top-hat and black-hat
(spots smaller than ``kernel_px``) of each channel, the largest of them, and, per spot, its
response over the largest response in a ring around it; a spot on textured ground or a cloud edge
has neighbours as strong as itself and scores low. What passes is a candidate only: the scan
hands it to the classifier at the lock bar, and the lock verifier judges the track before anything
is reported. Not in the paper.
"""

from typing import Optional, Tuple

import cv2
import numpy as np

from payload.types import GAD, Detections

_RING_PX = 25  # the neighbourhood a spot must stand alone in
_HOLE_PX = 9  # ... not counting itself


def ring_max(response: np.ndarray) -> np.ndarray:
    """The largest value in the _RING_PX square ring (a _HOLE_PX hole) around each pixel, pixels
    beyond the image left out (``response`` >= 0, at least _RING_PX on each side). The same as
    ``cv2.dilate`` with the ring as its kernel, at a third of the cost: OpenCV dilates with a
    rectangle row by row and column by column, with any other shape pixel by pixel, so the ring
    is four rectangles (above, below, left, right of the hole), each band shifted into place."""
    r, h = _RING_PX // 2, _HOLE_PX // 2
    band, s = r - h, h + 1  # each band is 8 px deep and starts 5 px from the centre
    pad = cv2.copyMakeBorder(response, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    across = cv2.dilate(pad, np.ones((1, _RING_PX), np.uint8))  # dx in [-12, 12]
    up = cv2.dilate(across, np.ones((band, 1), np.uint8), anchor=(0, band - 1))  # dy in [-7, 0]
    down = cv2.dilate(across, np.ones((band, 1), np.uint8), anchor=(0, 0))  # dy in [0, 7]
    left = cv2.dilate(pad, np.ones((1, band), np.uint8), anchor=(band - 1, 0))  # dx in [-7, 0]
    right = cv2.dilate(pad, np.ones((1, band), np.uint8), anchor=(0, 0))  # dx in [0, 7]
    hh, ww = response.shape
    rows, cols = slice(r, r + hh), slice(r, r + ww)
    above_below = np.maximum(up[r - s:r - s + hh, cols], down[r + s:r + s + hh, cols])
    sides = cv2.dilate(np.maximum(left[:, r - s:r - s + ww], right[:, r + s:r + s + ww]),
                       np.ones((_HOLE_PX, 1), np.uint8))  # dy in [-4, 4]
    return np.maximum(above_below, sides[rows])


class PointDetector:
    """``detect(image, offset_xy, module)`` -> Detections of isolated spots, strongest first."""

    def __init__(self, kernel_px: int = 11, min_contrast: float = 8.0, min_isolation: float = 1.5,
                 max_points: int = 8) -> None:
        self.kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel_px, kernel_px))
        # rows or columns a crop needs beyond the pixels it answers for, so that they get the whole
        # image's answer: the ring (12 px) of top-hats (an opening or closing: twice half the kernel)
        self.margin_px = _RING_PX // 2 + 2 * (kernel_px // 2)
        self.min_contrast, self.min_isolation = float(min_contrast), float(min_isolation)
        self.max_points = int(max_points)

    @property
    def kernel_px(self) -> int:
        """The largest spot's side (the top-hat kernel's)."""
        return int(self.kernel.shape[0])

    def detect(self, image_bgr: np.ndarray, offset_xy=(0.0, 0.0), module: str = GAD,
               min_isolation: Optional[float] = None) -> Detections:
        """``module``: whose hits they are (GAD on the scan's tiles, LAD in a search region);
        ``min_isolation``: this call's bar instead of the detector's own."""
        if min(image_bgr.shape[:2]) < _RING_PX:
            return Detections.empty()
        response = self.response(image_bgr)
        ring = ring_max(response)
        # isolation = response / (ring + 4) >= min_isolation, in 8 bit over the whole frame (a 1080p
        # frame in ~8 ms; in float, 13): response >= ceil(min_isolation * (ring + 4)), the bar rounded
        # up by convertScaleAbs, and no pass where that bar is beyond 255. +4 grey levels: a faint spot
        # on a perfectly flat patch is not infinitely isolated.
        a = self.min_isolation if min_isolation is None else float(min_isolation)
        bar = cv2.convertScaleAbs(ring, alpha=a, beta=4.0 * a + 0.5 - 1e-3)
        spots = cv2.compare(response, bar, cv2.CMP_GE)
        spots &= cv2.compare(response, self.min_contrast, cv2.CMP_GE)
        spots &= cv2.compare(ring, max(0.0, 255.0 / a - 4.0), cv2.CMP_LE)
        # the 8-connected spots' outer borders (the top level of RETR_CCOMP, a spot inside another's
        # hole included): on a few spots far cheaper than labelling every pixel
        contours, hierarchy = cv2.findContours(spots, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)[-2:]
        outer = [c for c, link in zip(contours, hierarchy[0]) if link[3] < 0] if contours else []
        outer.sort(key=lambda c: (int(c[0, 0, 1]), int(c[0, 0, 0])))  # raster order of the first pixel
        boxes, scores = [], []
        for contour in outer:
            x, y, w, h = cv2.boundingRect(contour)
            if w > self.kernel.shape[1] or h > self.kernel.shape[0]:
                continue  # larger than a spot: not this detector's object
            boxes.append((x - 1, y - 1, x + w + 1, y + h + 1))
            part = np.s_[y:y + h, x:x + w]
            scores.append(float((response[part].astype(np.float32) / (ring[part].astype(np.float32) + 4.0)).max()))
        if not boxes:
            return Detections.empty()
        order = np.argsort(-np.asarray(scores), kind="stable")[: self.max_points]
        xyxy = np.asarray(boxes, np.float32)[order] + np.float32([offset_xy[0], offset_xy[1]] * 2)
        # score: the isolation mapped into (0, 1) so that it ranks beside network scores
        score = 1.0 - 1.0 / np.asarray(scores, np.float32)[order]
        return Detections(xyxy, score, module)

    def response(self, image: np.ndarray) -> np.ndarray:
        """The spot response (uint8): the larger of the top-hat and black-hat, in each colour channel
        and the largest of those. A white drone against a pale, sunlit sky is nearly the sky's grey
        level, yet its blue stands 5-10 noise units below the sky's (the grey average hides it)."""
        response = np.maximum(cv2.morphologyEx(image, cv2.MORPH_TOPHAT, self.kernel),
                              cv2.morphologyEx(image, cv2.MORPH_BLACKHAT, self.kernel))
        if response.ndim == 3:  # whatever the channels (BGR, BGRA, one): the largest of them
            channels = cv2.split(response)
            response = channels[0]
            for channel in channels[1:]:
                response = cv2.max(response, channel)
        return response

    def centre(self, image: np.ndarray, xyxy, margin_px: int = 2) -> Optional[Tuple[float, float]]:
        """The centre of the isolated spot in a small box (no larger than a spot), or None where there
        is none: the response-weighted centroid of the spot's pixels at half its peak or more, on
        detect's top-hat / black-hat response (the peak's polarity; of a colour image, the channel
        where the spot is most isolated), the peak (the box's, grown by ``margin_px``) at least
        ``min_contrast`` and ``min_isolation`` x (the largest response within a ring's reach outside
        the spot + 4). The spot: the box, and the 8-connected pixels at half
        the peak or more around the peak with a pixel's rim, while no larger than a spot. A 3-6 px
        drone's network box is placed on a 4-8 px grid; its pixels say where it is to a fraction of
        one. With the box 3 px off, part of the drone lay outside it; counted as the surroundings, it
        failed its own isolation (seed 301 of configs/tiny-light-sky.yaml, docs/results.md)."""
        if image.ndim == 2:
            found = self._channel_centre(image, xyxy, margin_px)
            return found[:2] if found is not None else None
        found = [c for c in (self._channel_centre(image[..., k], xyxy, margin_px) for k in range(image.shape[2]))
                 if c is not None]
        return max(found, key=lambda c: c[2])[:2] if found else None

    def _channel_centre(self, grey: np.ndarray, xyxy, margin_px: int) -> Optional[Tuple[float, float, float]]:
        """centre() in one channel: (x, y, the peak's isolation) or None."""
        kernel_px = self.kernel_px
        x1, y1, x2, y2 = (float(v) for v in xyxy)
        if not np.isfinite([x1, y1, x2, y2]).all() or max(x2 - x1, y2 - y1) > kernel_px or x2 <= x1 or y2 <= y1:
            return None
        h, w = grey.shape[:2]
        pad = kernel_px // 2 + _RING_PX // 2
        ix1, iy1 = int(np.floor(x1)) - margin_px, int(np.floor(y1)) - margin_px
        ix2, iy2 = int(np.ceil(x2)) + margin_px, int(np.ceil(y2)) + margin_px
        wx1, wy1, wx2, wy2 = max(0, ix1 - pad), max(0, iy1 - pad), min(w, ix2 + pad), min(h, iy2 + pad)
        ix1, iy1, ix2, iy2 = max(ix1, wx1), max(iy1, wy1), min(ix2, wx2), min(iy2, wy2)
        if ix2 <= ix1 or iy2 <= iy1:
            return None
        window = grey[wy1:wy2, wx1:wx2]
        top = cv2.morphologyEx(window, cv2.MORPH_TOPHAT, self.kernel).astype(np.float32)
        black = cv2.morphologyEx(window, cv2.MORPH_BLACKHAT, self.kernel).astype(np.float32)
        inner = np.s_[iy1 - wy1:iy2 - wy1, ix1 - wx1:ix2 - wx1]
        response = top if top[inner].max() >= black[inner].max() else black  # the spot's polarity
        peak = float(response[inner].max())
        if peak < self.min_contrast:
            return None
        spot = np.zeros(response.shape, bool)
        spot[inner] = True
        # the spot's own pixels beyond the box belong to it, not to its surroundings
        half = response >= 0.5 * peak
        _, labels, stats, _ = cv2.connectedComponentsWithStats(half.astype(np.uint8), connectivity=8)
        py, px = np.unravel_index(int(np.argmax(np.where(spot, response, -1.0))), response.shape)
        sx, sy, sw, sh = stats[labels[py, px], :4]
        if max(sw, sh) <= kernel_px:
            spot[max(0, sy - 1):sy + sh + 1, max(0, sx - 1):sx + sw + 1] = True
        isolation = peak / (float(response[~spot].max(initial=0.0)) + 4.0)
        if isolation < self.min_isolation:
            return None
        weight = np.where(spot & half, response, 0.0)
        ys, xs = np.mgrid[wy1:wy2, wx1:wx2]
        total = float(weight.sum())
        # pixel (x, y) covers [x, x + 1): its centre is x + 0.5
        return float((weight * xs).sum() / total + 0.5), float((weight * ys).sum() / total + 0.5), isolation
