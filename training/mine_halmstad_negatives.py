"""Hard negatives from the Halmstad negatives_train clips: where the global detector fires on
birds, airliners, helicopters and background (every box there is not a drone).

Cuts a native-resolution 256x256 crop around each detection (global stage settings) and
appends them to the drone-free crops: writes training/cache/det_neg_mined.npy (det_neg + mined).

  python training/mine_halmstad_negatives.py model.onnx [--every 4] [--conf 0.3]
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import AppearanceConfig  # noqa: E402
from payload.detect.appearance import AppearanceDetector  # noqa: E402
from payload.detect.onnx_model import OnnxModel  # noqa: E402
from training.build_cache import CACHE, crop_with  # noqa: E402
from training.halmstad import frames, splits  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--conf", type=float, default=0.3)
    args = ap.parse_args()
    gad = AppearanceDetector(OnnxModel(args.model, threads=1), AppearanceConfig(confidence=args.conf, input_wh=(640, 384)), "GAD")
    rng = np.random.default_rng(3)
    crops = []
    clips = splits()["negatives_train"]
    for ci, clip in enumerate(clips):
        for i, img in frames(clip):
            if i % args.every:
                continue
            for box in gad.detect(img).xyxy[:3]:
                if max(box[2] - box[0], box[3] - box[1]) < 200:
                    crop, _ = crop_with(rng, img, box, 256)
                    crops.append(crop.copy())
        print("clip %d/%d %s mined=%d" % (ci + 1, len(clips), clip, len(crops)), flush=True)
    base = np.load(os.path.join(CACHE, "det_neg.npy"), mmap_mode="r")
    np.save(os.path.join(CACHE, "det_neg_mined.npy"), np.concatenate([np.asarray(base), np.stack(crops)]))
    print("done mined=%d total=%d" % (len(crops), len(base) + len(crops)))


if __name__ == "__main__":
    main()
