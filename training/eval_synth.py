"""F-score on a synthetic 1920x1080 moving-camera clip (payload.synth) with small drones:
the whole GLAD pipeline (payload.detect.pipeline.Glad) versus the global appearance detector alone.

A frame's reported box is a true positive when IoU > 0.5 with the scene's drone box.
  python training/eval_synth.py [--seed 7] [--frames 150] [--target-px 6 20]
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import DetectorConfig  # noqa: E402
from payload.detect.pipeline import Glad  # noqa: E402
from payload.models import build_detectors  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from payload.types import Frame  # noqa: E402
from training.build_cache import iou  # noqa: E402


def score(rows):
    tp = sum(r[0] for r in rows)
    npred = sum(r[1] for r in rows)
    ngt = sum(r[2] for r in rows)
    p, r = tp / max(1, npred), tp / max(1, ngt)
    return p, r, 2 * p * r / max(1e-9, p + r)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[7])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--target-px", type=float, nargs=2, default=(6.0, 20.0))
    args = ap.parse_args()
    cfg = DetectorConfig()
    models = build_detectors(cfg)
    for seed in args.seeds:
        glad = Glad(cfg, models)
        rows_glad, rows_gad, modules = [], [], {}
        for sf in Scene(seed=seed, width=1920, height=1080, fps=30.0, frames=args.frames, target_px=tuple(args.target_px)):
            t_ns = int(sf.index * 1e9 / 30.0)
            res = glad.process(Frame(sf.image, sf.index, t_ns, t_ns))
            gt = sf.target_xyxy
            for rows, dets in ((rows_glad, res.detections), (rows_gad, models.global_appearance.detect(sf.image)[:1])):
                hit = int(gt is not None and len(dets) > 0 and iou(dets.xyxy[0], np.asarray(gt, np.float32)) > 0.5)
                rows.append((hit, int(len(dets) > 0), int(gt is not None)))
            if len(res.detections):
                modules[res.detections.module[0]] = modules.get(res.detections.module[0], 0) + 1
        print("seed=%d frames=%d target_px=%s  GLAD P=%.3f R=%.3f F=%.3f (modules %s) | GAD alone P=%.3f R=%.3f F=%.3f"
              % ((seed, args.frames, list(args.target_px)) + score(rows_glad) + (modules,) + score(rows_gad)), flush=True)


if __name__ == "__main__":
    main()
