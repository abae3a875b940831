"""The paper's evaluation protocol (from Dogfight): TP at IoU > 0.5, P/R/F and 11-point AP;
beside it the bearing-level measure: centre-in-box matching and the bearing error.

Per frame, detections are matched greedily, highest score first, each to the unmatched
ground-truth box it overlaps most; a match needs IoU strictly above 0.5. AP is the 11-point
interpolated area under the precision-recall curve of all detections of the clip ranked by
score (pooled clips: of all their detections together). Undefined ratios (precision with no
detection, recall or AP with no ground truth) are NaN, never a made-up 0 or 1.

Centre-in-box (what a bearing needs: the autopilot steers at the box's centre, not its size):
a detection is a true positive when its centre lies inside a labelled box (edges included),
one-to-one per frame, highest score first, each taking the free box whose centre is nearest
its own. The bearing error of such a true positive is the angle between the camera rays
through the detection's centre and through the label's centre (payload.geometry.CameraModel).
"""

import math
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence

import numpy as np

from payload.boxes import iou_matrix
from payload.types import Detections

IOU_MATCH = 0.5  # a true positive needs IoU strictly greater than this
RECALL_POINTS = np.arange(11) / 10.0  # exact k/10, compared with exact-rational recalls


def match_frame(dets: Detections, gt_xyxy: np.ndarray, iou_match: float = IOU_MATCH) -> np.ndarray:
    """Boolean per detection (in ``dets`` order): True when it is a true positive."""
    is_tp = np.zeros(len(dets), bool)
    gt = np.asarray(gt_xyxy, np.float64).reshape(-1, 4)
    if not len(dets) or not len(gt):
        return is_tp
    iou = iou_matrix(dets.xyxy, gt)
    taken = np.zeros(len(gt), bool)
    for i in np.argsort(-dets.score, kind="stable"):
        free = np.where(taken, -1.0, iou[i])
        j = int(np.argmax(free))
        if free[j] > iou_match:
            taken[j] = True
            is_tp[i] = True
    return is_tp


def centre_match_frame(dets: Detections, gt_xyxy: np.ndarray) -> np.ndarray:
    """Per detection (in ``dets`` order) the index of the labelled box it matches by centre-in-box,
    -1 for none: highest score first, each to the free box containing its centre whose centre is
    nearest (ties: the lower index)."""
    match = np.full(len(dets), -1, np.int64)
    gt = np.asarray(gt_xyxy, np.float64).reshape(-1, 4)
    if not len(dets) or not len(gt):
        return match
    xyxy = np.asarray(dets.xyxy, np.float64).reshape(-1, 4)
    cx, cy = (xyxy[:, 0] + xyxy[:, 2]) / 2.0, (xyxy[:, 1] + xyxy[:, 3]) / 2.0
    inside = ((cx[:, None] >= gt[None, :, 0]) & (cx[:, None] <= gt[None, :, 2])
              & (cy[:, None] >= gt[None, :, 1]) & (cy[:, None] <= gt[None, :, 3]))
    dist = np.hypot(cx[:, None] - (gt[None, :, 0] + gt[None, :, 2]) / 2.0,
                    cy[:, None] - (gt[None, :, 1] + gt[None, :, 3]) / 2.0)
    taken = np.zeros(len(gt), bool)
    for i in np.argsort(-dets.score, kind="stable"):
        free = inside[i] & ~taken
        if free.any():
            j = int(np.argmin(np.where(free, dist[i], np.inf)))
            taken[j] = True
            match[i] = j
    return match


def bearing_error_deg(camera, det_xyxy: np.ndarray, gt_xyxy: np.ndarray) -> np.ndarray:
    """Angle in degrees between the rays through the centres of paired boxes (row i with row i).

    ``camera``: a payload.geometry.CameraModel for the frame size the boxes are in.
    """
    a = np.asarray(det_xyxy, np.float64).reshape(-1, 4)
    b = np.asarray(gt_xyxy, np.float64).reshape(-1, 4)
    out = np.zeros(len(a), np.float64)
    for i in range(len(a)):
        ray_a = camera.pixel_to_ray_cam((a[i, 0] + a[i, 2]) / 2.0, (a[i, 1] + a[i, 3]) / 2.0)
        ray_b = camera.pixel_to_ray_cam((b[i, 0] + b[i, 2]) / 2.0, (b[i, 1] + b[i, 3]) / 2.0)
        # atan2(|a x b|, a . b): accurate for the small angles that matter here, unlike acos
        out[i] = math.degrees(math.atan2(float(np.linalg.norm(np.cross(ray_a, ray_b))), float(np.dot(ray_a, ray_b))))
    return out


def ap_11point(ranked_tp: np.ndarray, gt: int) -> float:
    """11-point interpolated AP of detections already ranked by descending score."""
    if gt <= 0:
        return math.nan
    ranked_tp = np.asarray(ranked_tp, bool)
    if not len(ranked_tp):
        return 0.0
    cum_tp = np.cumsum(ranked_tp)
    precision = cum_tp / np.arange(1, len(ranked_tp) + 1)
    recall = cum_tp / float(gt)
    total = 0.0
    for r in RECALL_POINTS:
        reached = precision[recall >= r]
        total += float(reached.max()) if len(reached) else 0.0
    return total / len(RECALL_POINTS)


def _json_number(value):
    return None if isinstance(value, float) and math.isnan(value) else value


def _ratio(num: int, den: int) -> float:
    return num / den if den > 0 else math.nan


@dataclass(frozen=True)
class ClipScore:
    """Scores of one clip (or of pooled clips). Ratios are NaN where undefined."""

    name: str
    frames: int
    gt: int
    tp: int
    fp: int
    fn: int
    precision: float
    recall: float
    f1: float
    ap: float
    frames_with_detections: float  # fraction of frames with at least one detection (false alarms on negatives)
    # Every detection's score and TP flag, kept so that pooling ranks all detections together.
    det_score: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32), repr=False, compare=False)
    det_tp: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False, compare=False)
    # The same detections matched by centre-in-box (None where not scored that way), and the
    # bearing error in degrees of each centre-in-box true positive (empty without a camera).
    centre: Optional["ClipScore"] = field(default=None, repr=False, compare=False)
    bearing_err_deg: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64), repr=False, compare=False)

    @classmethod
    def from_ranked(cls, name: str, frames: int, gt: int, det_score: np.ndarray, det_tp: np.ndarray,
                    frames_detected: int, centre_tp: Optional[np.ndarray] = None,
                    bearing_err_deg: Optional[np.ndarray] = None) -> "ClipScore":
        centre = None
        if centre_tp is not None:
            centre = cls.from_ranked(name, frames, gt, det_score, centre_tp, frames_detected)
        bearing = np.zeros(0, np.float64) if bearing_err_deg is None else np.asarray(bearing_err_deg, np.float64)
        order = np.argsort(-np.asarray(det_score, np.float32), kind="stable")
        det_score = np.asarray(det_score, np.float32)[order]
        det_tp = np.asarray(det_tp, bool)[order]
        tp = int(det_tp.sum())
        fp = int(len(det_tp) - tp)
        precision = _ratio(tp, tp + fp)
        recall = _ratio(tp, gt)
        if math.isnan(precision) or math.isnan(recall):
            f1 = math.nan
        else:
            f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
        return cls(
            name=name, frames=int(frames), gt=int(gt), tp=tp, fp=fp, fn=int(gt) - tp,
            precision=precision, recall=recall, f1=f1, ap=ap_11point(det_tp, gt),
            frames_with_detections=_ratio(frames_detected, frames),
            det_score=det_score, det_tp=det_tp, centre=centre, bearing_err_deg=bearing,
        )

    @property
    def frames_detected(self) -> int:
        return 0 if self.frames == 0 else int(round(self.frames_with_detections * self.frames))

    def bearing_percentile(self, q: float) -> float:
        """The ``q``-th percentile of the bearing errors in degrees; NaN when there are none."""
        return float(np.percentile(self.bearing_err_deg, q)) if len(self.bearing_err_deg) else math.nan

    @property
    def bearing_median_deg(self) -> float:
        return self.bearing_percentile(50)

    @property
    def bearing_p95_deg(self) -> float:
        return self.bearing_percentile(95)

    def as_dict(self, curve: bool = True) -> Dict[str, object]:
        """Plain JSON-ready fields; NaN becomes None. ``centre``: the centre-in-box counts and
        ratios; ``bearing_error_deg``: n, median and p95 of the centre-in-box true positives."""
        out: Dict[str, object] = {}
        for key in ("name", "frames", "gt", "tp", "fp", "fn", "precision", "recall", "f1", "ap",
                    "frames_with_detections"):
            out[key] = _json_number(getattr(self, key))
        if curve:
            out["pr_curve"] = self.pr_curve()
        if self.centre is not None:
            out["centre"] = {key: _json_number(getattr(self.centre, key))
                             for key in ("tp", "fp", "fn", "precision", "recall", "f1", "ap")}
            out["bearing_error_deg"] = {"n": int(len(self.bearing_err_deg)),
                                        "median": _json_number(self.bearing_median_deg),
                                        "p95": _json_number(self.bearing_p95_deg)}
        return out

    def pr_curve(self, points: int = 50, score_step: float = 0.02) -> List[List[float]]:
        """[score threshold, precision, recall], highest score first: what the detections would score
        if only those at or above the threshold were kept. Thresholds: ``points`` spread over the
        ranking plus one every ``score_step`` of score (so each round threshold is on the curve)."""
        if not len(self.det_score) or self.gt <= 0:
            return []
        cum_tp = np.cumsum(self.det_tp)
        by_rank = np.linspace(0, len(cum_tp) - 1, min(points, len(cum_tp))).round().astype(int)
        grid = np.arange(0.0, 1.0 + 1e-9, score_step)
        by_score = np.searchsorted(-self.det_score, -grid, side="right") - 1
        ranks = np.unique(np.concatenate([by_rank, by_score[by_score >= 0]]))
        # a threshold keeps every detection with an equal score: move each rank to its last tie
        last_of_score = np.searchsorted(-self.det_score, -self.det_score[ranks], side="right") - 1
        return [[float(self.det_score[i]), float(cum_tp[i] / (i + 1)), float(cum_tp[i] / self.gt)]
                for i in np.unique(last_of_score)]


def score_clip(name: str, dets: Mapping[int, Detections], labels: Mapping[int, np.ndarray],
               frames: Optional[int] = None, iou_match: float = IOU_MATCH, camera=None) -> ClipScore:
    """Score one clip: ``dets`` and ``labels`` map 0-based frame index -> boxes.

    ``frames`` is the clip length (frames at or past it are ignored on both sides, e.g. after
    ``--limit``); by default the highest frame index either side knows + 1. Centre-in-box
    matching is scored too (``.centre``); ``camera`` (a payload.geometry.CameraModel for the
    clip's frame size) adds the bearing errors of its true positives.
    """
    known = set(dets) | set(labels)
    if frames is None:
        frames = max(known) + 1 if known else 0
    known = {index for index in known if index < frames}
    scores, flags, centre_flags, bearings = [], [], [], []
    gt = 0
    frames_detected = 0
    empty = np.zeros((0, 4), np.float32)
    for index in sorted(known):
        gt_xyxy = labels.get(index, empty)
        gt += len(gt_xyxy)
        frame_dets = dets.get(index)
        if frame_dets is None or not len(frame_dets):
            continue
        frames_detected += 1
        flags.append(match_frame(frame_dets, gt_xyxy, iou_match))
        centre = centre_match_frame(frame_dets, gt_xyxy)
        centre_flags.append(centre >= 0)
        if camera is not None and (centre >= 0).any():
            hit = centre >= 0
            bearings.append(bearing_error_deg(camera, np.asarray(frame_dets.xyxy)[hit], np.asarray(gt_xyxy)[centre[hit]]))
        scores.append(frame_dets.score)
    det_score = np.concatenate(scores) if scores else np.zeros(0, np.float32)
    det_tp = np.concatenate(flags) if flags else np.zeros(0, bool)
    centre_tp = np.concatenate(centre_flags) if centre_flags else np.zeros(0, bool)
    bearing = np.concatenate(bearings) if bearings else np.zeros(0, np.float64)
    return ClipScore.from_ranked(name, frames, gt, det_score, det_tp, frames_detected, centre_tp, bearing)


def pool(scores: Sequence[ClipScore], name: str = "POOLED") -> ClipScore:
    """One score over several clips: counts summed and every detection ranked together (the
    centre-in-box score too where every clip has one; the bearing errors of all clips)."""
    with_centre = bool(scores) and all(s.centre is not None for s in scores)
    return ClipScore.from_ranked(
        name,
        frames=sum(s.frames for s in scores),
        gt=sum(s.gt for s in scores),
        det_score=np.concatenate([s.det_score for s in scores]) if scores else np.zeros(0, np.float32),
        det_tp=np.concatenate([s.det_tp for s in scores]) if scores else np.zeros(0, bool),
        frames_detected=sum(s.frames_detected for s in scores),
        centre_tp=np.concatenate([s.centre.det_tp for s in scores]) if with_centre else None,  # type: ignore[union-attr]
        bearing_err_deg=np.concatenate([s.bearing_err_deg for s in scores]) if scores else None,
    )
