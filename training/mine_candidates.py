"""Mine what the runtime modules really propose, for the classifier and the local detector.

The paper trains its 32x32 classifier on motion-detector candidates. Here every module that can
hand GLAD a box proposes: GAD on the down-scaled frame, LAD in 300 px search regions (one around
the drone with a random offset, one elsewhere), GMD on the frame pair and LMD in the region. Each
box is labelled against the ground truth:
- drone: IoU > 0.3 with the drone's box, or its centre within half the drone's size of it;
- clutter: no overlap and its centre farther than 1.5x the drone's size + 8 px;
- anything between is dropped (ambiguous).

Outputs under training/cache/ (same layouts as build_cache.py / build_synth_cache.py):
  <name>_cls.npz   x [K,32,32,3], y [K]  classifier patches (payload.detect.patches.crop_patches)
  <name>_det.npz   images [N,256,256,3], xyxy [N,4] = NaN: native-resolution crops around the
                   appearance detectors' false positives that hold no drone (local hard negatives)

Sources: synthetic 1920x1080 scenes (--scenes, seeds from --first-seed, kept apart from the
build/eval seeds) and Halmstad clips of a split (--halmstad train negatives_train), every --every'th frame.

  python training/mine_candidates.py payload/models/glad_local.onnx --name mined1 --scenes 30 \
      --halmstad train negatives_train
"""

import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import AppearanceConfig, MotionConfig  # noqa: E402
from payload.detect.appearance import AppearanceDetector  # noqa: E402
from payload.detect.ego_motion import estimate  # noqa: E402
from payload.detect.motion import MotionDetector  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from payload.detect.patches import crop_patches  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from payload.types import GAD, GMD, LAD, LMD  # noqa: E402
from training.build_cache import crop_with, iou, jitter, save_extra_sets, within_crop_reach  # noqa: E402
from training.halmstad import frames, labels, splits  # noqa: E402

REGION_PX = 300
MAX_NEG_PER_SOURCE = 3  # per frame and module: keeps one noisy frame from flooding the set


def label(box, gt):
    """1 drone, 0 clutter, -1 ambiguous."""
    if gt is None:
        return 0
    size = max(gt[2] - gt[0], gt[3] - gt[1])
    d = np.hypot((box[0] + box[2] - gt[0] - gt[2]) / 2, (box[1] + box[3] - gt[1] - gt[3]) / 2)
    if iou(box, gt) > 0.3 or d <= size / 2:
        return 1
    if iou(box, gt) == 0.0 and d > 1.5 * size + 8:
        return 0
    return -1


def region_around(xy, size_wh):
    w, h = size_wh
    x0 = int(np.clip(xy[0] - REGION_PX / 2, 0, max(0, w - REGION_PX)))
    y0 = int(np.clip(xy[1] - REGION_PX / 2, 0, max(0, h - REGION_PX)))
    return x0, y0, min(w, x0 + REGION_PX), min(h, y0 + REGION_PX)


class Miner:
    def __init__(self, model_path, rng):
        model = OnnxModel(model_path, threads=2)
        self.gad = AppearanceDetector(model, AppearanceConfig(confidence=0.2), GAD)
        self.lad = AppearanceDetector(model, AppearanceConfig(confidence=0.1, input_wh=(320, 320)), LAD)
        self.gmd = MotionDetector(MotionConfig(), GMD)
        self.lmd = MotionDetector(MotionConfig(grid_wh=(25, 25), t2=4.0, alpha=0.0, max_blobs=30), LMD)
        self.rng = rng
        self.cls_x, self.cls_y, self.det_neg = [], [], []
        self.counts = {}

    def frame(self, img, prev, gt):
        rng = self.rng
        h, w = img.shape[:2]
        grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        pgrey = None if prev is None else cv2.cvtColor(prev, cv2.COLOR_BGR2GRAY)
        proposals = [(GAD, self.gad.detect(img).xyxy)]
        regions = []
        if gt is not None:
            c = (gt[:2] + gt[2:]) / 2 + rng.uniform(-100, 100, 2)
            regions.append(region_around(c, (w, h)))
        regions.append(region_around(rng.uniform(0, 1, 2) * (w, h), (w, h)))
        for x0, y0, x1, y1 in regions:
            proposals.append((LAD, self.lad.detect(img[y0:y1, x0:x1], offset_xy=(x0, y0)).xyxy))
            if pgrey is not None:
                p, g = pgrey[y0:y1, x0:x1], grey[y0:y1, x0:x1]
                m = self.lmd.detect(p, g, estimate(p, g, self.lmd.cfg), offset_xy=(x0, y0))
                proposals.append((LMD, m.candidates.xyxy))
        if pgrey is not None:
            camera = estimate(pgrey, grey, self.gmd.cfg)
            proposals.append((GMD, self.gmd.detect(pgrey, grey, camera).candidates.xyxy))
        pos = [jitter(rng, gt)] if gt is not None else []
        for module, boxes in proposals:
            neg = []
            for b in boxes:
                y = label(b, gt)
                if y == 1:
                    pos.append(b)
                elif y == 0:
                    neg.append(b)
            rng.shuffle(neg)
            neg = neg[:MAX_NEG_PER_SOURCE]
            if neg:
                self.cls_x.append(crop_patches(img, np.array(neg, np.float32)))
                self.cls_y += [0] * len(neg)
                self.counts[module] = self.counts.get(module, 0) + len(neg)
            if module in (GAD, LAD):  # appearance false positives: local-detector hard negatives
                for b in neg[:1]:
                    crop, _ = crop_with(rng, img, b, 256)
                    if gt is None or not within_crop_reach(b, gt):
                        self.det_neg.append(crop.copy())
        if pos:
            self.cls_x.append(crop_patches(img, np.array(pos, np.float32)))
            self.cls_y += [1] * len(pos)

    def summary(self):
        return "cls=%d (drone %d; clutter by module %s) det_neg=%d" % (
            len(self.cls_y), int(np.sum(self.cls_y)), self.counts, len(self.det_neg))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model", help="detector ONNX used as GAD and LAD")
    ap.add_argument("--name", required=True)
    ap.add_argument("--scenes", type=int, default=30)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--first-seed", type=int, default=3000)
    ap.add_argument("--halmstad", nargs="*", default=[], help="splits of Halmstad clips to mine too")
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--halmstad-every", type=int, default=10)
    args = ap.parse_args()
    miner = Miner(args.model, np.random.default_rng(3))
    for s in range(args.scenes):
        prev = None
        for sf in Scene(seed=args.first_seed + s, width=1920, height=1080, fps=30.0, frames=args.frames, target_px=(4.0, 24.0)):
            if sf.index % args.every == 0 and prev is not None:
                gt = None if sf.target_xyxy is None or sf.target_visible < 0.5 else np.asarray(sf.target_xyxy, np.float32)
                miner.frame(sf.image, prev, gt)
            prev = sf.image
        print("scene %d/%d %s" % (s + 1, args.scenes, miner.summary()), flush=True)
    for split in args.halmstad:
        for clip in splits()[split]:
            boxes = labels(clip)
            prev = None
            for i, img in frames(clip):
                if i % args.halmstad_every == 0 and prev is not None:
                    drones = [b for c, b in boxes.get(i, []) if c == "DRONE"]
                    miner.frame(img, prev, drones[0] if drones else None)
                prev = img
            print("%s %s %s" % (split, clip, miner.summary()), flush=True)
    det_neg = np.stack(miner.det_neg) if miner.det_neg else None
    save_extra_sets(args.name, np.concatenate(miner.cls_x), miner.cls_y, det_neg,
                    np.full((len(miner.det_neg), 4), np.nan, np.float32))
    print("done", miner.summary())


if __name__ == "__main__":
    main()
