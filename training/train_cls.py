"""Train the 32x32 patch classifier (MAV vs clutter) on training/cache/cls_*.npy on the CPU.

  python training/train_cls.py --name cls1 --steps 3000 [--resume]
A random 10% of the patches is held out (same clips as training, so optimistic) and
reported as accuracy / precision / recall.
"""

import argparse
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.detect.patches import patches_to_input  # noqa: E402
from training.augment import photometric  # noqa: E402
from training.net import PatchClassifier, count_params, load_weights, resume, save_checkpoint, training_device  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
CACHE = os.path.join(HERE, "cache")


def augment(rng, x):
    x = x.copy()
    flip = rng.random(len(x)) < 0.5
    x[flip] = x[flip][:, :, ::-1]
    return np.stack([photometric(rng, np.ascontiguousarray(p)) for p in x])


def with_sets(X, Y, paths):
    """``X``, ``Y`` with the patches of these npz files (x, y) appended."""
    for path in paths:
        z = np.load(path)
        X, Y = np.concatenate([X, z["x"]]), np.concatenate([Y, z["y"].astype(np.int64)])
    return X, Y


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", required=True)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--synth", nargs="*", default=[], help="npz files with more patches: x [K,32,32,3], y [K]")
    ap.add_argument("--hard", nargs="*", default=[], help="npz files of hard negatives (x, y = 0), e.g. birds and "
                    "airliners, drawn as --hard-frac of every batch besides the other clutter")
    ap.add_argument("--hard-frac", type=float, default=0.25)
    ap.add_argument("--init", default=None, help="start from this run's checkpoint (fine-tuning), e.g. training/runs/cls5/last.pt, "
                    "or from an exported classifier (.onnx; its BatchNorms stay frozen)")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--cache", default=CACHE, help="folder of cls_x.npy, cls_y.npy (build_cache.py)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    run = os.path.join(HERE, "runs", args.name)
    os.makedirs(run, exist_ok=True)
    X = np.load(os.path.join(args.cache, "cls_x.npy"))
    Y = np.load(os.path.join(args.cache, "cls_y.npy")).astype(np.int64)
    X, Y = with_sets(X, Y, args.synth)
    n_plain = len(Y)
    X, Y = with_sets(X, Y, args.hard)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(Y))
    hold, train = perm[: len(Y) // 10], perm[len(Y) // 10:]
    pos, neg = train[Y[train] == 1], train[(Y[train] == 0) & (train < n_plain)]
    hard = train[(Y[train] == 0) & (train >= n_plain)]
    n_hard = int(round(args.batch * args.hard_frac)) if len(hard) else 0
    device = training_device()
    net = PatchClassifier().to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    step = 0
    frozen_bn = bool(args.init and args.init.endswith(".onnx"))
    if frozen_bn:
        from training.onnx_init import freeze_batchnorm, load_onnx_classifier

        net = load_onnx_classifier(args.init).to(device)
        freeze_batchnorm(net)
        opt = torch.optim.AdamW([p for p in net.parameters() if p.requires_grad], lr=args.lr, weight_decay=1e-4)
        print("init from %s (BatchNorm folded in the graph: frozen)" % args.init, flush=True)
    elif args.init:
        load_weights(args.init, net, device)
    last = os.path.join(run, "last.pt")
    if args.resume and os.path.exists(last):
        step = resume(last, net, opt, device)
    print("params=%d train=%d (pos %d, hard %d) holdout=%d" % (count_params(net), len(train), len(pos), len(hard), len(hold)),
          flush=True)
    t0 = time.time()
    while step < args.steps:
        net.train()
        if frozen_bn:
            freeze_batchnorm(net)
        for g in opt.param_groups:
            g["lr"] = args.lr * 0.5 * (1 + math.cos(math.pi * step / args.steps))
        idx = np.concatenate([rng.choice(pos, args.batch // 2), rng.choice(neg, args.batch // 2 - n_hard),
                              rng.choice(hard, n_hard)])
        x = torch.from_numpy(patches_to_input(augment(rng, X[idx]))).to(device)
        loss = F.cross_entropy(net(x), torch.from_numpy(Y[idx]).to(device))
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % 200 == 0 or step == args.steps:
            net.eval()
            with torch.no_grad():
                p = torch.cat([torch.softmax(net(torch.from_numpy(patches_to_input(X[hold[i:i + 2048]])).to(device)), 1)[:, 1]
                               for i in range(0, len(hold), 2048)]).cpu().numpy()
            y = Y[hold]
            tp = int(((p >= 0.5) & (y == 1)).sum())
            prec = tp / max(1, int((p >= 0.5).sum()))
            rec = tp / max(1, int((y == 1).sum()))
            print("step=%d loss=%.3f holdout acc=%.4f P=%.4f R=%.4f s/step=%.3f"
                  % (step, loss.item(), float(((p >= 0.5) == (y == 1)).mean()), prec, rec, (time.time() - t0) / 200), flush=True)
            t0 = time.time()
            save_checkpoint(last, net, opt, step)


if __name__ == "__main__":
    main()
