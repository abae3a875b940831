"""Where a synthetic scene's drone frames go, frame by frame (issue 16's tiny white drone): reported
on the drone, reported elsewhere, coasting, a lock followed near it but not reported (the lock check
or the verifier not yet convinced), a lock elsewhere, or searching.

    python bench/tiny_trace.py --config configs/tiny-light-sky.yaml 300-309
    python bench/tiny_trace.py --config configs/tiny-light-sky.yaml 304 309 --frames 150

Per seed one letter a labelled frame: T reported with its centre in the drone's box, W reported
elsewhere, o coasting, n following a lock whose search region holds the drone's centre, f following
one elsewhere, s searching; the same in capitals (t w O N F, and _ for searching) where the drone
stands out less than 5x its ring's noise in every colour channel (bench/tiny_contrast.py).
Then each share per seed, and over every seed. "reported" is what `glad-payload eval` counts as
centre recall.
"""

import argparse
import collections
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from tiny_contrast import contrast  # noqa: E402

from payload.config import Config, load_config  # noqa: E402
from payload.errors import ConfigError  # noqa: E402
from payload.eval.labels import load_labels  # noqa: E402
from payload.eval.metrics import centre_match_frame  # noqa: E402
from payload.offline import iter_glad, synthetic_clip  # noqa: E402
from payload.synth import seed_range  # noqa: E402

KINDS = ("reported", "wrong", "coasting", "near", "far", "searching")
LETTER = {"reported": "T", "wrong": "W", "coasting": "o", "near": "n", "far": "f", "searching": "s"}
HIDDEN = {"reported": "t", "wrong": "w", "coasting": "O", "near": "N", "far": "F", "searching": "_"}
VISIBLE_OVER_NOISE = 5.0  # the drone's peak over its ring's noise (1.4826 x MAD)


def _inside(xy, box) -> bool:
    return box[0] <= xy[0] <= box[2] and box[1] <= xy[1] <= box[3]


def kind_of(result, box) -> str:
    """What the frame's result did with the drone labelled at ``box`` (xyxy)."""
    centre = ((box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0)
    if len(result.detections):
        # eval's own centre-in-box match: "reported" is what it counts as centre recall
        return "reported" if centre_match_frame(result.detections[:1], box)[0] >= 0 else "wrong"
    if result.target is not None:
        return "coasting"
    if result.following:
        region = result.region_xyxy
        return "near" if region is not None and _inside(centre, region) else "far"
    return "searching"


def visible(image: np.ndarray, box) -> bool:
    """Whether the drone stands out at least VISIBLE_OVER_NOISE x its ring's noise in a colour channel."""
    peaks = [contrast(image[:, :, ch], box) for ch in range(image.shape[2])]
    return max((p[1] for p in peaks if p is not None), default=0.0) >= VISIBLE_OVER_NOISE


def trace(cfg, seed: int, frames: int):
    """(letters, Counter of kinds) of one scene."""
    letters, counts = [], collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        clip = synthetic_clip(cfg, tmp, frames, seed, None, video=False)
        truth = load_labels(clip.labels)
        for frame, result in iter_glad(clip.video, cfg, progress=False, capture=clip.capture):
            boxes = truth.get(frame.index, np.zeros((0, 4)))
            if not len(boxes):
                continue
            kind = kind_of(result, boxes[0])
            counts[kind] += 1
            letters.append((LETTER if visible(frame.image, boxes[0]) else HIDDEN)[kind])
    return "".join(letters), counts


def shares(counts) -> str:
    n = sum(counts.values()) or 1
    return " ".join("%s %.3f" % (k, counts[k] / n) for k in KINDS)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seeds", nargs="+", type=seed_range, metavar="SEED", help="seeds or ranges, e.g. 300-309")
    ap.add_argument("--frames", type=int, default=150, help="frames per scene")
    ap.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    args = ap.parse_args()
    if args.frames < 1:
        raise SystemExit("--frames %d: expected at least 1 frame" % args.frames)
    try:
        cfg = load_config(args.config) if args.config else Config()
    except ConfigError as exc:
        raise SystemExit(str(exc)) from None
    total = collections.Counter()
    for seed in [s for group in args.seeds for s in group]:
        letters, counts = trace(cfg, seed, args.frames)
        print(letters)
        print("seed %d: %d labelled frames: %s" % (seed, sum(counts.values()), shares(counts)), flush=True)
        total.update(counts)
    print("all seeds: %d labelled frames: %s" % (sum(total.values()), shares(total)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
