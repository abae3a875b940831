"""Write a synthetic clip to disk: ``<name>.mp4`` + ``<name>.csv`` labels (Halmstad format) +
``<name>_homography.npy`` (per-frame backdrop homography, previous frame -> this frame).

Label rows are ``frame,class,x,y,w,h`` with frame 0-based and ``x,y`` the top-left corner
1-based as MATLAB stores it (the Halmstad convention), one row per frame with a visible target.
"""

import csv
import logging
import os
from typing import Iterable, Tuple

import cv2
import numpy as np

from payload.errors import PayloadError, SourceError
from payload.synth.scene import Scene, SceneFrame

log = logging.getLogger(__name__)


def export_clip(scene: Scene, out_dir: str, name: str) -> Tuple[str, str]:
    """Render ``scene`` (finite: scene.frames > 0) into ``out_dir``; returns (mp4 path, csv path)."""
    if scene.frames <= 0:
        raise PayloadError(f"synth export {name}: frames={scene.frames}, expected a finite clip (frames > 0)")
    os.makedirs(out_dir, exist_ok=True)
    video_path = os.path.join(out_dir, name + ".mp4")
    csv_path = os.path.join(out_dir, name + ".csv")
    writer = cv2.VideoWriter(video_path, cv2.VideoWriter_fourcc(*"mp4v"), scene.fps, (scene.width, scene.height))
    if not writer.isOpened():
        raise SourceError(f"synth export {video_path}: cannot open an mp4v video writer")
    homographies = []
    try:
        visible = _write_rows(scene, csv_path, lambda frame: (writer.write(frame.image), homographies.append(frame.homography)))
    finally:
        writer.release()
    np.save(os.path.join(out_dir, name + "_homography.npy"), np.asarray(homographies, np.float64))
    log.info("synth clip=%s frames=%d visible=%d out=%s", name, len(homographies), visible, out_dir)
    return video_path, csv_path


def write_labels(scene: Scene, out_dir: str, name: str) -> str:
    """The labels CSV of ``scene`` (same format as export_clip), from its ground truth alone (not drawn)."""
    if scene.frames <= 0:
        raise PayloadError(f"synth labels {name}: frames={scene.frames}, expected a finite clip (frames > 0)")
    os.makedirs(out_dir, exist_ok=True)
    csv_path = os.path.join(out_dir, name + ".csv")
    _write_rows(scene.truth(), csv_path, lambda frame: None)
    return csv_path


def _write_rows(frames: Iterable[SceneFrame], csv_path: str, each_frame) -> int:
    """Halmstad-style label rows (1-based x, y) for every frame with a visible drone; returns their count."""
    visible = 0
    with open(csv_path, "w", newline="") as fh:
        rows = csv.writer(fh)
        rows.writerow(["frame", "class", "x", "y", "w", "h"])
        for frame in frames:
            each_frame(frame)
            if frame.target_xyxy is not None:
                x1, y1, x2, y2 = (float(v) for v in frame.target_xyxy)
                rows.writerow([frame.index, "DRONE", f"{x1 + 1:.2f}", f"{y1 + 1:.2f}", f"{x2 - x1:.2f}",
                               f"{y2 - y1:.2f}"])
                visible += 1
    return visible


def main_synth(args) -> int:
    """``glad-payload synth OUT --seed --frames --width --height --fps --background --name``."""
    if args.frames <= 0:
        raise PayloadError(f"synth --frames {args.frames}: expected a positive number of frames")
    scene = Scene(seed=args.seed, width=args.width, height=args.height, fps=args.fps, frames=args.frames,
                  background=args.background)
    name = args.name or f"SYN_{args.seed}"
    video_path, csv_path = export_clip(scene, args.out, name)
    print(video_path)
    print(csv_path)
    return 0
