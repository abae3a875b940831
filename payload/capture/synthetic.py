"""A FrameSource that renders the synthetic air-to-air scene (demo, tests, bench without a camera)."""

import logging
from typing import Iterator, Optional

from payload.capture.base import EndOfStream, FrameSource, now_ns
from payload.config import SyntheticSceneConfig
from payload.synth.scene import Scene, SceneFrame
from payload.types import Frame

log = logging.getLogger(__name__)


def scene_of(cfg: SyntheticSceneConfig) -> Scene:
    """The scene a synthetic capture config describes."""
    return Scene(seed=cfg.seed, width=cfg.width, height=cfg.height, fps=cfg.fps, frames=cfg.frames,
                 target_px=tuple(cfg.target_px), background=cfg.background, drone_look=cfg.drone,
                 sky=cfg.sky, target_in_sky=cfg.target_in_sky)


class SyntheticSource(FrameSource):
    """Frames of ``scene_of(cfg)`` as fast as they are asked for, stamped with the scene's own
    timeline (1/fps apart, like a recording) so that the search region's motion model sees 1/fps
    between frames, not the render time. Played at camera rate (``capture.pace``) it is read by
    payload.capture.paced's thread, which drops what a slow consumer misses, as a camera does.

    The ground truth of the frame last read is ``last_truth`` (a SceneFrame).
    """

    live = False

    def __init__(self, cfg: SyntheticSceneConfig):
        super().__init__()
        self.cfg = cfg
        self.last_truth: Optional[SceneFrame] = None
        self._frames: Optional[Iterator[SceneFrame]] = None
        self._t0 = None

    def open(self) -> None:
        if self._frames is not None:
            return
        self._frames = iter(scene_of(self.cfg))
        self._t0 = None  # (mono, wall) of scene frame 0, read with it
        self.stats.connected = True
        log.info("synthetic source open seed=%d size=%dx%d fps=%.1f frames=%d", self.cfg.seed, self.cfg.width,
                 self.cfg.height, self.cfg.fps, self.cfg.frames)

    def read(self, timeout_s: float = 1.0) -> Optional[Frame]:
        if self._frames is None:
            self.open()
        try:
            truth = next(self._frames)
        except StopIteration:
            self.stats.connected = False
            raise EndOfStream() from None
        if self._t0 is None:
            self._t0 = now_ns()
        offset_ns = int(round(truth.index * 1e9 / self.cfg.fps))
        self.last_truth = truth
        self.stats.frames += 1
        return Frame(image=truth.image, index=truth.index, t_capture_ns=self._t0[0] + offset_ns,
                     t_wall_ns=self._t0[1] + offset_ns)

    def close(self) -> None:
        if self._frames is not None:
            self._frames.close()
            self._frames = None
        self.stats.connected = False
