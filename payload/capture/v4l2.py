"""A USB/CSI camera through Video4Linux2 (OpenCV's V4L2 backend), read by a LiveReader thread.

We ask for FOURCC, size and rate; the driver may give something else, so we read back what it
actually set and log it (the camera intrinsics in the config must match the real size).
"""

import logging
import os
from typing import Optional

import cv2
import numpy as np

from payload.capture.base import FrameSource
from payload.capture.live import Grabber, LiveReader
from payload.config import Retry
from payload.errors import CameraLost, SourceError
from payload.types import Frame

log = logging.getLogger(__name__)


def _fourcc_text(code: float) -> str:
    value = int(code)
    return "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4)) if value > 0 else "?"


class _V4L2Grabber(Grabber):
    def __init__(self, cap: cv2.VideoCapture, device: str) -> None:
        self._cap = cap
        self._device = device

    def grab(self, timeout_s: float) -> Optional[np.ndarray]:
        # The V4L2 backend blocks in select() until a frame comes; a failed read means the camera is gone.
        ok, image = self._cap.read()
        if not ok or image is None:
            raise CameraLost("capture.device: %s: read failed (unplugged or driver error)" % self._device)
        return image

    def close(self) -> None:
        self._cap.release()


class V4L2Source(FrameSource):
    """A V4L2 camera: ``device`` is a path such as /dev/video0 (a bare number N means /dev/videoN)."""

    live = True

    def __init__(
        self,
        device: str = "/dev/video0",
        width: int = 1920,
        height: int = 1080,
        fps: float = 30.0,
        fourcc: str = "MJPG",
        retry: Optional[Retry] = None,
    ) -> None:
        super().__init__()
        self.device = "/dev/video%s" % device if str(device).isdigit() else str(device)
        self.width = int(width)
        self.height = int(height)
        self.fps = float(fps)
        self.fourcc = str(fourcc)
        if len(self.fourcc) != 4:
            raise SourceError("capture.fourcc: %r: expected 4 characters such as MJPG or YUYV" % (self.fourcc,))
        self.actual = {}  # what the driver really gave: width, height, fps, fourcc
        self._reader = LiveReader(self._connect, retry or Retry(), self.stats, name=self.name, prepare=self._prepared)
        self._opened = False

    def _connect(self) -> _V4L2Grabber:
        if not os.path.exists(self.device):
            raise SourceError("capture.device: %s: no such device" % self.device)
        cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise SourceError("capture.device: %s: cannot be opened as a V4L2 camera (busy, or no permission?)" % self.device)
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # fewer driver buffers = less stale frames
        self.actual = {
            "width": int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
            "height": int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
            "fps": float(cap.get(cv2.CAP_PROP_FPS)),
            "fourcc": _fourcc_text(cap.get(cv2.CAP_PROP_FOURCC)),
        }
        wanted = {"width": self.width, "height": self.height, "fps": self.fps, "fourcc": self.fourcc}
        differs = [k for k in wanted if k != "fps" and self.actual[k] != wanted[k]]
        if abs(self.actual["fps"] - self.fps) > 0.5:
            differs.append("fps")
        level = logging.WARNING if differs else logging.INFO
        log.log(level, "v4l2 opened device=%s width=%d height=%d fps=%.2f fourcc=%s differs_from_config=%s",
                self.device, self.actual["width"], self.actual["height"], self.actual["fps"], self.actual["fourcc"],
                ",".join(differs) or "none")
        return _V4L2Grabber(cap, self.device)

    def open(self) -> None:
        if not self._opened:
            self._reader.start(self._connect())
            self._opened = True

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if not self._opened:
            raise SourceError("capture.device: %s: read before open()" % self.device)
        return self._reader.read(timeout_s)

    def close(self) -> None:
        if self._opened:
            self._reader.stop()
            self._opened = False
