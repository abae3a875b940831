"""A/B of ONNX Runtime thread settings on the whole pipeline: spinning on/off, threads default/1.

  PYTHONPATH=. python bench/ort_threads.py CLIP.mp4 [CONFIG.yaml]
The spinning switch is forced through a SessionOptions subclass here only to compare both ways;
the payload always turns spinning off (payload/detect/onnx_model.py). Variants are interleaved
so that a changing machine load hits them alike.
"""

import sys

import numpy as np
import onnxruntime as ort

from payload.bench.profile import run_bench
from payload.bench.runners import build_runner
from payload.config import config_with, load_config

_Original = ort.SessionOptions


_SPINNING = "session.intra_op.allow_spinning"


def options_class(spin):
    class Options(_Original):
        def __init__(self):
            super().__init__()
            _Original.add_session_config_entry(self, _SPINNING, "1" if spin else "0")

        def add_session_config_entry(self, key, value):
            if key != _SPINNING:  # the payload's own setting is overruled for the comparison
                _Original.add_session_config_entry(self, key, value)

    return Options


def main():
    source = sys.argv[1]
    base = load_config(sys.argv[2] if len(sys.argv) > 2 else None)
    variants = [("spin, threads=default", True, 0), ("no spin, threads=default", False, 0),
                ("no spin, threads=1", False, 1), ("spin, threads=1", True, 1)]
    results = {v[0]: [] for v in variants}
    for _ in range(2):
        for name, spin, threads in variants:
            ort.SessionOptions = options_class(spin)
            cfg = config_with(base, **{"detector.threads": threads})
            report = run_bench(cfg, source, build_runner(cfg, "glad"), frames=150)
            results[name].append((report.fps_end_to_end, report.latency_p99_ms))
            print("%-26s fps %.1f p99 %.1f ms" % ((name,) + results[name][-1]), flush=True)
    for name, values in results.items():
        print("%-26s mean fps %.1f  mean p99 %.1f ms" % (name, np.mean([v[0] for v in values]),
                                                         np.mean([v[1] for v in values])))


if __name__ == "__main__":
    main()
