"""How far the tiniest drones stand out from their surroundings: real Halmstad clips against the
synthetic tiny-light-sky scenes (issue 16, deliverable 4).

For each sampled drone box: the peak |grey - median of a ring around the box| inside the box
(grey levels), and that peak over the ring's noise (1.4826 * MAD, at least 1). A renderer whose
light drones stand out much less than the real ones trains and tests the detector on a harder,
unreal case; one that makes them stand out more flatters it.

    python bench/tiny_contrast.py                   # real: visible drone boxes <= 22 px wide
    python bench/tiny_contrast.py --synthetic 300-309 --config configs/tiny-light-sky.yaml
"""

import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from training import halmstad  # noqa: E402


def contrast(grey: np.ndarray, xyxy, ring_px: int = 8):
    """(peak contrast in grey levels, peak over ring noise, sign of the peak) of one box."""
    h, w = grey.shape
    x1, y1, x2, y2 = (int(round(v)) for v in xyxy)
    x1, y1, x2, y2 = max(0, x1), max(0, y1), min(w, x2), min(h, y2)
    if x2 <= x1 or y2 <= y1:
        return None
    X1, Y1, X2, Y2 = max(0, x1 - ring_px), max(0, y1 - ring_px), min(w, x2 + ring_px), min(h, y2 + ring_px)
    outer = grey[Y1:Y2, X1:X2].astype(np.float32)
    mask = np.ones(outer.shape, bool)
    mask[y1 - Y1:y2 - Y1, x1 - X1:x2 - X1] = False
    ring = outer[mask]
    if ring.size < 16:
        return None
    med = float(np.median(ring))
    noise = max(1.0, 1.4826 * float(np.median(np.abs(ring - med))))
    diff = grey[y1:y2, x1:x2].astype(np.float32) - med
    k = int(np.argmax(np.abs(diff)))
    peak = float(diff.flat[k])
    return abs(peak), abs(peak) / noise, np.sign(peak)


def real(max_w: float, per_clip: int):
    out = []
    sp = halmstad.splits()
    clips = sorted(set(sp["train"]) | set(sp["val"]))
    for clip in clips:
        boxes = {i: [b for c, b in v if c == "DRONE" and b[2] - b[0] <= max_w]
                 for i, v in halmstad.labels(clip).items()}
        boxes = {i: v for i, v in boxes.items() if v}
        if not boxes:
            continue
        keys = sorted(boxes)
        want = set(keys[int(j)] for j in np.linspace(0, len(keys) - 1, min(per_clip, len(keys))))
        for i, img in halmstad.frames(clip):
            if i in want:
                c = contrast(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), boxes[i][0])
                if c is not None:
                    out.append((clip,) + c)
            if i >= keys[-1]:
                break
    return out


def synthetic(seeds, config: str, every: int, frames: int):
    from payload.capture.synthetic import scene_of
    from payload.config import load_config
    cfg = load_config(config) if config else None
    out = []
    for seed in seeds:
        sc = cfg.capture.synthetic.model_copy(update={"seed": seed, "frames": frames})
        for f in scene_of(sc):
            if f.index % every or f.target_xyxy is None or f.target_visible < 0.9:
                continue
            c = contrast(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY), f.target_xyxy)
            if c is not None:
                out.append(("SYN_%d" % seed,) + c)
    return out


def report(rows, title):
    a = np.array([r[1] for r in rows])
    s = np.array([r[2] for r in rows])
    bright = np.mean([r[3] > 0 for r in rows])
    print("%s: %d boxes from %d clips, %.0f %% brighter than the ring" % (
        title, len(rows), len({r[0] for r in rows}), 100 * bright))
    print("  peak contrast, grey levels  q10/25/50/75: %s" % " / ".join("%.0f" % v for v in np.percentile(a, [10, 25, 50, 75])))
    print("  peak over ring noise        q10/25/50/75: %s" % " / ".join("%.1f" % v for v in np.percentile(s, [10, 25, 50, 75])))
    if bright:
        b = a[np.array([r[3] > 0 for r in rows])]
        print("  the brighter ones' contrast  q10/25/50/75: %s" % " / ".join("%.0f" % v for v in np.percentile(b, [10, 25, 50, 75])))
    per = {}
    for r in rows:
        per.setdefault(r[0], []).append(r[1])
    print("  per clip median: " + ", ".join("%s %.1f" % (k, np.median(v)) for k, v in sorted(per.items())))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--synthetic", help="seed range A-B instead of the real clips")
    ap.add_argument("--config", default="configs/tiny-light-sky.yaml")
    ap.add_argument("--max-w", type=float, default=22.0, help="real boxes at most this wide (px)")
    ap.add_argument("--per-clip", type=int, default=4)
    ap.add_argument("--every", type=int, default=15, help="synthetic: every Nth frame")
    ap.add_argument("--frames", type=int, default=150)
    a = ap.parse_args()
    if a.synthetic:
        lo, _, hi = a.synthetic.partition("-")
        seeds = range(int(lo), int(hi or lo) + 1)
        report(synthetic(seeds, a.config, a.every, a.frames), "synthetic %s (%s)" % (a.synthetic, a.config))
    else:
        report(real(a.max_w, a.per_clip), "Halmstad visible drones, boxes <= %.0f px wide" % a.max_w)


if __name__ == "__main__":
    main()
