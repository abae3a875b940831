"""Search-region ego-motion: homography error against the synthetic scene's true homographies,
and time, for several working widths / grids / LK settings (docs/notebook/2026-11-22.md, "Speed work").

  PYTHONPATH=. python bench/ego_motion_accuracy.py
"""

import time

import cv2
import numpy as np

from payload.config import Config
from payload.detect.ego_motion import estimate
from payload.synth.scene import Scene

BASE = Config().detector.global_.motion


def main():
    frames, truths = [], []
    for f in Scene(seed=1, frames=40):
        frames.append(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY))
        truths.append(f.homography)
    pts = np.stack(np.meshgrid(np.linspace(200, 1720, 9), np.linspace(150, 930, 6)), -1).reshape(-1, 1, 2)

    def variant(width, interp, grid, iters=30):
        cfg = BASE.model_copy(update={"grid_wh": grid, "lk_iterations": iters})
        errs, ms = [], []
        prev = None
        for i, grey in enumerate(frames):
            t0 = time.perf_counter()
            s = width / 1920.0
            small = cv2.resize(grey, None, fx=s, fy=s, interpolation=interp)
            if prev is not None:
                e = estimate(prev, small, cfg)
                scale = np.diag([s, s, 1.0])
                h = np.linalg.inv(scale) @ e.matrix @ scale if e.ok else np.eye(3)
                ms.append((time.perf_counter() - t0) * 1000)
                if truths[i] is not None:
                    a = cv2.perspectiveTransform(pts, h)
                    b = cv2.perspectiveTransform(pts, np.asarray(truths[i]))
                    errs.append(np.hypot(*(a - b).reshape(-1, 2).T).mean())
            prev = small
        return np.mean(errs), np.percentile(errs, 95), np.median(ms)

    ident = [np.hypot(*(cv2.perspectiveTransform(pts, np.asarray(h)) - pts).reshape(-1, 2).T).mean()
             for h in truths if h is not None]
    print("identity (no compensation): mean error %.2f px" % np.mean(ident))
    for v in [(640, cv2.INTER_AREA, (30, 20)), (640, cv2.INTER_LINEAR, (30, 20)), (640, cv2.INTER_AREA, (15, 10)),
              (640, cv2.INTER_AREA, (20, 14)), (640, cv2.INTER_AREA, (24, 16)),
              (320, cv2.INTER_AREA, (30, 20)), (320, cv2.INTER_AREA, (15, 10)), (320, cv2.INTER_AREA, (10, 7)),
              (320, cv2.INTER_AREA, (8, 6)), (640, cv2.INTER_AREA, (30, 20), 10)]:
        name = "%d px %s grid %s%s" % (v[0], "AREA" if v[1] == cv2.INTER_AREA else "LINEAR", v[2],
                                       " lk_iterations=%d" % v[3] if len(v) > 3 else "")
        print("%-40s error mean %.2f px p95 %.2f px, %.2f ms" % ((name,) + variant(*v)))


if __name__ == "__main__":
    main()
