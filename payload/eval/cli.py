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

import dataclasses
import json
import logging
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

from payload.errors import DataError
from payload.eval.labels import load_labels
from payload.eval.metrics import IOU_MATCH, ClipScore, pool, score_clip
from payload.records import read_detections_csv
from payload.types import Detections

log = logging.getLogger(__name__)

SPLITS_REL = os.path.join("shared", "data", "halmstad", "splits.json")
LABEL_SUFFIXES = (".csv", ".txt")

DetectFn = Callable[["ClipSpec"], Mapping[int, Detections]]


@dataclass(frozen=True)
class ClipSpec:
    """A clip to run the detector on and the labels to score it against.

    ``capture``: where the frames come from when they are not the ``video`` file (a synthetic
    scene rendered in memory); ``video`` then only names it. ``ego_motion``: frames and labels
    warped as if filmed by a moving camera (``--ego-motion``).
    """

    name: str
    video: str
    labels: str
    capture: Optional[Any] = None  # payload.config.CaptureConfig
    ego_motion: Optional[Any] = None  # payload.synth.ego_motion.EgoMotionWarp


class UsageError(Exception):
    """Wrong arguments or missing shared data: one line, exit status 2."""


def find_splits(explicit: Optional[str] = None) -> str:
    """splits.json: ``explicit``, else ../shared/... beside the repository root or the cwd."""
    if explicit:
        if not os.path.isfile(explicit):
            raise UsageError("--splits %s: no such file" % explicit)
        return explicit
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    candidates = [os.path.join(os.path.dirname(repo), SPLITS_REL),
                  os.path.join(os.path.dirname(os.getcwd()), SPLITS_REL),
                  os.path.join(os.getcwd(), SPLITS_REL)]
    for path in candidates:
        if os.path.isfile(path):
            return path
    raise UsageError("Halmstad splits.json not found (looked in %s); pass --splits PATH" % ", ".join(sorted(set(candidates))))


def split_clips(splits_path: str, split: str) -> List[ClipSpec]:
    """The clips of one or more comma-separated splits, e.g. ``val,negatives_val``."""
    try:
        with open(splits_path, encoding="utf-8") as handle:
            splits = json.load(handle)
    except (OSError, ValueError) as exc:
        raise UsageError("%s: cannot read splits: %s" % (splits_path, exc)) from None
    data_dir = os.path.dirname(os.path.abspath(splits_path))
    clips = []
    for key in [s.strip() for s in split.split(",") if s.strip()]:
        if not isinstance(splits, dict) or not isinstance(splits.get(key), list):
            raise UsageError("--split %s: no such split in %s (have: %s)"
                             % (key, splits_path, ", ".join(sorted(splits)) if isinstance(splits, dict) else "none"))
        for name in splits[key]:
            videos = [os.path.join(data_dir, sub, "%s.mp4" % name) for sub in ("visible", "ir")]
            video = next((v for v in videos if os.path.isfile(v)), None)
            if video is None:
                raise UsageError("clip %s of split %s: no video at %s" % (name, key, " or ".join(videos)))
            labels = os.path.join(data_dir, "labels", "%s.csv" % name)
            if not os.path.isfile(labels):
                raise UsageError("clip %s of split %s: no labels at %s" % (name, key, labels))
            clips.append(ClipSpec(name, video, labels))
    if not clips:
        raise UsageError("--split %r names no clips" % split)
    return clips


def _labels_for(video: str, given: Sequence[str], position: int) -> str:
    if len(given) > 1:
        return given[position]
    stem = os.path.splitext(os.path.basename(video))[0]
    folder = os.path.dirname(os.path.abspath(video))
    candidates = []
    if len(given) == 1:
        if os.path.isdir(given[0]):
            candidates += [os.path.join(given[0], stem + s) for s in LABEL_SUFFIXES]
        else:
            candidates.append(given[0])
    candidates += [os.path.join(folder, stem + s) for s in LABEL_SUFFIXES]
    candidates += [os.path.join(os.path.dirname(folder), "labels", stem + s) for s in LABEL_SUFFIXES]
    candidates.append(os.path.join(folder, stem, "gt", "gt.txt"))
    for path in candidates:
        if os.path.isfile(path):
            return path
    if len(given) == 1 and os.path.isdir(given[0]) and any(n.lower().endswith(".xml") for n in os.listdir(given[0])):
        return given[0]  # a Pascal VOC folder: the labels of this one clip
    raise UsageError("%s: no labels found (looked for %s)" % (video, ", ".join(candidates)))


def clips_from_paths(videos: Sequence[str], labels: Sequence[str]) -> List[ClipSpec]:
    """``--clips`` videos with labels given one per clip, in one folder, or found beside them."""
    if len(labels) > 1 and len(labels) != len(videos):
        raise UsageError("--clips has %d videos but --labels has %d paths (give one per clip, or one folder)"
                         % (len(videos), len(labels)))
    clips = []
    for i, video in enumerate(videos):
        if not os.path.isfile(video):
            raise UsageError("--clips %s: no such file" % video)
        clips.append(ClipSpec(os.path.splitext(os.path.basename(video))[0], video, _labels_for(video, labels, i)))
    return clips


def synthetic_clip(cfg, out_dir: str, frames: int, seed: Optional[int] = None,
                   target_px: Optional[Sequence[float]] = None, video: bool = True) -> ClipSpec:
    """The configured synthetic scene (``seed``/``target_px`` override it) and its labels under
    ``out_dir``. ``video``: written as an MP4 and read back like a recording (the bench measures
    decoding); otherwise rendered again in memory when the clip is run, frames exactly as drawn."""
    from payload.capture.synthetic import scene_of
    from payload.synth.export import export_clip, write_labels

    s = cfg.capture.synthetic.model_copy(update={
        "seed": cfg.capture.synthetic.seed if seed is None else seed,
        "frames": frames,
        "target_px": tuple(target_px if target_px is not None else cfg.capture.synthetic.target_px),
    })
    scene = scene_of(s)
    name = "SYN_%d_%dx%d" % (s.seed, s.width, s.height)
    log.info("rendering synthetic clip name=%s frames=%d target_px=%s video=%s", name, frames, list(s.target_px), video)
    if video:
        path, labels = export_clip(scene, out_dir, name)
        return ClipSpec(name, path, labels)
    labels = write_labels(scene, out_dir, name)
    capture = cfg.capture.model_copy(update={"source": "synthetic", "synthetic": s, "loop": False, "pace": False})
    return ClipSpec(name, "synthetic scene seed %d" % s.seed, labels, capture)


def synthetic_clips(cfg, out_dir: str, frames: int, seeds: Sequence[int],
                    target_px: Optional[Sequence[float]] = None) -> List[ClipSpec]:
    """One synthetic clip per seed (``--synthetic``), rendered in memory."""
    if target_px is not None and not 0 < target_px[0] <= target_px[1]:
        raise UsageError("--target-px %s %s: expected 0 < MIN <= MAX" % tuple(target_px))
    return [synthetic_clip(cfg, out_dir, frames, seed, target_px, video=False) for seed in seeds]


def with_ego_motion(clips: Sequence[ClipSpec], seed: int) -> List[ClipSpec]:
    """The recordings warped by synthetic camera motion, one seeded camera path per clip."""
    import cv2

    from payload.synth.ego_motion import EgoMotionWarp

    warped = []
    for position, clip in enumerate(clips):
        cap = cv2.VideoCapture(clip.video)
        size_wh = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        fps = cap.get(cv2.CAP_PROP_FPS)
        cap.release()
        if min(size_wh) <= 0:
            raise UsageError("%s: cannot read the video's frame size for --ego-motion" % clip.video)
        warp = EgoMotionWarp((seed, position), size_wh, fps)
        warped.append(dataclasses.replace(clip, name=clip.name + "~ego%d" % seed, ego_motion=warp))
    return warped


def clip_frame_size(clip: ClipSpec) -> Tuple[int, int]:
    """(width, height) of the clip's frames: the synthetic scene's, else the video's header."""
    if clip.capture is not None and clip.capture.source == "synthetic":
        return int(clip.capture.synthetic.width), int(clip.capture.synthetic.height)
    import cv2

    cap = cv2.VideoCapture(clip.video)
    size = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    if min(size) <= 0:
        raise UsageError("%s: cannot read the video's frame size (for the bearing error)" % clip.video)
    return size


def camera_for(cfg) -> Callable[[Tuple[int, int]], Any]:
    """Frame size -> the config's camera model at that size (payload.geometry.CameraModel)."""
    from payload.geometry import CameraModel

    return lambda size_wh: CameraModel.from_config(cfg.camera, size_wh)


def score_detection_files(dets: Sequence[str], labels: Sequence[str], iou_match: float = IOU_MATCH,
                          camera=None) -> List[ClipScore]:
    """Score existing CSVs; ``camera``: the camera model of their frames (None: no bearing error)."""
    if len(dets) != len(labels):
        raise UsageError("--dets has %d files but --labels has %d (give one label file or folder per CSV)"
                         % (len(dets), len(labels)))
    scores = []
    for dets_path, labels_path in zip(dets, labels):
        gt = load_labels(labels_path)
        found = read_detections_csv(dets_path)
        scores.append(score_clip(os.path.splitext(os.path.basename(dets_path))[0], found, gt, iou_match=iou_match,
                                 camera=camera))
    return scores


def score_clips(clips: Sequence[ClipSpec], detect: DetectFn, iou_match: float = IOU_MATCH,
                camera: Optional[Callable[[Tuple[int, int]], Any]] = None) -> List[ClipScore]:
    """Run ``detect`` (clip -> frame -> Detections, every frame present) and score each clip;
    ``camera``: frame size -> camera model, for the bearing error (None: not measured)."""
    labels = {clip.name: load_labels(clip.labels) for clip in clips}  # bad labels fail before any detection
    scores = []
    for clip in clips:
        found = detect(clip)
        frames = max(found) + 1 if found else 0
        gt = labels[clip.name] if clip.ego_motion is None else clip.ego_motion.labels(labels[clip.name])
        model = camera(clip_frame_size(clip)) if camera is not None else None
        score = score_clip(clip.name, found, gt, frames=frames, iou_match=iou_match, camera=model)
        log.info("eval clip=%s frames=%d gt=%d tp=%d fp=%d centre_tp=%d", clip.name, score.frames, score.gt, score.tp,
                 score.fp, score.centre.tp if score.centre is not None else -1)
        scores.append(score)
    return scores


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


def _glad_detector(args, cfg) -> DetectFn:
    # Imported here: scoring existing CSVs must not need the models or onnxruntime.
    from payload.detect_cmd import run_detect

    def detect(clip: ClipSpec) -> Dict[int, Detections]:
        warp = clip.ego_motion.frame if clip.ego_motion is not None else None
        return run_detect(clip.video, cfg, limit=args.limit, progress=not args.no_progress, capture=clip.capture,
                          warp=warp)

    return detect


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


def describe_camera(cfg) -> str:
    """How the bearing error's camera model was made, for the printed legend."""
    if cfg.camera.matrix is not None:
        return "camera: calibrated matrix %s%s" % (list(cfg.camera.matrix), " with distortion" if cfg.camera.distortion else "")
    return "camera: camera.hfov_deg %g at each clip's frame size, no calibration" % cfg.camera.hfov_deg


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
        return score_clips(clips, _glad_detector(args, cfg), args.iou, camera_for(cfg)), describe_camera(cfg)
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
