"""Milliseconds per inference of the shipped (or given) models with ONNX Runtime on this machine.

  python bench/model_speed.py [--threads 2] [--repeat 50] [--backend cpu]
Prints one line per model and input size: median and 90th-percentile ms of session.run
alone, and of AppearanceDetector.detect (letterbox + run + decode + NMS) on a blank frame.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import AppearanceConfig  # noqa: E402
from payload.detect.appearance import AppearanceDetector  # noqa: E402
from payload.detect.factory import builtin_model_path  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402


def timed(fn, repeat):
    for _ in range(3):
        fn()
    ms = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ms.append((time.perf_counter() - t) * 1000)
    return np.median(ms), np.percentile(ms, 90)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=50)
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--global-model", default=builtin_model_path("global"))
    ap.add_argument("--local-model", default=builtin_model_path("local"))
    ap.add_argument("--classifier-model", default=builtin_model_path("classifier"))
    args = ap.parse_args()
    cases = [
        ("global", args.global_model, (640, 384), (512, 640)),
        ("global", args.global_model, (640, 512), (512, 640)),
        ("local", args.local_model, (320, 320), (300, 300)),
    ]
    for name, path, input_wh, frame_hw in cases:
        model = OnnxModel(path, backend=args.backend, threads=args.threads, warmup_hw=(input_wh[1], input_wh[0]))
        x = np.random.default_rng(0).random((1, 3, input_wh[1], input_wh[0]), dtype=np.float32)
        med, p90 = timed(lambda m=model, x=x: m.run({"images": x}), args.repeat)
        det = AppearanceDetector(model, AppearanceConfig(confidence=0.1, input_wh=input_wh), "GAD")
        frame = np.random.default_rng(1).integers(0, 255, frame_hw + (3,), dtype=np.uint8)
        dmed, dp90 = timed(lambda d=det, f=frame: d.detect(f), args.repeat)
        print("%-10s %-20s input=%dx%d run: median %.2f ms p90 %.2f ms | detect(): median %.2f ms p90 %.2f ms"
              % (name, os.path.basename(path), input_wh[0], input_wh[1], med, p90, dmed, dp90))
    clf = OnnxModel(args.classifier_model, backend=args.backend, threads=args.threads, expected_inputs={"patches": 3})
    for n in (1, 8, 32):
        x = np.random.default_rng(0).random((n, 3, 32, 32), dtype=np.float32)
        med, p90 = timed(lambda x=x: clf.run({"patches": x}), args.repeat)
        print("classifier %-20s batch=%d run: median %.2f ms p90 %.2f ms" % (os.path.basename(args.classifier_model), n, med, p90))


if __name__ == "__main__":
    main()
