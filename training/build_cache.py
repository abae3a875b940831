"""Decode the Halmstad training clips once into arrays under training/cache/.

det_pos.npy   [N, S, S, 3] uint8 native-resolution crops with a drone anywhere inside,
det_pos_xyxy.npy [N, 4] its box in crop pixels;
det_neg.npy   [M, S, S, 3] crops without a drone (backgrounds of drone clips, birds,
airliners, helicopters and their surroundings from the negatives clips);
cls_x.npy [K, 32, 32, 3] uint8 classifier patches (payload.detect.patches.crop_patches),
cls_y.npy [K] 1 = drone, 0 = clutter; clutter = random background boxes, bird/plane/heli
boxes, and frame-difference blobs away from the label (what a motion detector proposes).

Usage: python training/build_cache.py [--crop 256] [--every 4]
       python training/build_cache.py --split ir_train --name ir   # thermal: ir_det.npz, ir_cls.npz
       python training/build_cache.py --name ego --ego-motion 1 --every 8   # train clips, moving camera
       python training/build_cache.py --split negatives_train --name objects --objects   # birds etc.
With --name, the drone clips of --split are written as extra sets for train_det/train_cls --synth
(<name>_det.npz: images, xyxy with NaN where no drone; <name>_cls.npz: x, y); no negatives clips.
--clips / --negatives name the clips instead of the splits (training/cv_train.py: every clip
outside one cross-validation fold); --cache writes into another folder.
"""

import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.detect.patches import crop_patches  # noqa: E402
from payload.synth.ego_motion import EgoMotionWarp  # noqa: E402
from training.halmstad import frames, labels, splits  # noqa: E402

CACHE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "cache")


OBJECT_JITTERS = 2


def iou(a: np.ndarray, b: np.ndarray) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / max(union, 1e-6)


def crop_with(rng, img, box, side):
    """A side x side crop with ``box`` at a random place inside; returns crop, box in crop pixels."""
    h, w = img.shape[:2]
    bw, bh = box[2] - box[0], box[3] - box[1]
    lo_x, hi_x = box[2] - side + min(4, side - bw), box[0] - min(4, side - bw)
    lo_y, hi_y = box[3] - side + min(4, side - bh), box[1] - min(4, side - bh)
    x0 = int(np.clip(rng.uniform(lo_x, max(lo_x, hi_x)), 0, w - side))
    y0 = int(np.clip(rng.uniform(lo_y, max(lo_y, hi_y)), 0, h - side))
    crop = img[y0:y0 + side, x0:x0 + side]
    b = box - np.array([x0, y0, x0, y0], np.float32)
    return crop, np.clip(b, 0, side)


def random_free_crop(rng, img, avoid, side, tries=10):
    h, w = img.shape[:2]
    for _ in range(tries):
        x0, y0 = int(rng.integers(0, w - side + 1)), int(rng.integers(0, h - side + 1))
        c = np.array([x0, y0, x0 + side, y0 + side], np.float32)
        if all(iou(c, a) == 0.0 for a in avoid):
            return img[y0:y0 + side, x0:x0 + side]
    return None


def random_boxes(rng, img, avoid, n):
    h, w = img.shape[:2]
    out = []
    for _ in range(n * 3):
        bw = rng.uniform(8, 60)
        bh = bw * rng.uniform(0.5, 1.2)
        x, y = rng.uniform(0, w - bw), rng.uniform(0, h - bh)
        b = np.array([x, y, x + bw, y + bh], np.float32)
        if all(iou(b, a) < 0.05 for a in avoid):
            out.append(b)
        if len(out) == n:
            break
    return out


def diff_blobs(prev, img, avoid, n):
    """Boxes of frame-difference blobs that do not overlap ``avoid`` (motion-detector-like clutter)."""
    g0 = cv2.GaussianBlur(cv2.cvtColor(prev, cv2.COLOR_BGR2GRAY), (5, 5), 0)
    g1 = cv2.GaussianBlur(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), (5, 5), 0)
    d = cv2.absdiff(g0, g1)
    mask = (d > 5 + float(d.mean())).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8), iterations=2)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    out = []
    for x, y, bw, bh, area in stats[1:]:
        if area < 6 or bw > 120 or bh > 120:
            continue
        b = np.array([x, y, x + bw, y + bh], np.float32)
        if all(iou(b, a) < 0.05 for a in avoid):
            out.append(b)
    return out[:n]


def within_crop_reach(box, other, side=256):
    """True when ``other`` may fall inside a ``side`` px crop cut around ``box`` by crop_with (it
    places the box anywhere in the crop): their centres are closer than the side (+4 px) on both axes."""
    reach = side + 4
    return (abs((other[0] + other[2]) / 2 - (box[0] + box[2]) / 2) < reach
            and abs((other[1] + other[3]) / 2 - (box[1] + box[3]) / 2) < reach)


def save_extra_sets(name, cls_x, cls_y, det_images=None, det_xyxy=None, cache=CACHE):
    """Write the sets train_cls / train_det read with --synth: <name>_cls.npz (x, y) and, given
    crops, <name>_det.npz (images, xyxy with NaN where the crop holds no drone)."""
    np.savez(os.path.join(cache, name + "_cls.npz"), x=np.asarray(cls_x), y=np.asarray(cls_y, np.uint8))
    if det_images is not None and len(det_images):
        np.savez(os.path.join(cache, name + "_det.npz"), images=np.asarray(det_images),
                 xyxy=np.asarray(det_xyxy, np.float32))


def jitter(rng, box, amount=0.15):
    w, h = box[2] - box[0], box[3] - box[1]
    s = rng.uniform(1 - amount, 1 + amount)
    cx = (box[0] + box[2]) / 2 + rng.uniform(-amount, amount) * w
    cy = (box[1] + box[3]) / 2 + rng.uniform(-amount, amount) * h
    return np.array([cx - w * s / 2, cy - h * s / 2, cx + w * s / 2, cy + h * s / 2], np.float32)


def clip_frames(clip, ego_seed=None):
    """(index, image, drone boxes, other boxes) per frame; with ``ego_seed``, as a turning, rolling,
    zooming, shaking camera would have filmed the clip (payload.synth.ego_motion, the warp that
    `glad-payload eval --ego-motion` applies to val)."""
    lab = labels(clip)
    warp = None
    for i, img in frames(clip):
        boxes = lab.get(i, [])
        if ego_seed is not None:
            if warp is None:
                warp = EgoMotionWarp(ego_seed, (img.shape[1], img.shape[0]))
            img = warp.image(i, img)
            boxes = [(c, m[0]) for c, b in boxes for m in [warp.boxes(i, b)] if len(m)]
        yield i, img, [b for c, b in boxes if c == "DRONE"], [b for c, b in boxes if c != "DRONE"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--crop", type=int, default=256)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--split", default="train", help="drone clips to read (train, ir_train)")
    ap.add_argument("--name", default=None, help="write <name>_det.npz and <name>_cls.npz instead of the main cache")
    ap.add_argument("--objects", action="store_true",
                    help="only the classifier patches of the labelled birds/airliners/helicopters of --split "
                         "(e.g. negatives_train), %d jittered per object every 2nd frame: <name>_cls.npz" % OBJECT_JITTERS)
    ap.add_argument("--ego-motion", type=int, default=None, metavar="SEED",
                    help="warp each clip by synthetic camera motion (seed SEED*1000 + clip number); needs --name")
    ap.add_argument("--clips", nargs="+", default=None, metavar="CLIP",
                    help="read these clips instead of the clips of --split (e.g. every drone clip outside a CV fold)")
    ap.add_argument("--negatives", nargs="+", default=None, metavar="CLIP",
                    help="negatives clips (birds, airliners, helicopters) instead of negatives_train")
    ap.add_argument("--cache", default=CACHE, help="output folder (default training/cache)")
    args = ap.parse_args()
    if (args.ego_motion is not None or args.objects) and not args.name:
        ap.error("--ego-motion and --objects write an extra set: give --name too")
    rng = np.random.default_rng(0 if args.ego_motion is None else args.ego_motion)
    os.makedirs(args.cache, exist_ok=True)
    sp = splits()
    if args.clips is not None:
        sp[args.split] = args.clips
    if args.negatives is not None:
        sp["negatives_train"] = args.negatives
    pos, pos_xyxy, neg, cls_x, cls_y = [], [], [], [], []
    side = args.crop
    if args.objects:
        for ci, clip in enumerate(sp[args.split]):
            for i, img, _, others in clip_frames(clip):
                if i % 2 == 0 and others:
                    boxes = [jitter(rng, b) for b in others for _ in range(OBJECT_JITTERS)]
                    cls_x.append(crop_patches(img, np.array(boxes)))
                    cls_y += [0] * len(boxes)
            print("objects %d/%d %s cls=%d" % (ci + 1, len(sp[args.split]), clip, len(cls_y)), flush=True)
        save_extra_sets(args.name, np.concatenate(cls_x), cls_y, cache=args.cache)
        return

    for ci, clip in enumerate(sp[args.split]):
        prev = None
        for i, img, drones, others in clip_frames(clip, None if args.ego_motion is None else args.ego_motion * 1000 + ci):
            if i % args.every == 0 and drones:
                crop, b = crop_with(rng, img, drones[0], side)
                pos.append(crop.copy())
                pos_xyxy.append(b)
            if i % (args.every * 3) == 1:
                c = random_free_crop(rng, img, drones + others, side)
                if c is not None:
                    neg.append(c.copy())
            if i % 3 == 0 and drones:
                boxes = [jitter(rng, drones[0]) for _ in range(2)]
                cls_x.append(crop_patches(img, np.array(boxes)))
                cls_y += [1] * len(boxes)
                bg = random_boxes(rng, img, drones, 2)
                if prev is not None:
                    bg += diff_blobs(prev, img, drones, 3)
                if bg:
                    cls_x.append(crop_patches(img, np.array(bg)))
                    cls_y += [0] * len(bg)
            prev = img
        print("%s %d/%d %s pos=%d neg=%d cls=%d" % (args.split, ci + 1, len(sp[args.split]), clip, len(pos), len(neg),
                                                  len(cls_y)), flush=True)

    if args.name:
        nan = np.full((len(neg), 4), np.nan, np.float32)
        save_extra_sets(args.name, np.concatenate(cls_x), cls_y, np.stack(pos + neg),
                        np.concatenate([np.stack(pos_xyxy).astype(np.float32), nan]), cache=args.cache)
        print("done %s pos=%d neg=%d cls=%d (drone %d)" % (args.name, len(pos), len(neg), len(cls_y), int(np.sum(cls_y))))
        return

    for ci, clip in enumerate(sp["negatives_train"]):
        prev = None
        for i, img, _, others in clip_frames(clip):
            if i % (args.every * 4) == 0:
                if others and max(others[0][2] - others[0][0], others[0][3] - others[0][1]) < side - 8:
                    crop, _ = crop_with(rng, img, others[0], side)
                    neg.append(crop.copy())
                c = random_free_crop(rng, img, [], side)
                if c is not None:
                    neg.append(c.copy())
            if i % 4 == 0:
                boxes = [jitter(rng, b) for b in others]
                boxes += random_boxes(rng, img, others, 1)
                if prev is not None:
                    boxes += diff_blobs(prev, img, [], 2)
                if boxes:
                    cls_x.append(crop_patches(img, np.array(boxes)))
                    cls_y += [0] * len(boxes)
            prev = img
        print("neg %d/%d %s neg=%d cls=%d" % (ci + 1, len(sp["negatives_train"]), clip, len(neg), len(cls_y)), flush=True)

    np.save(os.path.join(args.cache, "det_pos.npy"), np.stack(pos))
    np.save(os.path.join(args.cache, "det_pos_xyxy.npy"), np.stack(pos_xyxy).astype(np.float32))
    np.save(os.path.join(args.cache, "det_neg.npy"), np.stack(neg))
    np.save(os.path.join(args.cache, "cls_x.npy"), np.concatenate(cls_x))
    np.save(os.path.join(args.cache, "cls_y.npy"), np.array(cls_y, np.uint8))
    print("done pos=%d neg=%d cls=%d (drone %d)" % (len(pos), len(neg), len(cls_y), int(np.sum(cls_y))))


if __name__ == "__main__":
    main()
