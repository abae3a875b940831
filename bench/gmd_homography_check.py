"""GMD at 1080p: its own full-resolution homography vs the one shared from the 640 px grey copy.
Counts detections and frames where a detection overlaps the true target (IoU > 0.3) on 3 synthetic clips.

  PYTHONPATH=. python bench/gmd_homography_check.py
"""

import time

import cv2
import numpy as np

from payload.boxes import iou_matrix
from payload.config import Config
from payload.detect.ego_motion import EgoMotion, GreyLevels, estimate
from payload.detect.motion import MotionDetector
from payload.synth.scene import Scene


def main():
    cfg = Config().detector.global_.motion
    stats = {name: {"frames": 0, "detections": 0, "hits": 0, "ms": []} for name in ("full", "shared640")}
    for seed in (1, 3, 5):
        prev = None
        for f in Scene(seed=seed, frames=40):
            grey = GreyLevels.of(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY))
            if prev is not None and f.target_xyxy is not None:
                for name, s in stats.items():
                    detector = MotionDetector(cfg, "GMD")
                    t0 = time.perf_counter()
                    if name == "shared640":
                        camera = EgoMotion(cfg).estimate(prev, grey, fine=True)
                    else:
                        camera = estimate(prev.full, grey.full, cfg)
                    dets = detector.detect(prev.full, grey.full, camera).detections
                    s["ms"].append((time.perf_counter() - t0) * 1000)
                    s["frames"] += 1
                    s["detections"] += len(dets)
                    s["hits"] += int(len(dets) > 0 and iou_matrix(dets.xyxy, np.asarray(f.target_xyxy)[None]).max() > 0.3)
            prev = grey
    for name, s in stats.items():
        print("%-10s frames=%d detections=%d frames_with_target_hit=%d median_ms=%.1f"
              % (name, s["frames"], s["detections"], s["hits"], np.median(s["ms"])))


if __name__ == "__main__":
    main()
