"""``glad-payload detect``: GLAD over a recording, one CSV row per detection."""

import logging
import os
from typing import Callable, Dict, Iterator, Optional, Tuple

import cv2

from payload.annotate import VideoOut, draw_result
from payload.capture import open_source
from payload.config import CaptureConfig, Config, load_config
from payload.detect.pipeline import Glad, GladResult
from payload.errors import SourceError
from payload.types import Detections, Frame

log = logging.getLogger(__name__)


def recording_config(cfg: Config, source: str) -> Config:
    """``cfg`` with its capture section pointed at a video file or image folder."""
    if not os.path.exists(source):
        raise SourceError("%s: no such file or folder" % source)
    kind = "folder" if os.path.isdir(source) else "file"
    capture = cfg.capture.model_copy(update={"source": kind, "path": source, "loop": False, "pace": False})
    return cfg.model_copy(update={"capture": capture})


def _frame_count(source: str) -> Optional[int]:
    if os.path.isdir(source):
        return None
    cap = cv2.VideoCapture(source)
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    return n if n > 0 else None


def iter_glad(source: str, cfg: Config, limit: int = 0, progress: bool = True,
              glad: Optional[Glad] = None, capture: Optional[CaptureConfig] = None,
              warp: Optional[Callable[[Frame], Frame]] = None) -> Iterator[Tuple[Frame, GladResult]]:
    """Run GLAD over every frame of a recording (at most ``limit`` frames when > 0); ``capture``
    replaces the recording (e.g. a finite synthetic scene), ``source`` then only names it;
    ``warp`` changes each frame first (e.g. synthetic ego-motion)."""
    if capture is None:
        cfg = recording_config(cfg, source)
        total = _frame_count(source)
    else:
        cfg = cfg.model_copy(update={"capture": capture})
        total = capture.synthetic.frames if capture.source == "synthetic" and capture.synthetic.frames else None
    glad = glad or Glad(cfg.detector)
    if limit and total:
        total = min(total, limit)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=os.path.basename(source.rstrip("/")), unit="frame", leave=False)
    try:
        with open_source(cfg.capture) as frames:
            for frame in frames:
                if limit and frame.index >= limit:
                    break
                if warp is not None:
                    frame = warp(frame)
                yield frame, glad.process(frame)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()


def run_detect(source: str, cfg: Config, limit: int = 0, progress: bool = True,
               capture: Optional[CaptureConfig] = None,
               warp: Optional[Callable[[Frame], Frame]] = None) -> Dict[int, Detections]:
    """Frame index -> GLAD's detections for that frame, over a whole recording (or ``capture``)."""
    return {frame.index: result.detections
            for frame, result in iter_glad(source, cfg, limit, progress, capture=capture, warp=warp)}


def main_detect(args) -> int:
    from payload.records import DetectionsCsvWriter

    cfg = load_config(args.config)
    video = VideoOut(args.video) if args.video else None
    frames = hits = 0
    with DetectionsCsvWriter(args.out) as writer:
        try:
            for frame, result in iter_glad(args.source, cfg, progress=not args.no_progress):
                writer.write(frame.index, result.detections)
                frames += 1
                hits += bool(len(result.detections))
                if video is not None:
                    video.write(draw_result(frame.image, result))
        finally:
            if video is not None:
                video.close()
    print("%s: %d frames, %d with a detection -> %s" % (args.source, frames, hits, args.out))
    return 0
