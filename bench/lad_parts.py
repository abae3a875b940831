"""Where the local appearance stage's time goes inside GLAD: its network run against the whole stage.

Runs GLAD on a clip and times, on every local frame, LAD as the pipeline does (crop, letterbox,
input conversion, the ONNX run, decoding, NMS) and the ONNX run alone inside it.

  PYTHONPATH=. python bench/lad_parts.py CLIP.mp4 [--threads N] [--frames N]
"""

import argparse
import time

import numpy as np

from bench.frame_budget import frames_of  # noqa: I001
from payload.config import Config, config_with
from payload.detect.pipeline import Glad


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip")
    ap.add_argument("--threads", type=int, default=0, help="detector.threads (0 = the payload's default)")
    ap.add_argument("--frames", type=int, default=0)
    args = ap.parse_args()
    glad = Glad(config_with(Config(), **{"detector.threads": args.threads}).detector)
    model = glad.models.local_appearance.model
    run, net = model.run, []

    def timed_run(feeds):
        t = time.perf_counter()
        out = run(feeds)
        net.append((time.perf_counter() - t) * 1000.0)
        return out

    model.run = timed_run
    stage = []
    for frame in frames_of(args.clip, args.frames):
        net_before = len(net)
        result = glad.process(frame)
        if "LAD" in result.timings_ms and len(net) > net_before:
            stage.append((result.timings_ms["LAD"], net[-1]))
    ms = np.array(stage)
    print("%s threads=%d local frames=%d" % (args.clip, model.session.get_session_options().intra_op_num_threads, len(ms)))
    for name, col in (("LAD stage", ms[:, 0]), ("network run", ms[:, 1]), ("rest", ms[:, 0] - ms[:, 1])):
        print("%-12s median %6.2f  p95 %6.2f  p99 %6.2f ms" % (name, np.median(col), np.percentile(col, 95),
                                                             np.percentile(col, 99)))


if __name__ == "__main__":
    main()
