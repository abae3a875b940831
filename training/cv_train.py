"""Train one set of GLAD networks per cross-validation fold, each without that fold's clips.

For every fold k of payload/eval/folds.json (whole blocks of consecutive clip numbers per clip
kind, issue 16) this builds fold k's training caches from every clip OUTSIDE fold k, trains
the global detector, the local detector and the classifier with the shipped recipe shortened
(the same step counts for every fold), and exports them to OUT/fold{k}/glad_global.onnx,
glad_local.onnx, glad_classifier.onnx, which ``glad-payload cv --fold-models OUT`` evaluates on
fold k's clips together with fold k's lock verifier (``training/train_verifier.py --export-folds
OUT``: the verifier trained without fold k's locks; payload/models/MODEL_CARD.md).

The shortened recipe (payload/models/MODEL_CARD.md has the shipped one), per fold:
  caches   build_cache.py over the visible drone clips and the visible negatives clips outside
           the fold (det_pos / det_neg / cls_*); build_cache.py --name ir over the thermal drone
           clips outside the fold; with --ir-negatives the thermal negatives clips join the
           negatives. Synthetic scenes (no Halmstad pixels, so shared by all folds):
           build_synth_cache.py seeds 1000+ (4-24 px) and 1100+ (4-14 px), --synth-scenes each.
  global   train_det.py from scratch (no shipped weights: they saw every fold), width 1.5,
           160 px samples, scale 0.45-1.5, 35 % drone-free, extra sets (synthetic, thermal) at
           40 %, lr 3e-3 cosine, --glb-steps (default 2500; shipped: ~12,700 over five runs).
  local    train_det.py from the fold's global detector, scale 0.7-1.4, 30 % drone-free, extra
           sets at 55 %, lr 7e-4, --loc-steps (default 1000).
  classifier the shipped classifier's two steps: train_cls.py from scratch on the fold's patches +
           synthetic + thermal patches, --cls-steps (default 2500; shipped cls5: 5,000); then
           from that network (exported, BatchNorm frozen) --cls-tune-steps (default 1500, as
           shipped: cls14 / clsB) with the tiny light drones on a clear sky (synth_light, twice) and
           the labelled objects of the thermal negatives clips of the OTHER folds as a quarter of
           every batch. Or, with --classifier-from DIR, the fold's classifier of another run.
           (Before 2026-12-07 the figures used clsB's fold classifiers from training/cv_cls_thermal.py,
           which start from the shipped cls5 and train on the train split's patches: their drone
           side had seen most of every fold's clips.)
  Left out of the shortened recipe: the mined hard negatives (mined1, synth_det_mined: mined
  with a detector trained on every clip) and the ego-motion set (ego1).

Every stage is skipped once done (a marker with its command line beside its output; a changed
command runs it again), the training stages resume from their last checkpoint (train_*.py
--resume, saved every 200 steps), so after any interruption the same command continues:

  nice -n 15 python training/cv_train.py --log training/runs/cv/base/train.log &    # all folds
  python training/cv_train.py --folds-only 0 --glb-steps 20 --loc-steps 10 --cls-steps 20 \\
      --tag smoke --max-clips 2 --synth-scenes 1                                     # smoke test

Outputs (gitignored): caches under training/cache/cv/, runs and models under
training/runs/cv/<tag>/ (models: training/runs/cv/<tag>/models/fold{k}/).
"""

import argparse
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from typing import List, Optional, Sequence

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
from payload.eval.folds import clip_frames, load_folds, parse_clip  # noqa: E402
from training.halmstad import HALMSTAD  # noqa: E402

PY = sys.executable
_child: Optional[subprocess.Popen] = None
_stopping: Optional[int] = None


class Log:
    def __init__(self, path: Optional[str]) -> None:
        self.path = path
        if path:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)

    def __call__(self, text: str) -> None:
        line = "%s cv_train: %s" % (time.strftime("%Y-%m-%d %H:%M:%S"), text)
        print(line, flush=True)
        if self.path:
            with open(self.path, "a", encoding="utf-8") as handle:
                handle.write(line + "\n")


def _stop(signum, _frame):
    """SIGTERM/SIGINT: passed on to the running stage (so nothing keeps training unwatched); the
    driver stops once it has exited (run_stage), or at once between stages."""
    global _stopping
    _stopping = signum
    if _child is None:
        raise SystemExit(128 + signum)
    _child.send_signal(signum)


def run_stage(log: Log, name: str, marker: str, argv: List[str], outputs: List[str],
              inputs: Sequence[str] = ()) -> None:
    """Run ``argv`` unless ``marker`` records this very command as done and its outputs exist.
    Outputs older than one of ``inputs`` (the checkpoint a stage starts from or exports) are
    removed first and the stage runs again from the new input, not resumed from the stale one."""
    global _child
    command = " ".join(shlex.quote(a) for a in argv)
    stale = [o for o in outputs if os.path.exists(o)
             and any(os.path.exists(i) and os.path.getmtime(i) > os.path.getmtime(o) for i in inputs)]
    for path in stale:
        log("%s: %s is older than its input, removed" % (name, path))
        os.remove(path)
    if os.path.isfile(marker) and all(os.path.exists(p) for p in outputs):
        with open(marker, encoding="utf-8") as handle:
            if handle.read().strip() == command:
                log("%s: done before, skipped" % name)
                return
    log("%s: start: %s" % (name, command if len(command) < 400 else command[:400] + " ..."))
    started = time.time()
    out = open(log.path, "a", encoding="utf-8") if log.path else None
    try:
        _child = subprocess.Popen(argv, cwd=REPO, stdout=out or None, stderr=subprocess.STDOUT if out else None)
        rc = _child.wait()
    finally:
        _child = None
        if out is not None:
            out.close()
    if _stopping is not None:
        log("%s: stopped by signal %d (exit status %d); the same command resumes" % (name, _stopping, rc))
        raise SystemExit(128 + _stopping)
    if rc != 0:
        log("%s: FAILED with exit status %d" % (name, rc))
        raise SystemExit(1)
    missing = [p for p in outputs if not os.path.exists(p)]
    if missing:
        log("%s: FAILED: no %s" % (name, ", ".join(missing)))
        raise SystemExit(1)
    os.makedirs(os.path.dirname(marker), exist_ok=True)
    with open(marker, "w", encoding="utf-8") as handle:
        handle.write(command + "\n")
    log("%s: done in %.0f s" % (name, time.time() - started))


def select(names: Sequence[str], sensor: str, negatives: bool, limit: int = 0) -> List[str]:
    """The clips of one sensor ('V' or 'IR'): its drone clips, or its negatives (birds, airliners,
    helicopters); the first ``limit`` when > 0."""
    picked = [n for n in names if parse_clip(n)[0].split("_", 1)[0] == sensor
              and parse_clip(n)[0].endswith("_DRONE") != negatives]
    return picked[:limit] if limit else picked


def tiny_light_set(log: Log, cache: str, scenes: int) -> str:
    """The tiny light drones on a clear sky (synth_light: seeds 1300+, 2-8 px, a patch a positive only
    where the drone stands out by 5 noise units), for the classifier's second step; its path."""
    light = os.path.join(cache, "synth_light_cls.npz")
    run_stage(log, "tiny light drone patches", os.path.join(cache, ".done-synth_light"),
              [PY, "training/build_synth_cache.py", "--cache", cache, "--name", "synth_light", "--first-seed", "1300",
               "--scenes", str(scenes), "--target-px", "2", "8", "--drone", "light", "--sky", "clear", "--in-sky",
               "--min-noise", "5"], [light])
    return light


def thermal_object_sets(log: Log, cache: str, names: Sequence[str], folds, max_clips: int = 0) -> List[str]:
    """The labelled objects of the thermal negatives clips, one set per fold k from fold k's clips
    only (irobj{k}_cls.npz), hard negatives for the classifier's second step; their paths, fold by fold."""
    objects = []
    for fold in range(folds.k):
        clips = [n for n in select(names, "IR", True, max_clips) if folds.fold_of(n) == fold]
        path = os.path.join(cache, "irobj%d_cls.npz" % fold)
        run_stage(log, "thermal objects of fold %d (%d clips)" % (fold, len(clips)),
                  os.path.join(cache, ".done-irobj%d" % fold),
                  [PY, "training/build_cache.py", "--cache", cache, "--split", "ir_negatives_train", "--objects",
                   "--name", "irobj%d" % fold, "--clips"] + clips, [path])
        objects.append(path)
    return objects


def hard_sets(objects: List[str], target: str) -> List[str]:
    """The thermal-object sets (one per fold, ``objects[j]`` from fold j's clips) that the classifier
    of ``target`` ('0', '1', ... or 'all') may train on: every fold's but its own."""
    return [path for j, path in enumerate(objects) if target == "all" or j != int(target)]


def given_classifier(root: str, fold: int) -> str:
    return os.path.join(root, "fold%d" % fold, "glad_classifier.onnx")


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tag", default="base", help="names the runs and models folder: training/runs/cv/TAG/")
    ap.add_argument("--folds", default=None, help="fold definition (default payload/eval/folds.json)")
    ap.add_argument("--folds-only", type=int, nargs="*", default=None, metavar="K", help="train only these folds")
    ap.add_argument("--glb-steps", type=int, default=2500)
    ap.add_argument("--loc-steps", type=int, default=1000)
    ap.add_argument("--cls-steps", type=int, default=2500)
    ap.add_argument("--cls-tune-steps", type=int, default=1500, help="the classifier's second step (shipped: 1,500)")
    ap.add_argument("--classifier-from", default=None, metavar="DIR",
                    help="take each fold's classifier from DIR/fold{k}/glad_classifier.onnx (another run's, e.g. "
                         "the shipped classifier's recipe per fold) instead of training the shortened one")
    ap.add_argument("--synth-scenes", type=int, default=30, help="synthetic scenes per synthetic set (two sets)")
    ap.add_argument("--ir-negatives", action="store_true", help="thermal negatives clips join the negatives")
    ap.add_argument("--threads", type=int, default=1, help="torch threads per training run")
    ap.add_argument("--max-clips", type=int, default=0, help="at most N clips per list (smoke tests only)")
    ap.add_argument("--log", default=None, help="append progress here as well as to stdout")
    args = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    log = Log(args.log)

    folds = load_folds(args.folds)
    names = sorted(clip_frames(HALMSTAD))
    if not names:
        log("no clips under %s" % HALMSTAD)
        return 2
    smoke = "-smoke%d" % args.max_clips if args.max_clips else ""
    cache_root = os.path.join(HERE, "cache", "cv" + smoke)
    common = os.path.join(cache_root, "common-s%d" % args.synth_scenes)
    run_root = os.path.join(HERE, "runs", "cv", args.tag)
    models_root = os.path.join(run_root, "models")
    log("tag=%s folds=%s (k=%d) steps glb=%d loc=%d cls=%d synth_scenes=%d ir_negatives=%s clips=%d"
        % (args.tag, folds.source, folds.k, args.glb_steps, args.loc_steps, args.cls_steps, args.synth_scenes,
           args.ir_negatives, len(names)))

    todo = args.folds_only if args.folds_only is not None else list(range(folds.k))
    wrong = [fold for fold in todo if not 0 <= fold < folds.k]
    if wrong:
        log("--folds-only %d: no such fold (k=%d)" % (wrong[0], folds.k))
        return 2
    missing = [given_classifier(args.classifier_from, fold) for fold in todo] if args.classifier_from else []
    missing = [path for path in missing if not os.path.isfile(path)]
    if missing:  # before anything trains
        log("--classifier-from %s: no %s" % (args.classifier_from, ", ".join(missing)))
        return 2
    for name, extra in (("synth", []), ("synth2", ["--first-seed", "1100", "--target-px", "4", "14"])):
        run_stage(log, "common %s" % name, os.path.join(common, ".done-" + name),
                  [PY, "training/build_synth_cache.py", "--cache", common, "--name", name,
                   "--scenes", str(args.synth_scenes)] + extra,
                  [os.path.join(common, name + "_det.npz"), os.path.join(common, name + "_cls.npz")])

    if not args.classifier_from:  # the classifier's second step: built once for every fold
        light = tiny_light_set(log, common, args.synth_scenes)
        objects = thermal_object_sets(log, common, names, folds, args.max_clips)
    for fold in todo:
        outside = folds.training(names, fold)

        v_drones = select(outside, "V", False, args.max_clips)
        ir_drones = select(outside, "IR", False, args.max_clips)
        negatives = select(outside, "V", True, args.max_clips)
        if args.ir_negatives:
            negatives += select(outside, "IR", True, args.max_clips)
        held = sorted(set(names) - set(outside))
        log("fold %d: holds out %d clips; trains on %d visible drone, %d negatives (%s), %d thermal drone clips"
            % (fold, len(held), len(v_drones), len(negatives), "visible + thermal" if args.ir_negatives else "visible",
               len(ir_drones)))
        cache = os.path.join(cache_root, "fold%d%s" % (fold, "-irneg" if args.ir_negatives else ""))
        runs = os.path.join(run_root, "fold%d" % fold)
        models = os.path.join(models_root, "fold%d" % fold)
        os.makedirs(models, exist_ok=True)
        with open(os.path.join(models, "clips.json"), "w", encoding="utf-8") as handle:
            json.dump({"fold": fold, "held_out": held, "visible_drones": v_drones, "negatives": negatives,
                       "thermal_drones": ir_drones}, handle, indent=1)
        main_cache = ["det_pos.npy", "det_pos_xyxy.npy", "det_neg.npy", "cls_x.npy", "cls_y.npy"]
        run_stage(log, "fold %d cache" % fold, os.path.join(cache, ".done-cache"),
                  [PY, "training/build_cache.py", "--cache", cache, "--clips"] + v_drones + ["--negatives"] + negatives,
                  [os.path.join(cache, f) for f in main_cache])
        run_stage(log, "fold %d thermal cache" % fold, os.path.join(cache, ".done-ir"),
                  [PY, "training/build_cache.py", "--cache", cache, "--split", "ir_train", "--name", "ir", "--clips"]
                  + ir_drones, [os.path.join(cache, "ir_det.npz"), os.path.join(cache, "ir_cls.npz")])

        extra_det = [os.path.join(common, "synth_det.npz"), os.path.join(common, "synth2_det.npz"),
                     os.path.join(cache, "ir_det.npz")]
        extra_cls = [os.path.join(common, "synth_cls.npz"), os.path.join(common, "synth2_cls.npz"),
                     os.path.join(cache, "ir_cls.npz")]
        det_common = ["--cache", cache, "--width", "1.5", "--size", "160", "--wh-weight", "2",
                      "--threads", str(args.threads), "--resume", "--synth"] + extra_det
        rel = os.path.relpath(runs, os.path.join(HERE, "runs"))
        glb = os.path.join(runs, "glb", "last.pt")
        run_stage(log, "fold %d global detector" % fold, os.path.join(runs, "glb", ".done"),
                  [PY, "training/train_det.py", "--name", os.path.join(rel, "glb"), "--steps", str(args.glb_steps),
                   "--lr", "3e-3", "--scale-max", "1.5", "--neg-frac", "0.35", "--synth-frac", "0.4"] + det_common,
                  [glb])
        loc = os.path.join(runs, "loc", "last.pt")
        run_stage(log, "fold %d local detector" % fold, os.path.join(runs, "loc", ".done"),
                  [PY, "training/train_det.py", "--name", os.path.join(rel, "loc"), "--init", glb,
                   "--steps", str(args.loc_steps), "--lr", "7e-4", "--scale-min", "0.7", "--scale-max", "1.4",
                   "--neg-frac", "0.3", "--synth-frac", "0.55"] + det_common, [loc], inputs=[glb])
        exports = [("det", glb, "glad_global.onnx"), ("det", loc, "glad_local.onnx")]
        if args.classifier_from:
            given = given_classifier(args.classifier_from, fold)
            shutil.copyfile(given, os.path.join(models, "glad_classifier.onnx"))
            log("fold %d classifier: copied from %s" % (fold, given))
        else:
            cls = os.path.join(runs, "cls", "last.pt")
            run_stage(log, "fold %d classifier" % fold, os.path.join(runs, "cls", ".done"),
                      [PY, "training/train_cls.py", "--name", os.path.join(rel, "cls"), "--steps", str(args.cls_steps),
                       "--cache", cache, "--threads", str(args.threads), "--resume", "--synth"] + extra_cls, [cls])
            first = os.path.join(runs, "cls", "first_step.onnx")
            run_stage(log, "fold %d export the classifier's first step" % fold, os.path.join(runs, "cls", ".done-export"),
                      [PY, "training/export.py", "cls", cls, first], [first], inputs=[cls])
            # The second step as shipped (cls14 -> clsB): from the exported file, BatchNorm frozen, with the
            # labelled thermal birds, airliners and helicopters of the other folds as hard negatives and the
            # tiny light drones twice; nothing of this fold's clips.
            tuned = os.path.join(runs, "cls_tuned", "last.pt")
            run_stage(log, "fold %d classifier, second step" % fold, os.path.join(runs, "cls_tuned", ".done"),
                      [PY, "training/train_cls.py", "--name", os.path.join(rel, "cls_tuned"), "--init", first,
                       "--steps", str(args.cls_tune_steps), "--lr", "5e-4", "--cache", cache,
                       "--threads", str(args.threads), "--resume", "--synth"] + extra_cls + [light, light]
                      + ["--hard"] + hard_sets(objects, str(fold)) + ["--hard-frac", "0.25"],
                      [tuned], inputs=[first])
            exports.append(("cls", tuned, "glad_classifier.onnx"))
        for kind, ckpt, out in exports:
            target = os.path.join(models, out)
            run_stage(log, "fold %d export %s" % (fold, out), os.path.join(models, ".done-" + out),
                      [PY, "training/export.py", kind, ckpt, target], [target], inputs=[ckpt])
        log("fold %d: models in %s" % (fold, models))
    log("finished: glad-payload cv --fold-models %s" % models_root)
    return 0


if __name__ == "__main__":
    sys.exit(main())
