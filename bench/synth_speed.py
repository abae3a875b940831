"""Rendering speed of the synthetic scene on ONE core (the brief: > 30 fps at 1080p).

    python bench/synth_speed.py [--width 1920 --height 1080 --frames 300 --seed 1]

The one-off backdrop rendering is timed separately from the per-frame loop.
"""

import argparse
import os
import sys
import time

import cv2

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from payload.synth.scene import Scene  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1, help="cv2.setNumThreads (default 1 core)")
    args = ap.parse_args()
    cv2.setNumThreads(args.threads)
    t0 = time.perf_counter()
    frames = iter(Scene(seed=args.seed, width=args.width, height=args.height, frames=args.frames))
    next(frames)
    t1 = time.perf_counter()
    n = sum(1 for _ in frames)
    t2 = time.perf_counter()
    dt = t2 - t1
    print(f"synth {args.width}x{args.height} setup_s={t1 - t0:.2f} frames={n} fps={n / dt:.1f} "
          f"ms_per_frame={1000 * dt / max(n, 1):.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
