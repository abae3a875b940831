"""Hard negatives for the global detector: what it fires on in synthetic scenes that is not the drone.

Runs a detector ONNX the way the global stage does (whole 1920x1080 frame letterboxed into
--input-wh, confidence >= --conf) on fresh synthetic scenes and cuts a native-resolution crop
around every detection that does not overlap the drone (birds, ground clutter, horizon).
Appends them as drone-free rows (NaN boxes) to a copy of synth_det.npz.

  python training/mine_synth_negatives.py /tmp/det3.onnx --scenes 20 --out training/cache/synth_det_mined.npz
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import AppearanceConfig  # noqa: E402
from payload.detect.appearance import AppearanceDetector  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from training.build_cache import CACHE, crop_with, iou, within_crop_reach  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--first-seed", type=int, default=2000)
    ap.add_argument("--conf", type=float, default=0.3)
    ap.add_argument("--input-wh", type=int, nargs=2, default=(640, 384))
    ap.add_argument("--out", default=os.path.join(CACHE, "synth_det_mined.npz"))
    args = ap.parse_args()
    gad = AppearanceDetector(OnnxModel(args.model, threads=1), AppearanceConfig(confidence=args.conf, input_wh=tuple(args.input_wh)), "GAD")
    rng = np.random.default_rng(2)
    crops = []
    for s in range(args.scenes):
        for sf in Scene(seed=args.first_seed + s, width=1920, height=1080, fps=30.0, frames=args.frames, target_px=(4.0, 24.0)):
            if sf.index % 4:
                continue
            gt = None if sf.target_xyxy is None else np.asarray(sf.target_xyxy, np.float32)
            for box in gad.detect(sf.image).xyxy:
                if gt is not None and iou(box, gt) > 0.0:
                    continue
                if max(box[2] - box[0], box[3] - box[1]) > 200:
                    continue
                crop, _ = crop_with(rng, sf.image, box, 256)
                if gt is not None:  # the crop must not contain the drone either
                    if within_crop_reach(box, gt):
                        continue
                crops.append(crop.copy())
        print("scene %d/%d mined=%d" % (s + 1, args.scenes, len(crops)), flush=True)
    base = np.load(os.path.join(CACHE, "synth_det.npz"))
    images = np.concatenate([base["images"], np.stack(crops)])
    xyxy = np.concatenate([base["xyxy"], np.full((len(crops), 4), np.nan, np.float32)])
    np.savez(args.out, images=images, xyxy=xyxy)
    print("done mined=%d total=%d" % (len(crops), len(images)))


if __name__ == "__main__":
    main()
