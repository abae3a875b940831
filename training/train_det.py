"""Train the tiny CenterNet detector on cached Halmstad crops (training/build_cache.py) on the CPU.

One network serves the global detector (frames down-scaled ~0.75 into 640x384) and the local
one (crops at native resolution): each sample is re-scaled by a random factor in
[--scale-min, --scale-max] before a random --size crop, so both regimes are seen.

  python training/train_det.py --name det1 --steps 3000            # new run
  python training/train_det.py --name det1 --steps 5000 --resume   # continue from last.pt
Checkpoints and log go to training/runs/<name>/.
"""

import argparse
import math
import os
import sys
import time

import cv2
import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from training.augment import paste_drone, photometric, thermal_polarity  # noqa: E402
from training.net import (  # noqa: E402
    STRIDE,
    TinyCenterNet,
    count_params,
    load_weights,
    resume,
    save_checkpoint,
    training_device,
)

HERE = os.path.dirname(os.path.abspath(__file__))
CACHE = os.path.join(HERE, "cache")
PAD = 114


class Sampler:
    def __init__(self, size, scale_min, scale_max, neg_frac, seed, extra=None, extra_frac=0.3, neg_file="det_neg.npy",
                 cache=CACHE, paste_frac=0.0, paste_px=(2.0, 10.0), polarity_p=0.0):
        self.pos = np.load(os.path.join(cache, "det_pos.npy"), mmap_mode="r")
        self.pos_xyxy = np.load(os.path.join(cache, "det_pos_xyxy.npy"))
        self.neg = np.load(os.path.join(cache, neg_file), mmap_mode="r")
        self.extra = extra  # optional (images, xyxy) of further crops, e.g. synthetic scenes (NaN xyxy: no drone)
        self.extra_frac = extra_frac
        self.size, self.smin, self.smax, self.neg_frac = size, scale_min, scale_max, neg_frac
        self.rng = np.random.default_rng(seed)
        self.paste_frac, self.paste_px, self.polarity_p = paste_frac, paste_px, polarity_p

    def one(self):
        rng, t = self.rng, self.size
        smin, smax = self.smin, self.smax
        pasted = self.paste_frac > 0 and rng.random() < self.paste_frac
        if pasted:
            # a real drone shrunk to a few pixels (and recoloured) on a real drone-free frame: the
            # tiny drones the recordings hold too few of, on real backgrounds; kept near native scale
            k = rng.integers(len(self.pos))
            span = math.exp(rng.uniform(math.log(self.paste_px[0]), math.log(self.paste_px[1])))
            img, box = paste_drone(rng, np.asarray(self.neg[rng.integers(len(self.neg))]), np.asarray(self.pos[k]),
                                   self.pos_xyxy[k], span)
            smin, smax = 0.8, 1.25
        elif self.extra is not None and rng.random() < self.extra_frac:
            # synthetic 1920x1080 crops: drones mostly in the local regime (native resolution; at
            # the global 1/3 down-scale their 4-24 px shrink to a few pixels), clutter and birds
            # at every scale so the global detector learns to ignore them
            k = rng.integers(len(self.extra[0]))
            img, box = np.asarray(self.extra[0][k]), self.extra[1][k].copy()
            if np.isfinite(box).all():
                smin = max(smin, 0.6)
            else:
                box, smin = None, min(smin, 0.33)
        elif rng.random() < self.neg_frac:
            img, box = np.asarray(self.neg[rng.integers(len(self.neg))]), None
        else:
            k = rng.integers(len(self.pos))
            img, box = np.asarray(self.pos[k]), self.pos_xyxy[k].copy()
        # log-uniform scale: as many down-scaled (global) as native (local) samples
        s = math.exp(rng.uniform(math.log(smin), math.log(smax)))
        h, w = img.shape[:2]
        nw, nh = max(8, int(round(w * s))), max(8, int(round(h * s)))
        img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        if box is not None:
            box = box * np.array([nw / w, nh / h, nw / w, nh / h], np.float32)
        canvas = np.full((t, t, 3), PAD, np.uint8)
        # canvas origin (ox, oy) in the resized crop: the box fully inside, the crop covering the
        # canvas where possible (grey padding only where the crop is smaller than the canvas)
        def origin(lo_box, hi_box, n):
            lo_img, hi_img = min(0, n - t), max(0, n - t)
            lo, hi = max(lo_box, lo_img), min(hi_box, hi_img)
            if lo > hi:
                lo, hi = (lo_box, hi_box) if lo_box <= hi_box else ((lo_box + hi_box) / 2,) * 2
            return rng.uniform(lo, hi)

        if box is not None:
            ox = origin(box[2] - t + 1, box[0] - 1, nw)
            oy = origin(box[3] - t + 1, box[1] - 1, nh)
        else:
            ox = origin(-1e9, 1e9, nw)
            oy = origin(-1e9, 1e9, nh)
        tx, ty = -ox, -oy
        tx, ty = int(round(tx)), int(round(ty))
        x0, y0 = max(0, tx), max(0, ty)
        x1, y1 = min(t, tx + nw), min(t, ty + nh)
        if x1 > x0 and y1 > y0:
            canvas[y0:y1, x0:x1] = img[y0 - ty:y1 - ty, x0 - tx:x1 - tx]
        if box is not None:
            box = box + np.array([tx, ty, tx, ty], np.float32)
        if rng.random() < 0.5:
            canvas = canvas[:, ::-1]
            if box is not None:
                box = np.array([t - box[2], box[1], t - box[0], box[3]], np.float32)
        canvas = thermal_polarity(rng, np.ascontiguousarray(canvas), self.polarity_p)
        img = photometric(rng, canvas)[..., ::-1] / 255.0
        return img.transpose(2, 0, 1).astype(np.float32), box

    def batch(self, n):
        xs, boxes = zip(*(self.one() for _ in range(n)))
        return torch.from_numpy(np.stack(xs)), list(boxes)


def targets(boxes, size):
    """Heatmap (gaussian per centre), offset / log-size regression targets and their mask."""
    g = size // STRIDE
    n = len(boxes)
    hm = np.zeros((n, 1, g, g), np.float32)
    reg = np.zeros((n, 4, g, g), np.float32)
    mask = np.zeros((n, 1, g, g), np.float32)
    yy, xx = np.mgrid[0:g, 0:g].astype(np.float32)
    for i, b in enumerate(boxes):
        if b is None:
            continue
        b = np.clip(b, 0, size - 1e-3)
        w, h = b[2] - b[0], b[3] - b[1]
        if w < 1 or h < 1:
            continue
        cx, cy = (b[0] + b[2]) / 2 / STRIDE, (b[1] + b[3]) / 2 / STRIDE
        ix, iy = int(cx), int(cy)
        sigma = max(0.5, min(w, h) / STRIDE / 4.0)
        hm[i, 0] = np.maximum(hm[i, 0], np.exp(-((xx - ix) ** 2 + (yy - iy) ** 2) / (2 * sigma ** 2)))
        reg[i, :, iy, ix] = [cx - ix, cy - iy, math.log(w / STRIDE), math.log(h / STRIDE)]
        mask[i, 0, iy, ix] = 1.0
    return torch.from_numpy(hm), torch.from_numpy(reg), torch.from_numpy(mask)


def focal_loss(logit, hm):
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    pos = hm.eq(1).float()
    neg_w = (1 - hm) ** 4
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p ** 2 * neg_w * (1 - pos)
    npos = pos.sum().clamp(min=1)
    return -(pos_loss.sum() + neg_loss.sum()) / npos


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", required=True)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--scale-min", type=float, default=0.45)
    ap.add_argument("--scale-max", type=float, default=1.3)
    ap.add_argument("--neg-frac", type=float, default=0.3)
    ap.add_argument("--width", type=float, default=1.0)
    ap.add_argument("--wh-weight", type=float, default=1.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--init", default=None, help="start from this checkpoint's (.pt) or exported model's (.onnx) weights")
    ap.add_argument("--synth", nargs="*", default=[], help="npz files with extra crops: images [N,S,S,3], xyxy [N,4] (NaN = no drone)")
    ap.add_argument("--synth-frac", type=float, default=0.3)
    ap.add_argument("--neg-file", default="det_neg.npy", help="drone-free crops in --cache")
    ap.add_argument("--paste-frac", type=float, default=0.0,
                    help="share of samples made by pasting a real drone, shrunk to --paste-px and recoloured, on a drone-free crop")
    ap.add_argument("--paste-px", type=float, nargs=2, default=(2.0, 10.0), help="pasted drone size range, px across")
    ap.add_argument("--polarity-p", type=float, default=0.0, help="probability a thermal (grey) sample is flipped white-hot <-> black-hot")
    ap.add_argument("--cache", default=CACHE, help="folder of det_pos.npy, det_pos_xyxy.npy, det_neg.npy (build_cache.py)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    run = os.path.join(HERE, "runs", args.name)
    os.makedirs(run, exist_ok=True)
    device = training_device()
    net = TinyCenterNet(args.width).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    step = 0
    last = os.path.join(run, "last.pt")
    if args.resume and os.path.exists(last):
        step = resume(last, net, opt, device)
    extra = None
    if args.synth:
        files = [np.load(path) for path in args.synth]
        extra = (np.concatenate([z["images"] for z in files]), np.concatenate([z["xyxy"] for z in files]))
    sampler = Sampler(args.size, args.scale_min, args.scale_max, args.neg_frac, seed=step + 1, extra=extra, extra_frac=args.synth_frac, neg_file=args.neg_file,
                      cache=args.cache, paste_frac=args.paste_frac, paste_px=tuple(args.paste_px), polarity_p=args.polarity_p)
    if step == 0 and args.init and args.init.endswith(".onnx"):
        from training.onnx_init import load_onnx_detector, max_abs_diff

        calibration = [sampler.batch(args.batch)[0] for _ in range(4)]
        net = load_onnx_detector(args.init, args.width, calibration)
        print("init from %s (BatchNorm folded in the graph: re-split on 4 batches; max abs difference to the "
              "ONNX output on one of them: %.2e)" % (args.init, max_abs_diff(net, args.init, calibration[0])), flush=True)
        net = net.to(device)
        opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    elif step == 0 and args.init:
        load_weights(args.init, net, device)
        print("init from %s" % args.init, flush=True)
    print("params=%d steps=%d batch=%d size=%d" % (count_params(net), args.steps, args.batch, args.size), flush=True)
    net.train()
    t0 = time.time()
    avg = None
    while step < args.steps:
        lr = args.lr * 0.5 * (1 + math.cos(math.pi * step / args.steps))
        for g in opt.param_groups:
            g["lr"] = lr
        x, boxes = sampler.batch(args.batch)
        x = x.to(device)
        hm, reg, mask = (t.to(device) for t in targets(boxes, args.size))
        out = net(x)
        l_hm = focal_loss(out[:, 0:1], hm)
        npos = mask.sum().clamp(min=1)
        l_off = (F.l1_loss(out[:, 1:3], reg[:, 0:2], reduction="none") * mask).sum() / npos
        l_wh = (F.l1_loss(out[:, 3:5], reg[:, 2:4], reduction="none") * mask).sum() / npos
        loss = l_hm + l_off + args.wh_weight * l_wh
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        cur = np.array([loss.item(), l_hm.item(), l_off.item(), l_wh.item()])
        avg = cur if avg is None else 0.98 * avg + 0.02 * cur
        if step % 50 == 0:
            print("step=%d loss=%.3f hm=%.3f off=%.3f wh=%.3f lr=%.5f s/step=%.2f"
                  % (step, *avg, lr, (time.time() - t0) / 50), flush=True)
            t0 = time.time()
        if step % 200 == 0 or step == args.steps:
            save_checkpoint(last, net, opt, step, width=args.width)
    print("done step=%d" % step, flush=True)


if __name__ == "__main__":
    main()
