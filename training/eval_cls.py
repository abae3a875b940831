"""Validate the patch classifier on Halmstad val clips through payload.detect.classifier.

Positives: the labelled drone boxes of `val` clips. Negatives: drone-sized random background
boxes of the same frames, frame-difference blobs away from the drone, and every labelled
bird / airliner / helicopter box in `negatives_val`.

  python training/eval_cls.py payload/models/glad_classifier.onnx [--every 10] [--plot docs/img/pr_classifier.png]

``--plot``: the threshold curve of each group (the share of drone boxes kept against the share
of that group kept, as the drone probability threshold falls), with the shipped thresholds
marked: ``detector.classifier.threshold`` and ``confirm_threshold`` (needs matplotlib, as bench/plot_results.py).
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
    ap.add_argument("--plot", help="write the threshold curves to this PNG")
    args = ap.parse_args()
    clf = AppearanceClassifier(OnnxModel(args.model, threads=2, expected_inputs={"patches": 3}), ClassifierConfig())
    rng = np.random.default_rng(0)
    probs = {"drone": [], "background": [], "motion blobs": [], "negatives_val birds/planes/helis": []}
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
                        groups["negatives_val birds/planes/helis"] = boxes
                    for name, bs in groups.items():
                        if bs:
                            probs[name].append(clf.probabilities(img, Detections(np.array(bs), np.ones(len(bs)), "GMD")))
                prev = img
    probs = {name: np.concatenate(p) if p else np.zeros(0) for name, p in probs.items()}
    for name, p in probs.items():
        rate = float((p >= args.threshold).mean()) if len(p) else float("nan")
        print("%-33s n=%5d  accepted (prob >= %.2f): %.3f" % (name, len(p), args.threshold, rate))
    if args.plot:
        plot(probs, os.path.basename(args.model), args.plot)
        print("wrote %s" % args.plot)


def plot(probs, model_name, out_png):
    """Drone boxes kept against each clutter group's boxes kept, over every threshold; dots at the
    shipped classifier threshold and lock-confirmation threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from payload.config import ClassifierConfig

    cfg = ClassifierConfig()
    marks = sorted({cfg.threshold, cfg.confirm_threshold})
    drone = probs["drone"]
    grid = np.linspace(1.0, 0.0, 201)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, p in probs.items():
        if name == "drone" or not len(p):
            continue
        line, = ax.plot([(p >= t).mean() for t in grid], [(drone >= t).mean() for t in grid], lw=1.5,
                        label="%s (n=%d)" % (name, len(p)))
        for t in marks:
            x, y = (p >= t).mean(), (drone >= t).mean()
            ax.plot(x, y, "o", ms=4, color=line.get_color())
            ax.annotate("%.1f" % t, (x, y), fontsize=7, xytext=(3, -9), textcoords="offset points")
    ax.set_xscale("symlog", linthresh=0.01)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("clutter boxes accepted (log scale above 0.01)")
    ax.set_ylabel("drone boxes of val accepted (n=%d)" % len(drone))
    ax.set_title("Classifier %s: drone probability thresholds (dots: %s)"
                 % (model_name, ", ".join("%.1f" % t for t in marks)), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
