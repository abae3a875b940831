"""Render synthetic moving-camera scenes (payload.synth) into training arrays under training/cache/.

synth_det.npz: images [N, S, S, 3] uint8 native-resolution crops of 1920x1080 frames; xyxy [N, 4]
  the drone's box in crop pixels, NaN rows for crops without it (ground clutter, birds, cars).
synth_cls.npz: x [K, 32, 32, 3] classifier patches (payload.detect.patches), y [K] 1 = drone;
  clutter = random boxes and blobs of the motion-compensated frame difference (the previous frame
  warped by the scene's exact homography): what a motion detector proposes on a moving camera.

  python training/build_synth_cache.py [--scenes 40] [--frames 90]
  python training/build_synth_cache.py --name synth_light --first-seed 1300 --target-px 2 8 \
      --drone light --sky clear --in-sky        # tiny light drones against a bright sky (issue 16)

``--min-noise K``: a drone patch is a positive only where the drone stands out from the sky around it
by K noise units or more in some colour channel (bench/tiny_contrast.py's measure): beside the sun a
light drone can vanish, and a blank patch of sky taught as "drone" would teach the classifier to pass
sky.
"""

import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.tiny_contrast import contrast  # noqa: E402
from payload.detect.patches import crop_patches  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from training.build_cache import (  # noqa: E402
    CACHE,
    crop_with,
    jitter,
    random_boxes,
    random_free_crop,
    save_extra_sets,
)


def compensated_blobs(prev, img, homography, avoid, n):
    warped = cv2.warpPerspective(prev, homography, (img.shape[1], img.shape[0]))
    from training.build_cache import diff_blobs

    return diff_blobs(warped, img, avoid, n)


def _noise_units(channel: np.ndarray, xyxy) -> float:
    """How far the drone in box ``xyxy`` stands out from its ring in one channel, in noise units
    (bench/tiny_contrast.py's measure); 0 where there is no ring to measure against."""
    measured = contrast(channel, xyxy)
    return measured[1] if measured is not None else 0.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=40)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--first-seed", type=int, default=1000, help="seeds kept apart from the demo/eval seeds")
    ap.add_argument("--crop", type=int, default=256)
    ap.add_argument("--name", default="synth", help="outputs <name>_det.npz and <name>_cls.npz")
    ap.add_argument("--target-px", type=float, nargs=2, default=(4.0, 24.0), help="drone size range")
    ap.add_argument("--cache", default=CACHE, help="output folder (default training/cache)")
    ap.add_argument("--drone", choices=("any", "light"), default="any", help="airframe colour (payload.synth)")
    ap.add_argument("--sky", choices=("any", "clear"), default="any", help="sky (clear: blue with the sun's glare)")
    ap.add_argument("--in-sky", action="store_true", help="keep the drone above the horizon")
    ap.add_argument("--min-noise", type=float, default=0.0, help="positives only where the drone stands out this much")
    args = ap.parse_args()
    os.makedirs(args.cache, exist_ok=True)
    rng = np.random.default_rng(1)
    images, boxes, cls_x, cls_y = [], [], [], []
    side = args.crop
    for s in range(args.scenes):
        seed = args.first_seed + s
        prev = None
        for sf in Scene(seed=seed, width=1920, height=1080, fps=30.0, frames=args.frames, target_px=tuple(args.target_px),
                        drone_look=args.drone, sky=args.sky, target_in_sky=args.in_sky):
            img = sf.image
            box = sf.target_xyxy
            visible = box is not None and sf.target_visible >= 0.5
            avoid = [np.asarray(box, np.float32)] if box is not None else []
            if sf.index % 3 == 0 and visible:
                crop, b = crop_with(rng, img, np.asarray(box, np.float32), side)
                images.append(crop.copy())
                boxes.append(b)
            if sf.index % 6 == 1:
                c = random_free_crop(rng, img, avoid, side)
                if c is not None:
                    images.append(c.copy())
                    boxes.append(np.full(4, np.nan, np.float32))
            if sf.index % 3 == 0:
                if visible and args.min_noise > 0:
                    visible = max(_noise_units(img[..., c], box) for c in range(3)) >= args.min_noise
                if visible:
                    pos = [jitter(rng, np.asarray(box, np.float32)) for _ in range(2)]
                    cls_x.append(crop_patches(img, np.array(pos)))
                    cls_y += [1] * len(pos)
                neg = random_boxes(rng, img, avoid, 2)
                if prev is not None:
                    neg += compensated_blobs(prev, img, sf.homography, avoid, 4)
                if neg:
                    cls_x.append(crop_patches(img, np.array(neg)))
                    cls_y += [0] * len(neg)
            prev = img
        print("scene %d/%d seed=%d det=%d cls=%d" % (s + 1, args.scenes, seed, len(images), len(cls_y)), flush=True)
    save_extra_sets(args.name, np.concatenate(cls_x), cls_y, np.stack(images), np.stack(boxes), cache=args.cache)
    print("done det=%d (with drone %d) cls=%d (drone %d)"
          % (len(images), int(np.isfinite(np.stack(boxes)[:, 0]).sum()), len(cls_y), int(np.sum(cls_y))))


if __name__ == "__main__":
    main()
