"""``glad-payload eval``: score detections CSVs against labels, or run GLAD over clips and score.

Two modes:
- ``--dets A.csv B.csv --labels A.csv B.csv``: score existing detections, pairwise.
- ``--split val[,negatives_val]`` (Halmstad splits.json) or ``--clips a.mp4 ...``: run the
  detector over each clip, then score; ``--ego-motion SEED`` warps those recordings (frames and
  labels) as if the camera moved.
Both print one row per clip and a POOLED row (counts summed, detections ranked together):
the paper's P/R/F/AP at IoU > 0.5, then the same by centre-in-box matching (cP cR cF cAP) and
the median and 95th percentile of the bearing error of its true positives in degrees (deg50,
deg95; camera model from the config's camera section at each clip's frame size).
"""

import json
import math
import sys
import tempfile
from typing import List, Optional, Sequence, Tuple

from payload.errors import DataError
from payload.eval.metrics import IOU_MATCH, ClipScore, pool
from payload.offline import (
    UsageError,
    camera_for,
    clips_from_paths,
    describe_camera,
    find_splits,
    glad_detector,
    score_clips,
    score_detection_files,
    split_clips,
    synthetic_clips,
    with_ego_motion,
)


def _cell(value: float, percent: bool = False, fmt: str = "%.3f") -> str:
    if isinstance(value, float) and math.isnan(value):
        return "-"
    return "%.1f" % (100.0 * value) if percent else fmt % value


NAN = float("nan")
TABLE_LEGEND = ("P R F AP: IoU > %g; cP cR cF cAP: centre of the box inside the labelled box; deg50 deg95: "
                "bearing error of those centre matches, median and 95th percentile, degrees")


def format_table(scores: Sequence[ClipScore], pooled: Optional[ClipScore] = None) -> str:
    """Fixed-column text table: one row per clip, then the pooled row. The first eleven columns
    (clip .. det%) keep their order; the centre-in-box and bearing columns follow."""
    rows = list(scores) + ([pooled] if pooled is not None else [])
    width = max([len("clip")] + [len(s.name) for s in rows])
    header = "%-*s %7s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s" % (
        width, "clip", "frames", "gt", "tp", "fp", "fn", "P", "R", "F", "AP", "det%",
        "cP", "cR", "cF", "cAP", "deg50", "deg95")
    lines = [header, "-" * len(header)]
    for i, s in enumerate(rows):
        if pooled is not None and i == len(rows) - 1:
            lines.append("-" * len(header))
        c = s.centre
        lines.append("%-*s %7d %6d %6d %6d %6d %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s %6s" % (
            width, s.name, s.frames, s.gt, s.tp, s.fp, s.fn, _cell(s.precision), _cell(s.recall),
            _cell(s.f1), _cell(s.ap), _cell(s.frames_with_detections, percent=True),
            _cell(c.precision if c else NAN), _cell(c.recall if c else NAN), _cell(c.f1 if c else NAN),
            _cell(c.ap if c else NAN), _cell(s.bearing_median_deg, fmt="%.2f"), _cell(s.bearing_p95_deg, fmt="%.2f")))
    return "\n".join(lines)


def write_json(path: str, scores: Sequence[ClipScore], pooled: ClipScore, iou_match: float = IOU_MATCH) -> None:
    try:
        with open(path, "w", encoding="utf-8") as handle:
            json.dump({"iou_match": iou_match, "clips": [s.as_dict() for s in scores], "pooled": pooled.as_dict()},
                      handle, indent=2)
            handle.write("\n")
    except OSError as exc:
        raise DataError("%s: cannot write JSON: %s" % (path, exc.strerror or exc)) from None


def main_eval(args) -> int:
    try:
        with tempfile.TemporaryDirectory(prefix="glad-eval-") as tmp:
            scores, camera_note = _scores(args, tmp)
    except UsageError as exc:
        print("glad-payload eval: %s" % exc, file=sys.stderr)
        return 2
    pooled = pool(scores)
    print(format_table(scores, pooled))
    print(TABLE_LEGEND % args.iou + " (%s)" % camera_note)
    if args.iou != IOU_MATCH:
        print("(matched at IoU > %g, not the paper's 0.5)" % args.iou)
    if args.json:
        write_json(args.json, scores, pooled, args.iou)
        print("wrote %s" % args.json)
    return 0


def _scores(args, tmp: str) -> Tuple[List[ClipScore], str]:
    if args.ego_motion is not None and not (args.split or args.clips):
        raise UsageError("--ego-motion warps recordings: give it with --split or --clips")
    if not 0.0 < args.iou < 1.0:
        raise UsageError("--iou %s: expected a number between 0 and 1 (the paper uses 0.5)" % args.iou)
    sources = [name for name, given in (("--split", args.split), ("--clips", args.clips),
                                        ("--synthetic", args.synthetic)) if given]
    if len(sources) > 1:
        raise UsageError("give one of --split, --clips, --synthetic, not %s" % " and ".join(sources))
    from payload.config import load_config

    if sources:
        if args.dets:
            raise UsageError("--dets scores existing CSVs; it does not combine with %s" % sources[0])
        if args.frame_size is not None:
            raise UsageError("--frame-size is for --dets; %s reads each clip's frame size" % sources[0])
        cfg = load_config(args.config)
        if args.split:
            clips = split_clips(find_splits(args.splits), args.split)
        elif args.clips:
            clips = clips_from_paths(args.clips, args.labels)
        else:
            clips = synthetic_clips(cfg, tmp, args.frames, args.synthetic, args.target_px)
        if args.ego_motion is not None:
            clips = with_ego_motion(clips, args.ego_motion)
        return score_clips(clips, glad_detector(cfg, args.limit, not args.no_progress), args.iou, camera_for(cfg)), describe_camera(cfg)
    if args.dets:
        cfg = load_config(args.config)
        if args.frame_size is None:
            return (score_detection_files(args.dets, args.labels, args.iou),
                    "no bearing error: give --frame-size W H of the --dets clips")
        if min(args.frame_size) <= 0:
            raise UsageError("--frame-size %d %d: expected positive width and height" % tuple(args.frame_size))
        camera = camera_for(cfg)(tuple(args.frame_size))
        return score_detection_files(args.dets, args.labels, args.iou, camera), describe_camera(cfg)
    raise UsageError("nothing to score: give --dets with --labels, --split NAME, --clips VIDEO... or --synthetic SEED...")
