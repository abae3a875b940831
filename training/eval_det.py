"""Quick validation of a detector ONNX on the Halmstad val clips, through the payload's own detector.

global: whole frames letterboxed into --global-wh, all detections >= --global-conf, IoU > 0.5;
        plus false alarms per frame on negatives_val clips (birds, airliners, helicopters).
local:  a --crop square search region at native resolution with the drone at a random
        place inside, the single best detection >= --local-conf (the switcher's pick), IoU > 0.5.

  python training/eval_det.py payload/models/glad_global.onnx [--every 5]
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import AppearanceConfig  # noqa: E402
from payload.detect.appearance import AppearanceDetector  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from training.build_cache import iou  # noqa: E402
from training.halmstad import frames, labels, splits  # noqa: E402


def prf(tp, npred, ngt):
    p, r = tp / max(1, npred), tp / max(1, ngt)
    return p, r, 2 * p * r / max(1e-9, p + r)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--global-wh", type=int, nargs=2, default=(640, 384))
    ap.add_argument("--global-conf", type=float, default=0.5)
    ap.add_argument("--local-conf", type=float, default=0.1)
    ap.add_argument("--local-model", default=None)
    ap.add_argument("--crop", type=int, default=300)
    ap.add_argument("--split", default="val")
    ap.add_argument("--negatives", type=int, default=10, help="how many negatives_val clips to scan")
    args = ap.parse_args()
    gm = OnnxModel(args.model, threads=2)
    lm = OnnxModel(args.local_model, threads=2) if args.local_model else gm
    gad = AppearanceDetector(gm, AppearanceConfig(confidence=args.global_conf, input_wh=tuple(args.global_wh)), "GAD")
    lad = AppearanceDetector(lm, AppearanceConfig(confidence=args.local_conf, input_wh=(320, 320)), "LAD")
    rng = np.random.default_rng(0)
    g = dict(tp=0, pred=0, gt=0)
    loc = dict(tp=0, pred=0, gt=0)
    t_g, t_l, n = 0.0, 0.0, 0
    for clip in splits()[args.split]:
        lab = labels(clip)
        c = dict(tp=0, pred=0, gt=0)
        for i, img in frames(clip):
            if i % args.every:
                continue
            gts = [b for cls, b in lab.get(i, []) if cls == "DRONE"]
            t = time.perf_counter()
            dets = gad.detect(img)
            t_g += time.perf_counter() - t
            n += 1
            used = set()
            for d in dets.xyxy:
                for k, b in enumerate(gts):
                    if k not in used and iou(d, b) > 0.5:
                        used.add(k)
                        c["tp"] += 1
                        break
            c["pred"] += len(dets)
            c["gt"] += len(gts)
            if gts:
                b = gts[0]
                h, w = img.shape[:2]
                s = args.crop
                x0 = int(np.clip(rng.uniform(b[2] - s + 8, b[0] - 8), 0, w - s))
                y0 = int(np.clip(rng.uniform(b[3] - s + 8, b[1] - 8), 0, h - s))
                t = time.perf_counter()
                ld = lad.detect(img[y0:y0 + s, x0:x0 + s], offset_xy=(x0, y0))
                t_l += time.perf_counter() - t
                loc["gt"] += 1
                if len(ld):
                    best = ld.xyxy[int(np.argmax(ld.score))]
                    loc["pred"] += 1
                    loc["tp"] += int(iou(best, b) > 0.5)
        for k in g:
            g[k] += c[k]
        print("%s global P=%.3f R=%.3f F=%.3f (tp=%d pred=%d gt=%d)" % ((clip,) + prf(c["tp"], c["pred"], c["gt"]) + (c["tp"], c["pred"], c["gt"])), flush=True)
    print("GLOBAL %dx%d conf=%.2f P=%.3f R=%.3f F=%.3f  (%.1f ms/frame incl. letterbox)"
          % ((*args.global_wh, args.global_conf) + prf(g["tp"], g["pred"], g["gt"]) + (1000 * t_g / max(1, n),)))
    print("LOCAL crop=%d conf=%.2f top-1 P=%.3f R=%.3f F=%.3f  (%.1f ms/crop)"
          % ((args.crop, args.local_conf) + prf(loc["tp"], loc["pred"], loc["gt"]) + (1000 * t_l / max(1, loc["gt"]),)))
    fa, nf = 0, 0
    for clip in splits()["negatives_val"][: args.negatives]:
        for i, img in frames(clip):
            if i % (args.every * 3):
                continue
            fa += len(gad.detect(img))
            nf += 1
    print("NEGATIVES_VAL global false alarms: %d in %d frames (%.3f per frame)" % (fa, nf, fa / max(1, nf)))


if __name__ == "__main__":
    main()
