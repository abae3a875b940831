"""The picture the ground station sees: the camera frame scaled to the stream's size, with GLAD's
boxes (module and score), its mode (global/local) and the lock state drawn on it.

The frame is scaled first and drawn on afterwards: drawing at 1080p and then scaling costs a
full-size copy and blurs the text. Bilinear, not area averaging: several times cheaper at 1080p,
and the boxes that show a small target are drawn after scaling anyway. It is stretched, not letterboxed, to the configured size, so
normalised image coordinates (what CAMERA_TRACK_POINT carries) mean the same in the stream and
in the camera frame.
"""

from typing import Optional, Tuple

import cv2
import numpy as np

from payload.annotate import draw_result
from payload.detect.pipeline import GladResult


def lock_text(state: str, result: GladResult) -> str:
    """The lock state as drawn (``payload.step.state_text``): e.g. 'DETECTED 0.87', 'COASTING 0.60', 'SEARCHING'."""
    if result.target is None:
        return state.upper()
    return "%s %.2f" % (state.upper(), result.target.score)


def render(image: np.ndarray, result: Optional[GladResult], state: str, size_wh: Tuple[int, int],
           annotate: bool) -> np.ndarray:
    """The BGR picture of ``size_wh`` for this frame; annotated when ``annotate`` and a result is given."""
    h, w = image.shape[:2]
    out_w, out_h = size_wh
    scaled = image if (w, h) == (out_w, out_h) else cv2.resize(image, (out_w, out_h), interpolation=cv2.INTER_LINEAR)
    if not annotate:
        return scaled
    if result is None:  # no detection ran on this frame (disabled by command): say so
        out = scaled.copy()
        cv2.putText(out, state.upper(), (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(out, state.upper(), (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        return out
    return draw_result(scaled, result, lock_text(state, result), scale=(out_w / float(w), out_h / float(h)))


def to_i420(bgr: np.ndarray) -> np.ndarray:
    """Planar YUV 4:2:0 (I420), what the encoders take: converted here, where it is cheapest,
    rather than by videoconvert in the encoder's thread."""
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420)
