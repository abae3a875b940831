"""Per-module time of GLAD on a clip, frame by frame: median, p95, p99 and max per module.

The frames are decoded first and held in memory, so only the detector is timed (no decoding, no
MAVLink); each module's time is what GladResult.timings_ms says. Prints the frames on which a stage
degraded (its work capped to stay in its budget) too.

  PYTHONPATH=. python bench/frame_budget.py CLIP.mp4 [--frames 150] [--repeat 1] [--config FILE]
"""

import argparse
import time
from collections import Counter

import cv2
import numpy as np

from payload.config import Config, load_config
from payload.detect.pipeline import Glad
from payload.types import Frame


def frames_of(path, limit):
    cap = cv2.VideoCapture(path)
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    out = []
    while not limit or len(out) < limit:
        ok, image = cap.read()
        if not ok:
            break
        out.append(Frame(image, len(out), int(len(out) * 1e9 / fps), 0))
    cap.release()
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip")
    ap.add_argument("--frames", type=int, default=0, help="0 = the whole clip")
    ap.add_argument("--repeat", type=int, default=1, help="passes over the clip (timings pooled)")
    ap.add_argument("--config", default=None)
    args = ap.parse_args()
    cfg = load_config(args.config) if args.config else Config()
    frames = frames_of(args.clip, args.frames)
    glad = Glad(cfg.detector)
    per_frame, totals, degraded = [], [], Counter()
    for _ in range(args.repeat):
        glad.reset()
        for frame in frames:
            t0 = time.perf_counter()
            result = glad.process(frame)
            totals.append((time.perf_counter() - t0) * 1000.0)
            per_frame.append(result.timings_ms)
            degraded.update(getattr(result, "degraded", ()))
    h, w = frames[0].image.shape[:2]
    print("%s %dx%d frames=%d passes=%d" % (args.clip, w, h, len(frames), args.repeat))
    print("%-11s %5s %7s %7s %7s %7s" % ("module", "runs", "median", "p95", "p99", "max"))
    names = list(dict.fromkeys(k for t in per_frame for k in t))
    for name in names + ["total"]:
        ms = np.array(totals if name == "total" else [t[name] for t in per_frame if name in t])
        print("%-11s %5d %7.2f %7.2f %7.2f %7.2f" % (name, len(ms), np.median(ms), np.percentile(ms, 95),
                                                   np.percentile(ms, 99), ms.max()))
    if degraded:
        print("degraded frames: " + " ".join("%s=%d" % kv for kv in sorted(degraded.items())))


if __name__ == "__main__":
    main()
