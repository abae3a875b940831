"""Draw what GLAD decided onto a frame (for --video outputs, the demo and the live video)."""

from typing import Optional, Tuple

import cv2
import numpy as np

from payload.detect.pipeline import GladResult

_COLOURS = {"GAD": (0, 255, 0), "GMD": (0, 200, 255), "LAD": (255, 128, 0), "LMD": (255, 0, 255)}


def draw_result(image: np.ndarray, result: GladResult, status: Optional[str] = None,
                scale: Tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """A copy of ``image`` with the search region, the target and a status line drawn on it.
    ``scale``: (x, y) factors from the result's pixel coordinates to ``image``'s (a resized frame)."""
    sx, sy = scale
    out = image.copy()
    if result.region_xyxy is not None:
        x1, y1, x2, y2 = (int(v * s) for v, s in zip(result.region_xyxy, (sx, sy, sx, sy)))
        cv2.rectangle(out, (x1, y1), (x2 - 1, y2 - 1), (200, 200, 200), 1)
    for box, module, score in zip(result.detections.xyxy, result.detections.module, result.detections.score):
        x1, y1, x2, y2 = (int(round(v * s)) for v, s in zip(box, (sx, sy, sx, sy)))
        colour = _COLOURS.get(str(module), (0, 0, 255))
        pad = 4  # keep a tiny target visible under its box
        cv2.rectangle(out, (x1 - pad, y1 - pad), (x2 + pad, y2 + pad), colour, 2)
        cv2.putText(out, "%s %.2f" % (module, score), (x1 - pad, max(12, y1 - pad - 4)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)
    for other in result.targets:
        if other.primary:
            continue
        # the targets reported beside the one sent: thin, with their ids (what an operator designates)
        x1, y1, x2, y2 = (int(round(v * s)) for v, s in zip(other.target.xyxy, (sx, sy, sx, sy)))
        cv2.rectangle(out, (x1 - 4, y1 - 4), (x2 + 4, y2 + 4), (200, 200, 200), 1)
        cv2.putText(out, "#%d" % other.id, (x1 - 4, max(12, y1 - 8)), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (200, 200, 200), 1, cv2.LINE_AA)
    if result.target is not None and not result.target.measured:
        cx, cy = int(result.target.center[0] * sx), int(result.target.center[1] * sy)
        cv2.drawMarker(out, (cx, cy), (0, 0, 255), cv2.MARKER_CROSS, 16, 1)
    text = "frame %d  %s" % (result.frame_index, result.mode.upper())
    if status:
        text += "  " + status
    cv2.putText(out, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return out


class VideoOut:
    """An MP4 writer opened on the first frame (size known only then)."""

    def __init__(self, path: str, fps: float = 30.0) -> None:
        self.path = path
        self.fps = fps
        self._writer = None

    def write(self, image: np.ndarray) -> None:
        if self._writer is None:
            h, w = image.shape[:2]
            self._writer = cv2.VideoWriter(self.path, cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h))
        self._writer.write(image)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
