"""Validate the patch classifier on Halmstad val clips through payload.detect.classifier.

Positives: the labelled drone boxes of `val` clips. Negatives: drone-sized random background
boxes of the same frames, frame-difference blobs away from the drone, and every labelled
bird / airliner / helicopter box in `negatives_val`.

  python training/eval_cls.py payload/models/glad_classifier.onnx [--every 10]
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import ClassifierConfig  # noqa: E402
from payload.detect.classifier import AppearanceClassifier  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from payload.types import Detections  # noqa: E402
from training.build_cache import diff_blobs, random_boxes  # noqa: E402
from training.halmstad import frames, labels, splits  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--threshold", type=float, default=0.5)
    args = ap.parse_args()
    clf = AppearanceClassifier(OnnxModel(args.model, threads=2, expected_inputs={"patches": 3}), ClassifierConfig())
    rng = np.random.default_rng(0)
    probs = {"drone": [], "background": [], "motion blobs": [], "birds/planes/helis": []}
    for split, positive in (("val", True), ("negatives_val", False)):
        for clip in splits()[split]:
            lab = labels(clip)
            prev = None
            for i, img in frames(clip):
                if i % args.every == 0:
                    boxes = [b for _, b in lab.get(i, [])]
                    groups = {}
                    if positive:
                        groups["drone"] = boxes
                        groups["background"] = random_boxes(rng, img, boxes, 3)
                        if prev is not None:
                            groups["motion blobs"] = diff_blobs(prev, img, boxes, 3)
                    else:
                        groups["birds/planes/helis"] = boxes
                    for name, bs in groups.items():
                        if bs:
                            probs[name].append(clf.probabilities(img, Detections(np.array(bs), np.ones(len(bs)), "GMD")))
                prev = img
    for name, p in probs.items():
        p = np.concatenate(p) if p else np.zeros(0)
        rate = float((p >= args.threshold).mean()) if len(p) else float("nan")
        print("%-20s n=%5d  accepted (prob >= %.2f): %.3f" % (name, len(p), args.threshold, rate))


if __name__ == "__main__":
    main()
