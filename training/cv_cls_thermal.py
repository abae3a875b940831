"""Teach the shipped classifier the thermal birds, airliners and helicopters, one fold at a time.

The thermal negatives were in no network's training, and the lock the payload holds on them is
on the labelled object in 93 % of the frames (the mined locks of training/mine_tracks.py): a
thermal bird or airliner passes the 32x32 classifier as a drone. This fine-tunes the shipped
classifier (payload/models/glad_classifier.onnx, BatchNorm frozen) with those objects as hard
negatives, beside the kinds of patches it was trained on (payload/models/MODEL_CARD.md, cls5) so that
it keeps what it knew (a first run without the synthetic and mined sets forgot the synthetic drones:
their centre-F fell from 0.69 to 0.46 in the verifier's cross-validation):

  caches   build_cache.py (train + negatives_train: cls_x/cls_y), build_cache.py --name ir
           (thermal drone patches), build_synth_cache.py (synth: seeds 1000+, 4-24 px; synth2:
           1100+, 4-14 px; 30 scenes each), mine_candidates.py (mined1: what the modules propose
           away from the drone), and per fold k build_cache.py --objects over the thermal
           negatives clips IN fold k (irobj{k}_cls.npz: each labelled object jittered, every 2nd frame)
  fold k   train_cls.py --init glad_classifier.onnx --hard irobj{j}_cls.npz for every j != k,
           exported to OUT/fold{k}/glad_classifier.onnx beside the shipped global and local networks
  all      the same with every fold's objects: OUT/all/glad_classifier.onnx (the one that would ship)

``--init`` is the classifier to start from: cls5, the one shipped before this recipe (the shipped
file is cls14 now, which saw every fold's thermal negatives), kept in git:

  git show 1361a20:payload/models/glad_classifier.onnx > training/cache/cls5.onnx

so ``glad-payload cv --fold-models OUT`` and ``training/mine_tracks.py --fold-models OUT`` score
each fold's thermal negatives with a classifier that never saw them. The drone side stays as
optimistic as the shipped networks (they saw most drone clips). Every stage is skipped once done
and training resumes from its checkpoint (training/cv_train.py's run_stage):

  nice -n 10 python training/cv_cls_thermal.py --init training/cache/cls5.onnx --log training/runs/cv/clsir2/train.log

``--light`` adds issue 16's tiny light drones on a clear sky (``--tag clsB``, 2026-12-06).
"""

import argparse
import os
import shutil
import sys
from typing import List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
from payload.eval.folds import clip_frames, load_folds  # noqa: E402
from training.cv_train import PY, Log, hard_sets, run_stage, thermal_object_sets, tiny_light_set  # noqa: E402
from training.halmstad import HALMSTAD  # noqa: E402

SHIPPED = os.path.join(REPO, "payload", "models")


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tag", default="clsir2", help="runs and models under training/runs/cv/TAG/")
    ap.add_argument("--init", required=True, help="the classifier (ONNX) to fine-tune: cls5 (see above)")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--lr", type=float, default=5e-4)
    ap.add_argument("--hard-frac", type=float, default=0.25)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--log", default=None)
    ap.add_argument("--light", action="store_true",
                    help="also the tiny light drones on a clear sky (synth_light: seeds 1300+, 2-8 px, positives only "
                         "where the drone stands out by 5 noise units), twice")
    args = ap.parse_args(argv)
    log = Log(args.log)
    folds = load_folds()
    names = sorted(clip_frames(HALMSTAD))
    cache = os.path.join(HERE, "cache")
    run_root = os.path.join(HERE, "runs", "cv", args.tag)
    models_root = os.path.join(run_root, "models")

    run_stage(log, "cache", os.path.join(cache, ".done-cache"), [PY, "training/build_cache.py"],
              [os.path.join(cache, f) for f in ("cls_x.npy", "cls_y.npy")])
    run_stage(log, "thermal cache", os.path.join(cache, ".done-ir"),
              [PY, "training/build_cache.py", "--split", "ir_train", "--name", "ir"], [os.path.join(cache, "ir_cls.npz")])
    synth = os.path.join(cache, "synth_cls.npz"), os.path.join(cache, "synth2_cls.npz"), os.path.join(cache, "mined1_cls.npz")
    run_stage(log, "synthetic patches", os.path.join(cache, ".done-synth"),
              [PY, "training/build_synth_cache.py", "--scenes", "30"], [synth[0]])
    run_stage(log, "synthetic small patches", os.path.join(cache, ".done-synth2"),
              [PY, "training/build_synth_cache.py", "--name", "synth2", "--first-seed", "1100", "--scenes", "30",
               "--target-px", "4", "14"], [synth[1]])
    run_stage(log, "module candidates", os.path.join(cache, ".done-mined1"),
              [PY, "training/mine_candidates.py", os.path.join(SHIPPED, "glad_local.onnx"), "--name", "mined1",
               "--scenes", "30", "--halmstad", "train", "negatives_train"], [synth[2]])
    if args.light:
        light = tiny_light_set(log, cache, 30)
        synth = synth + (light, light)  # a few thousand patches among ~100,000: listed twice
    objects = thermal_object_sets(log, cache, names, folds)

    for target in [str(k) for k in range(folds.k)] + ["all"]:
        hard = hard_sets(objects, target)
        name = "fold" + target if target != "all" else "all"
        rel = os.path.join("cv", args.tag, name, "cls")
        ckpt = os.path.join(HERE, "runs", rel, "last.pt")
        run_stage(log, "%s classifier" % name, os.path.join(HERE, "runs", rel, ".done"),
                  [PY, "training/train_cls.py", "--name", rel, "--init", args.init,
                   "--steps", str(args.steps), "--lr", str(args.lr), "--threads", str(args.threads), "--resume",
                   "--synth", os.path.join(cache, "ir_cls.npz"), *synth, "--hard"] + hard + ["--hard-frac", str(args.hard_frac)],
                  [ckpt])
        models = os.path.join(models_root, name)
        os.makedirs(models, exist_ok=True)
        for other in ("glad_global.onnx", "glad_local.onnx"):
            shutil.copyfile(os.path.join(SHIPPED, other), os.path.join(models, other))
        out = os.path.join(models, "glad_classifier.onnx")
        run_stage(log, "%s export" % name, os.path.join(models, ".done-cls"),
                  [PY, "training/export.py", "cls", ckpt, out], [out], inputs=[ckpt])
    log("finished: glad-payload cv --fold-models %s" % models_root)
    return 0


if __name__ == "__main__":
    sys.exit(main())
