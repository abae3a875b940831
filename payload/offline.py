"""What the offline tools share: the clips to run GLAD on, running it over a recording, scoring.

``glad-payload detect``, ``eval``, ``cv`` and ``bench`` (and the training scripts) all take
clips (a Halmstad split, video files with their labels, or a synthetic scene), run GLAD over
every frame of each, and score the detections against the labels; the commands only parse
arguments and print. A clip may be warped by synthetic camera motion (``--ego-motion``).
"""

import dataclasses
import json
import logging
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

from payload.config import CaptureConfig, Config
from payload.errors import SourceError
from payload.eval.labels import load_labels
from payload.eval.metrics import IOU_MATCH, ClipScore, score_clip
from payload.records import read_detections_csv
from payload.types import Detections, Frame

if TYPE_CHECKING:
    from payload.detect.pipeline import GladResult

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


#: Between a recording's name and the camera path that warped it (``with_ego_motion``).
WARPED_MARK = "~"


def check_ego_motion_seed(seed: int) -> None:
    """Refuse (UsageError, one line) a camera-path seed numpy's seeding cannot take, before any clip is read."""
    if seed < 0:
        raise UsageError("--ego-motion %d: expected a seed >= 0" % seed)


def with_ego_motion(clips: Sequence[ClipSpec], seed: int) -> List[ClipSpec]:
    """The recordings warped by synthetic camera motion, one seeded camera path per clip."""
    import cv2

    from payload.synth.ego_motion import EgoMotionWarp

    check_ego_motion_seed(seed)
    warped = []
    for position, clip in enumerate(clips):
        cap = cv2.VideoCapture(clip.video)
        size_wh = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        fps = cap.get(cv2.CAP_PROP_FPS)
        cap.release()
        if min(size_wh) <= 0:
            raise UsageError("%s: cannot read the video's frame size for --ego-motion" % clip.video)
        warp = EgoMotionWarp((seed, position), size_wh, fps)
        warped.append(dataclasses.replace(clip, name=clip.name + WARPED_MARK + "ego%d" % seed, ego_motion=warp))
    return warped


def recorded_name(name: str) -> str:
    """The recording a clip name stands for: ``V_DRONE_013~ego7`` (``with_ego_motion``) -> ``V_DRONE_013``."""
    return name.split(WARPED_MARK, 1)[0]


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


def describe_camera(cfg) -> str:
    """How the bearing error's camera model was made, for the printed legend."""
    if cfg.camera.matrix is not None:
        return "camera: calibrated matrix %s%s" % (list(cfg.camera.matrix), " with distortion" if cfg.camera.distortion else "")
    return "camera: camera.hfov_deg %g at each clip's frame size, no calibration" % cfg.camera.hfov_deg


def recording_config(cfg: Config, source: str) -> Config:
    """``cfg`` with its capture section pointed at a video file or image folder."""
    if not os.path.exists(source):
        raise SourceError("%s: no such file or folder" % source)
    kind = "folder" if os.path.isdir(source) else "file"
    capture = cfg.capture.model_copy(update={"source": kind, "path": source, "loop": False, "pace": False})
    return cfg.model_copy(update={"capture": capture})


def _frame_count(source: str) -> Optional[int]:
    if os.path.isdir(source):
        return None
    import cv2

    cap = cv2.VideoCapture(source)
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    return n if n > 0 else None


def iter_glad(source: str, cfg: Config, limit: int = 0, progress: bool = True,
              capture: Optional[CaptureConfig] = None,
              warp: Optional[Callable[[Frame], Frame]] = None) -> Iterator[Tuple[Frame, "GladResult"]]:
    """Run GLAD over every frame of a recording (at most ``limit`` frames when > 0); ``capture``
    replaces the recording (e.g. a finite synthetic scene), ``source`` then only names it;
    ``warp`` changes each frame first (e.g. synthetic ego-motion)."""
    # Imported here: scoring existing CSVs must not need the models or onnxruntime.
    from payload.capture import open_source
    from payload.detect.pipeline import Glad

    if capture is None:
        cfg = recording_config(cfg, source)
        total = _frame_count(source)
    else:
        cfg = cfg.model_copy(update={"capture": capture})
        total = capture.synthetic.frames if capture.source == "synthetic" and capture.synthetic.frames else None
    glad = Glad(cfg.detector)
    if limit and total:
        total = min(total, limit)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=os.path.basename(source.rstrip("/")), unit="frame", leave=False)
    try:
        with open_source(cfg.capture) as frames:
            for frame in frames:
                if limit and frame.index >= limit:
                    break
                if warp is not None:
                    frame = warp(frame)
                yield frame, glad.process(frame)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()


def run_detect(source: str, cfg: Config, limit: int = 0, progress: bool = True,
               capture: Optional[CaptureConfig] = None,
               warp: Optional[Callable[[Frame], Frame]] = None) -> Dict[int, Detections]:
    """Frame index -> GLAD's detections for that frame, over a whole recording (or ``capture``)."""
    return {frame.index: result.detections
            for frame, result in iter_glad(source, cfg, limit, progress, capture=capture, warp=warp)}


def glad_detector(cfg: Config, limit: int = 0, progress: bool = True) -> DetectFn:
    """GLAD with ``cfg`` as a DetectFn: each clip from its first frame (a fresh detector), its
    synthetic scene or ego-motion warp applied, at most ``limit`` frames when > 0."""

    def detect(clip: ClipSpec) -> Dict[int, Detections]:
        warp = clip.ego_motion.frame if clip.ego_motion is not None else None
        return run_detect(clip.video, cfg, limit=limit, progress=progress, capture=clip.capture, warp=warp)

    return detect
