"""Time the motion detector: a 1920x1080 global pass (GMD) and a 300x300 local pass (LMD).

Synthetic textured ground panning 3 px per frame with one textured mover; prints the median
and 90th-percentile ms per pass, with and without the homography estimate.
Run: python bench/motion_speed.py [--repeats 30]
"""

import argparse
import time

import cv2
import numpy as np

from payload.config import MotionConfig
from payload.detect.ego_motion import estimate
from payload.detect.motion import MotionDetector


def frame_pair(w, h, seed=1):
    rng = np.random.default_rng(seed)
    ground = rng.integers(0, 256, (h + 40, w + 40)).astype(np.float32)
    ground = cv2.normalize(cv2.GaussianBlur(ground, (0, 0), 3.0), None, 60, 200, cv2.NORM_MINMAX).astype(
        np.uint8
    )
    prev = ground[20 : 20 + h, 20 : 20 + w].copy()
    cur = ground[22 : 22 + h, 23 : 23 + w].copy()
    mover = cv2.normalize(rng.integers(0, 256, (30, 30)).astype(np.float32), None, 0, 90, cv2.NORM_MINMAX)
    mover = mover.astype(np.uint8)
    prev[h // 2 : h // 2 + 30, w // 2 : w // 2 + 30] = mover
    cur[h // 2 + 5 : h // 2 + 35, w // 2 + 8 : w // 2 + 38] = mover
    return prev, cur


def timed(fn, repeats):
    fn()  # warm-up
    ms = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ms.append((time.perf_counter() - t0) * 1e3)
    return np.median(ms), np.percentile(ms, 90)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--threads", type=int, default=-1, help="cv2.setNumThreads; -1 = OpenCV default")
    args = parser.parse_args()
    if args.threads >= 0:
        cv2.setNumThreads(args.threads)
    cfg = MotionConfig()
    print(f"opencv {cv2.__version__} threads={cv2.getNumThreads()}")
    for label, (w, h), module in (
        ("global 1920x1080", (1920, 1080), "GMD"),
        ("local 300x300", (300, 300), "LMD"),
    ):
        bench_one(label, MotionDetector(cfg, module), *frame_pair(w, h), args.repeats)


def bench_one(label, det, prev, cur, repeats):
    est = estimate(prev, cur, det.cfg)
    result = det.detect(prev, cur, est)
    full = timed(lambda: det.detect(prev, cur, estimate(prev, cur, det.cfg)), repeats)
    homography = timed(lambda: estimate(prev, cur, det.cfg), repeats)
    given = timed(lambda: det.detect(prev, cur, est), repeats)
    print(
        f"{label:17s} detect {full[0]:6.2f} ms (p90 {full[1]:6.2f}) | homography {homography[0]:6.2f} ms | "
        f"detect with given H {given[0]:6.2f} ms | candidates={len(result.candidates)} "
        f"detections={len(result.detections)}"
    )


if __name__ == "__main__":
    main()
