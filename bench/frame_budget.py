"""Per-module time of GLAD (or a baseline runner) on a clip, frame by frame: median, p95, p99, max.

The frames are decoded first and held in memory, so only the detector is timed (no decoding, no
MAVLink); each module's time is what GladResult.timings_ms says. ``--clock cpu`` times the same
spans in CPU seconds of the whole process (every thread: ONNX Runtime's and OpenCV's workers
included) instead of wall-clock: on a machine shared with other work a preempted frame costs no
more CPU, so the CPU figures compare versions fairly whatever the load. Prints the frames on which
a stage degraded (left work out to stay in its budget) too.

  PYTHONPATH=. python bench/frame_budget.py CLIP.mp4 [--runner glad|tiled] [--clock wall|cpu]
      [--frames N] [--repeat N] [--config FILE]
"""

import argparse
import os
import sys
import time
import types
from collections import Counter

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.bench.runners import build_runner  # noqa: E402
from payload.config import Config, load_config  # noqa: E402
from payload.types import Frame  # noqa: E402


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


def use_clock(clock):
    """Make the detector modules time their spans with ``clock`` (they call time.perf_counter)."""
    import payload.bench.runners as runners
    import payload.detect.pipeline as pipeline

    for module in (pipeline, runners):
        module.time = types.SimpleNamespace(perf_counter=clock)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip")
    ap.add_argument("--runner", default="glad", choices=("glad", "global", "tiled"))
    ap.add_argument("--clock", default="wall", choices=("wall", "cpu"))
    ap.add_argument("--frames", type=int, default=0, help="0 = the whole clip")
    ap.add_argument("--repeat", type=int, default=1, help="passes over the clip (timings pooled)")
    ap.add_argument("--config", default=None)
    args = ap.parse_args()
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    use_clock(clock)
    cfg = load_config(args.config) if args.config else Config()
    frames = frames_of(args.clip, args.frames)
    runner = build_runner(cfg, args.runner)
    per_frame, totals, degraded = [], [], Counter()
    for _ in range(args.repeat):
        runner.reset()
        for frame in frames:
            t0 = clock()
            result = runner.process(frame)
            totals.append((clock() - t0) * 1000.0)
            per_frame.append(result.timings_ms)
            degraded.update(getattr(result, "degraded", {}).keys())
    h, w = frames[0].image.shape[:2]
    print("%s %dx%d runner=%s clock=%s frames=%d passes=%d load=%.1f" % (
        args.clip, w, h, args.runner, args.clock, len(frames), args.repeat, os.getloadavg()[0]))
    print("%-11s %5s %7s %7s %7s %7s" % ("module", "runs", "median", "p95", "p99", "max"))
    names = list(dict.fromkeys(k for t in per_frame for k in t))
    for name in names + ["frame"]:
        ms = np.array(totals if name == "frame" else [t[name] for t in per_frame if name in t])
        print("%-11s %5d %7.2f %7.2f %7.2f %7.2f" % (name, len(ms), np.median(ms), np.percentile(ms, 95),
                                                   np.percentile(ms, 99), ms.max()))
    print("frame sum %.0f ms" % sum(totals))
    if degraded:
        print("degraded frames: " + " ".join("%s=%d" % kv for kv in sorted(degraded.items())))


if __name__ == "__main__":
    main()
