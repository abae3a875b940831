"""The targets GLAD follows at once (issue 16: more than one drone in view).

A ``Track`` is what the single-target GLAD kept for its one target: the search region (Kalman
prediction, payload.detect.region), the switcher's state (local misses), the classifier's lock
check and the lock verifier, plus a stable integer id and whether the operator designated it.
GLAD (payload.detect.pipeline) keeps up to ``detector.targets.max`` of them; each runs the local
stage in its own region. Of the tracks it reports, one is the primary (``primary_of``): the one
sent to the autopilot on the existing messages. The others are listed (detections CSV, log).
"""

from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from payload.config import DetectorConfig
from payload.detect.classifier import LockCheck
from payload.detect.region import SearchRegion
from payload.detect.switcher import LOCAL, Switcher
from payload.detect.verify import LockVerifier
from payload.types import Detections, Target

CENTRE, LARGEST, OPERATOR = "centre", "largest", "operator"


@dataclass(frozen=True)
class TrackedTarget:
    """One reported target of a frame (``GladResult.targets``)."""

    id: int  # stable while GLAD follows it; a target found anew gets a new one
    target: Target  # measured or coasting (the search region's prediction)
    detections: Detections  # 1 row when measured this frame, 0 while coasting
    primary: bool = False  # the one sent to the autopilot
    designated: bool = False  # the operator's choice
    lock_p: float = float("nan")  # the verifier's drone probability (nan: not judged)


class Track:
    """One followed target's state. ``lock_settings``: LockCheck's (hits, threshold, confirm_hits,
    confirm_threshold) as GLAD decides them; ``verifier_model``: the loaded verifier network or None."""

    def __init__(self, track_id: int, cfg: DetectorConfig, lock_settings: Tuple[int, float, int, float],
                 verifier_model=None, local_available: bool = True) -> None:
        self.id = track_id
        self.region = SearchRegion(cfg.search_region)
        self.switcher = Switcher(cfg.switcher, local_available=local_available)
        self.lock = LockCheck(*lock_settings)
        v = cfg.verifier
        self.verifier = LockVerifier(verifier_model, v.min_frames, v.threshold, v.release_threshold, v.enabled)
        self.designated = False  # an operator's lock: no retarget may take it
        self.reported = False  # whether the last frame reported it
        self.unreported = 0  # frames in a row it was followed without being reported
        self.begin_frame()

    def begin_frame(self) -> None:
        """Forget what the last frame measured of this target (the per-frame fields below)."""
        self.target: Optional[Target] = None  # this frame's target; None: the track ends
        self.detections = Detections.empty()  # what this frame reports of it (0 or 1 row)
        self.region_xyxy: Optional[np.ndarray] = None  # the region searched this frame (local)
        self.observed: Optional[Detections] = None  # the detection a detector found (verifier row)
        self.drone_p: Optional[float] = None  # the classifier's probability for it this frame
        self.last_row: Optional[np.ndarray] = None  # the verifier's row of this frame
        self.last_box: Optional[np.ndarray] = None  # the box this frame reports if verified

    def update_config(self, cfg: DetectorConfig, lock_settings: Tuple[int, float, int, float],
                      local_available: bool) -> None:
        self.region.update_config(cfg.search_region)
        self.switcher.update_config(cfg.switcher)
        self.switcher.local_available = local_available
        self.lock.update_config(*lock_settings)
        v = cfg.verifier
        self.verifier.update_config(v.min_frames, v.threshold, v.release_threshold, v.enabled)

    @property
    def local(self) -> bool:
        """Whether the local stage follows it this frame (else the global stage runs for it)."""
        return self.region.active and self.switcher.mode == LOCAL

    def start(self, best: Detections) -> None:
        """Start afresh on ``best``'s first box: a new search region, its lock judged anew."""
        self.designated = False
        self.region.start(tuple(best.centers[0]), tuple(best.xywh[0, 2:]), float(best.score[0]))
        self.lock.reset()
        self.verifier.reset()
        self.unreported = 0
        self.observed = best

    def designate(self, center_xy: Tuple[float, float], size_wh: Tuple[float, float]) -> None:
        """The operator's point: local from the next frame, its lock judged afresh."""
        self.region.start((float(center_xy[0]), float(center_xy[1])), (float(size_wh[0]), float(size_wh[1])), 0.0)
        self.switcher.reset()
        self.switcher.after(hit=True)
        self.lock.reset()
        self.verifier.reset()
        self.designated = True

    def box(self) -> Optional[np.ndarray]:
        """Where it is: this frame's target box, else the search region's last box."""
        if self.target is not None:
            return self.target.xyxy
        return self.region.predicted_box() if self.region.active else None

    def stale(self, frames: int) -> bool:
        """Whether it may give its place to a new hit (GLAD's global stage), not being the operator's:
        the classifier has neither confirmed nor dropped it in ``frames`` frames of being followed,
        or the verifier refuses it (``LockVerifier.refused``: a bird or clutter the classifier took,
        which else held the only place for the rest of the clip). A confirmed lock the verifier
        merely holds back is not stale: on val those were the drones themselves, and giving their
        place cost synthetic F (docs/results.md)."""
        if self.designated or self.unreported < frames:
            return False
        return not self.lock.confirmed or self.verifier.refused

    @property
    def verified(self) -> bool:
        """Reportable: the classifier confirmed the lock and the verifier believes it (an operator's
        lock needs no drone verdict)."""
        return self.lock.confirmed and (self.verifier.verified or self.designated)


def overlap(a: Optional[np.ndarray], b: Optional[np.ndarray]) -> bool:
    """Whether two xyxy boxes share any area."""
    if a is None or b is None:
        return False
    return min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1])


def is_far(box: np.ndarray, tracks: Sequence[Track], gate_px: float) -> bool:
    """Whether a hit belongs to none of ``tracks``: it overlaps none of their boxes and lies farther
    than ``gate_px`` (the local stage's jump gate: nearer, a track's own local stage takes it) from
    their centres."""
    cx, cy = (box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0
    for track in tracks:
        other = track.box()
        if other is None:
            continue
        if overlap(box, other):
            return False
        ox, oy = (other[0] + other[2]) / 2.0, (other[1] + other[3]) / 2.0
        if np.hypot(cx - ox, cy - oy) <= gate_px:
            return False
    return True


def merge_overlapping(tracks: List[Track]) -> List[Track]:
    """Tracks (oldest first) with each one whose box comes to overlap an older one's removed: two
    tracks on one drone. The older keeps its id and state; the operator's mark moves to it."""
    kept: List[Track] = []
    for track in tracks:
        older = next((k for k in kept if overlap(k.box(), track.box())), None)
        if older is None:
            kept.append(track)
        elif track.designated:
            older.designated = True
    return kept


# A primary is kept until another target is clearly better: two drones about as near the centre (or
# as large) would otherwise swap the primary from frame to frame and the autopilot would steer to
# and fro between them.
SWITCH_CENTRE_FRAC = 0.05  # nearer the centre by 5 % of the image diagonal
SWITCH_AREA_RATIO = 1.5  # a box 1.5x the area


def primary_of(tracks: Sequence[Track], rule: str, image_wh: Tuple[int, int],
               previous: Optional[int] = None) -> Optional[Track]:
    """The reported track sent to the autopilot (``tracks`` reported, oldest first; ties keep the
    older): ``centre`` nearest the image centre, ``largest`` the largest box, ``operator`` the
    designated one (nearest the centre while the operator has chosen none). The track with id
    ``previous`` (last frame's primary) stays primary unless another is clearly nearer or larger."""
    if not tracks:
        return None
    if rule == OPERATOR:
        chosen = [t for t in tracks if t.designated]
        if chosen:
            return chosen[0]
        rule = CENTRE
    kept = next((t for t in tracks if t.id == previous), None)
    if rule == LARGEST:
        areas = [float((t.target.xyxy[2] - t.target.xyxy[0]) * (t.target.xyxy[3] - t.target.xyxy[1])) for t in tracks]
        best = int(np.argmax(areas))
        if kept is not None and areas[best] < SWITCH_AREA_RATIO * areas[tracks.index(kept)]:
            return kept
        return tracks[best]
    cx, cy = image_wh[0] / 2.0, image_wh[1] / 2.0
    distances = [float(np.hypot(t.target.center[0] - cx, t.target.center[1] - cy)) for t in tracks]
    best = int(np.argmin(distances))
    if kept is not None and distances[best] > distances[tracks.index(kept)] - SWITCH_CENTRE_FRAC * float(np.hypot(*image_wh)):
        return kept
    return tracks[best]
