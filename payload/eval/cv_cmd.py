"""``glad-payload cv``: grouped cross-validation of GLAD over the Halmstad clips (payload.eval.cv)."""

import json
import os
import sys
import time
from typing import Any, Dict, List

from payload.errors import DataError
from payload.offline import (
    UsageError,
    camera_for,
    describe_camera,
    find_splits,
    glad_detector,
    with_ego_motion,
)


def _detector_for(args, cfgs) -> Any:
    return lambda fold: glad_detector(cfgs[fold], args.limit, not args.no_progress)


def main_cv(args) -> int:
    from payload.config import config_with, flat_config, load_config
    from payload.eval import cv
    from payload.eval.folds import load_folds

    try:
        if args.limit < 0 or args.limit_clips < 0:
            raise UsageError("--limit and --limit-clips must be >= 0 (0 = all)")
        if not 0.0 < args.iou < 1.0:
            raise UsageError("--iou %s: expected a number between 0 and 1 (the paper uses 0.5)" % args.iou)
        folds = load_folds(args.folds)
        only = sorted(set(args.folds_only)) if args.folds_only else list(range(folds.k))
        if any(not 0 <= f < folds.k for f in only):
            raise UsageError("--folds-only %s: folds are 0..%d" % (" ".join(map(str, args.folds_only)), folds.k - 1))
        data_dir = os.path.dirname(os.path.abspath(find_splits(args.splits)))
        cfg = load_config(args.config)
        if args.fold_models:
            files = cv.fold_model_files(args.fold_models, only)
            cfgs = {f: config_with(cfg, **files[f]) for f in only}
            models = "per fold: %s/fold{k}/" % args.fold_models
        else:
            cfgs = {f: cfg for f in only}
            models = cv.SHIPPED_NOTE
        per_fold = cv.fold_clips(cv.halmstad_clips(data_dir), folds, args.limit_clips)
        if args.ego_motion is not None:
            per_fold = [with_ego_motion(clips, args.ego_motion) for clips in per_fold]
        settings: Dict[str, Any] = {"fold_ranges": folds.ranges, "block_size": folds.block_size, "limit": args.limit}
        if args.ego_motion is not None:  # kept detections of the clips as filmed are not these
            settings["ego_motion"] = args.ego_motion
        fold_settings = {f: {"config": flat_config(c), "models": cv.model_digests(c)} for f, c in cfgs.items()}
        detector_for = _detector_for(args, cfgs)
        if args.dets_dir:
            store = cv.DetectionsStore(args.dets_dir, settings, fold_settings)
            plain = detector_for
            detector_for = lambda fold: store.wrap(fold, plain(fold))  # noqa: E731
    except UsageError as exc:
        print("glad-payload cv: %s" % exc, file=sys.stderr)
        return 2
    print("grouped cross-validation: %d folds of %s (whole blocks of %d consecutive clip numbers per kind)"
          % (folds.k, folds.source, folds.block_size))
    for line in folds.describe():
        print("  " + line)
    print("models: %s" % models)
    subset = []
    if args.limit_clips:
        subset.append("at most %d clips of each kind per fold" % args.limit_clips)
    if args.limit:
        subset.append("the first %d frames of each clip" % args.limit)
    if len(only) < folds.k:
        subset.append("folds %s only" % " ".join(map(str, only)))
    if args.ego_motion is not None:
        subset.append("each warped by a camera path from seed %d" % args.ego_motion)
    print("clips: %d (%s)" % (sum(len(per_fold[f]) for f in only), ", ".join(subset) if subset else "all"), flush=True)
    started = time.time()
    results = cv.run_cv(per_fold, detector_for, camera_for(cfg), args.iou, only)
    summary = cv.summarise(results)
    print()
    print(cv.format_cv(summary))
    print()
    print("mean +- sd over the %d folds%s:" % (len(only), "" if len(only) == folds.k else " run (of %d)" % folds.k))
    for line in cv.headline(summary):
        print("  " + line)
    print("P R F AP: IoU > %g; cP cR cF cAP: box centre inside the labelled box; deg50 deg95: bearing error of "
          "the centre matches, degrees (%s); target%%: frames of negative clips with a reported target"
          % (args.iou, describe_camera(cfg)))
    if not args.fold_models:
        print("NOTE %s (the networks saw most of these clips in training; what this checks honestly are the "
              "thresholds and rules)" % cv.SHIPPED_NOTE)
    if args.json:
        meta = {"command": "glad-payload cv " + " ".join(_argv(args)), "models": models,
                "optimistic": not args.fold_models, "iou_match": args.iou, "camera": describe_camera(cfg),
                "limit": args.limit, "limit_clips": args.limit_clips, "ego_motion": args.ego_motion,
                "folds_file": folds.source, "folds_run": only,
                "fold_ranges": folds.ranges, "seconds": round(time.time() - started, 1)}
        try:
            with open(args.json, "w", encoding="utf-8") as handle:
                json.dump(cv.cv_report(results, summary, meta), handle, indent=1)
                handle.write("\n")
        except OSError as exc:
            raise DataError("%s: cannot write JSON: %s" % (args.json, exc.strerror or exc)) from None
        print("wrote %s" % args.json)
    return 0


def _argv(args) -> List[str]:
    out: List[str] = []
    for flag, value in (("--config", args.config), ("--folds", args.folds), ("--fold-models", args.fold_models),
                        ("--limit", args.limit or None), ("--limit-clips", args.limit_clips or None),
                        ("--ego-motion", args.ego_motion), ("--dets-dir", args.dets_dir), ("--json", args.json)):
        if value is not None:
            out += [flag, str(value)]
    if args.folds_only:
        out += ["--folds-only"] + [str(f) for f in args.folds_only]
    if args.iou != 0.5:
        out += ["--iou", str(args.iou)]
    return out
