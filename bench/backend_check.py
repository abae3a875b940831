"""The shipped models on a GPU backend against the CPU, on the same real inputs.

  python bench/backend_check.py CLIP --backend cuda [--frames 20]

For every shipped model, inputs made from CLIP's frames the way GLAD makes them (GAD: the whole
frame letterboxed; LAD: 320x320 crops at native resolution; the classifier: 32x32 patches; the
verifier: rows of random features; the classifier's patches around 1-40 random boxes, cut as GLAD
cuts them, as varied in number as a frame's candidates), run through a CPU session and a session on ``--backend``
(``payload.detect.onnx_model.OnnxModel``, the payload's own session code). Prints per model the
provider ORT actually chose, the largest output difference, whether the detections above the
config's confidence are the same boxes (within 0.5 px), and the median / p99 ms per run on each.
Exit status 1 when a backend's detections differ from the CPU's.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.capture.file import VideoFileSource  # noqa: E402
from payload.config import Config  # noqa: E402
from payload.detect.appearance import decode, letterbox  # noqa: E402
from payload.detect.factory import builtin_model_path  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from payload.detect.patches import crop_patches, patches_to_input  # noqa: E402
from payload.errors import SourceError  # noqa: E402


def frames_of(clip, n):
    """The clip's first ``n`` images, read by the payload's own file source."""
    try:
        with VideoFileSource(clip) as source:
            out = [frame.image for _, frame in zip(range(n), source)]
    except SourceError as exc:
        sys.exit("backend_check: %s" % exc)
    if not out:
        sys.exit("backend_check: %s: no frames could be read" % clip)
    return out


def inputs(frames, cfg, rng):
    gwh = tuple(cfg.detector.global_.appearance.input_wh)
    lwh = tuple(cfg.detector.local.appearance.input_wh)
    glob = [letterbox(f, gwh)[0].copy() for f in frames]
    local, patches = [], []
    for f in frames:
        h, w = f.shape[:2]
        x, y = rng.integers(0, max(1, w - lwh[0])), rng.integers(0, max(1, h - lwh[1]))
        local.append(letterbox(f[y:y + lwh[1], x:x + lwh[0]], lwh)[0].copy())
        # as many candidate boxes (4-40 px) as a frame's candidates: the batch size varies
        n = int(rng.integers(1, 41))
        xy = rng.uniform((0, 0), (w - 40, h - 40), (n, 2))
        boxes = np.concatenate([xy, xy + rng.uniform(4, 40, (n, 2))], axis=1)
        patches.append(patches_to_input(crop_patches(f, boxes)))
    return {"global": (gwh, glob), "local": (lwh, local), "classifier": (None, patches)}


def timed(model, feeds):
    outs, ms = [], []
    for feed in feeds:
        t = time.perf_counter()
        outs.append(model.run(feed)[0])
        ms.append((time.perf_counter() - t) * 1000.0)
    return outs, np.median(ms), np.percentile(ms, 99)


def same_boxes(a, b, confidence, input_wh):
    ba, sa = decode(a, confidence, input_wh)
    bb, sb = decode(b, confidence, input_wh)
    if len(ba) != len(bb):
        return False
    return bool(np.all(np.abs(np.sort(ba, axis=0) - np.sort(bb, axis=0)) <= 0.5))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip")
    ap.add_argument("--backend", default="cuda", choices=("cpu", "cuda", "tensorrt"))
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3, help="passes over the inputs (the first warms up)")
    args = ap.parse_args()
    cfg = Config()
    rng = np.random.default_rng(0)
    made = inputs(frames_of(args.clip, args.frames), cfg, rng)
    verifier_rows = [rng.normal(size=(4, 32, 25)).astype(np.float32) for _ in range(args.frames)]
    made["verifier"] = (None, verifier_rows)
    names = {"global": "images", "local": "images", "classifier": "patches", "verifier": "tracks"}
    expected = {"global": {"images": 3}, "local": {"images": 3}, "classifier": {"patches": 3},
                "verifier": {"tracks": (None, None, None)}}
    confidence = cfg.detector.global_.appearance.confidence
    failed = False
    for name in ("global", "local", "classifier", "verifier"):
        input_wh, data = made[name]
        feeds = [{names[name]: x} for x in data]
        row = []
        results = {}
        for backend in ("cpu", args.backend):
            model = OnnxModel(builtin_model_path(name), backend=backend, threads=cfg.detector.threads,
                              expected_inputs=expected[name], varying_batch=name == "classifier",
                              warmup_hw=(input_wh[1], input_wh[0]) if input_wh else None)
            for _ in range(args.repeat - 1):
                timed(model, feeds)
            outs, med, p99 = timed(model, feeds)
            results[backend] = outs
            row.append("%s[%s] %.2f/%.2f ms" % (backend, model.providers[0].replace("ExecutionProvider", ""), med, p99))
        diff = max(float(np.max(np.abs(a - b))) for a, b in zip(results["cpu"], results[args.backend]))
        verdict = ""
        if input_wh is not None:
            same = all(same_boxes(a, b, confidence, input_wh) for a, b in zip(results["cpu"], results[args.backend]))
            verdict = " detections %s" % ("same" if same else "DIFFER")
            failed |= not same
        else:
            agree = np.mean([np.array_equal(a.argmax(-1) if a.shape[-1] > 1 else a > 0.5,
                                            b.argmax(-1) if b.shape[-1] > 1 else b > 0.5)
                             for a, b in zip(results["cpu"], results[args.backend])])
            verdict = " decisions agree %.3f" % agree
        print("%-10s %s  max |diff| %.2e%s" % (name, "  ".join(row), diff, verdict), flush=True)
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
