"""GLAD: the global-local detector around the four modules (paper Fig. 2).

Per frame one detector runs, chosen by the switcher:
- global: appearance (GAD) on the down-scaled full frame; only if it finds nothing, motion
  (GMD) on the full frame, its candidates checked by the 32x32 classifier; if that finds
  nothing either on a frame GAD down-scales strongly (1080p), GAD's look at native
  resolution: the local detector on a few tiles of the frame in turn (payload.detect.scan);
- local: appearance (LAD) inside the search region at native resolution; only if it finds
  nothing, motion (LMD) inside the region, checked by the classifier.
A hit moves/keeps the switcher on local and updates the search region; a local miss grows
the region around its prediction until the switcher gives up. Local hits farther than
max_jump_px from the prediction are ignored, unless one would have started a target globally
(score >= T0, confirmed by the classifier) and beats the hits near the prediction: then the
target starts again there.
"""

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Tuple

import cv2
import numpy as np

from payload.config import DetectorConfig, section_changes
from payload.detect.classifier import LockCheck
from payload.detect.ego_motion import EgoMotion, GreyLevels
from payload.detect.factory import DetectorModels, build_detectors
from payload.detect.motion import MotionDetector
from payload.detect.region import SearchRegion
from payload.detect.scan import NativeScan
from payload.detect.switcher import GLOBAL, LOCAL, Switcher
from payload.detect.verify import LockVerifier
from payload.types import GAD, GMD, LAD, LMD, Detections, Frame, Target

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class GladResult:
    """What GLAD decided for one frame."""

    frame_index: int
    t_capture_ns: int
    mode: str  # the detector that ran: 'global' or 'local'
    detections: Detections  # the chosen target as 0 or 1 rows (what is reported and scored)
    candidates: Detections  # every box the modules that ran produced (debugging)
    target: Optional[Target]  # measured or predicted (coasting) target; None when searching globally
    region_xyxy: Optional[np.ndarray]  # the search region searched this frame (local mode)
    timings_ms: Dict[str, float] = field(default_factory=dict)  # per module, for the benchmark
    # a lock is followed but not reported: LockCheck or the verifier is not yet convinced of it
    following: bool = False
    lock_p: float = float("nan")  # the verifier's drone probability for the lock (nan: not judged)
    # per module, the work it left out this frame to stay within its time budget (e.g. GMD:
    # candidates over motion.max_candidates not judged); empty on a frame done in full
    degraded: Dict[str, int] = field(default_factory=dict)

    @property
    def state(self) -> str:
        """The one vocabulary of the target state: 'searching', 'following' (a lock not reported
        yet), 'detected' (a measured target) or 'coasting' (the search region's prediction)."""
        if self.target is None:
            return "following" if self.following else "searching"
        return "detected" if self.target.measured else "coasting"


class Glad:
    """Runs the GLAD pipeline frame by frame. ``models``: payload.detect.factory.build_detectors(cfg),
    made here when not given."""

    def __init__(self, cfg: DetectorConfig, models: Optional[DetectorModels] = None) -> None:
        if models is None:
            models = build_detectors(cfg)
        self.cfg = cfg
        self.models = models
        self.ego_motion = EgoMotion(cfg.global_.motion)
        self.gmd = MotionDetector(cfg.global_.motion, GMD)
        self.lmd = MotionDetector(cfg.local.motion, LMD)
        self.region = SearchRegion(cfg.search_region)
        self.switcher = Switcher(cfg.switcher, local_available=self._local_available(cfg))
        self.lock = LockCheck(*self._lock_settings(cfg))
        v = cfg.verifier
        self.verifier = LockVerifier(models.verifier, v.min_frames, v.threshold, v.release_threshold, v.enabled)
        self.scan = NativeScan()
        # what this frame measured of the lock, for the verifier's row (reset each frame)
        self._observed: Optional[Detections] = None
        self._drone_p: Optional[float] = None
        self._homography: Optional[np.ndarray] = None
        self._degraded: Dict[str, int] = {}
        self.last_lock_row: Optional[np.ndarray] = None  # the verifier's row of this frame's lock
        self.last_lock_box: Optional[np.ndarray] = None  # the box that frame reports if verified
        self._prev: Optional[GreyLevels] = None
        self._prev_t_ns: Optional[int] = None
        self.designated = False  # the lock is an operator's (designate): no retarget may take it

    @staticmethod
    def _local_available(cfg: DetectorConfig) -> bool:
        return cfg.local.appearance.enabled or cfg.local.motion.enabled

    def _lock_settings(self, cfg: DetectorConfig) -> Tuple[int, float, int, float]:
        """LockCheck's (hits, threshold, confirm_hits, confirm_threshold). It needs the classifier,
        and a local stage to follow a lock with (global-only, every hit starts a new lock): off
        without them."""
        c = cfg.classifier
        if not (c.enabled and self.models.classifier is not None and self._local_available(cfg)):
            return 0, c.lock_threshold, 0, c.confirm_threshold
        return c.lock_hits, c.lock_threshold, c.confirm_hits, c.confirm_threshold

    def update_config(self, cfg: DetectorConfig) -> List[str]:
        """Hot reload: thresholds and switches; models stay as loaded. Returns the keys applied:
        switching on a stage whose model was not loaded at start is not (it needs a restart)."""
        data = cfg.model_dump(by_alias=True)  # a stage without a loaded model stays off, as it runs
        if self.models.global_appearance is None:
            data["global"]["appearance"]["enabled"] = False
        if self.models.local_appearance is None:
            data["local"]["appearance"]["enabled"] = False
        if self.models.classifier is None:
            data["classifier"]["enabled"] = False
        if self.models.verifier is None:
            data["verifier"]["enabled"] = False
        cfg = DetectorConfig.model_validate(data)
        applied = section_changes(self.cfg, cfg, "detector")
        self.cfg = cfg
        self.ego_motion.update_config(cfg.global_.motion)
        self.gmd.update_config(cfg.global_.motion)
        self.lmd.update_config(cfg.local.motion)
        self.region.update_config(cfg.search_region)
        self.switcher.update_config(cfg.switcher)
        self.switcher.local_available = self._local_available(cfg)
        self.lock.update_config(*self._lock_settings(cfg))
        v = cfg.verifier
        self.verifier.update_config(v.min_frames, v.threshold, v.release_threshold, v.enabled)
        if self.models.global_appearance is not None:
            self.models.global_appearance.update_config(cfg.global_.appearance)
        if self.models.local_appearance is not None:
            self.models.local_appearance.update_config(cfg.local.appearance)
        if self.models.classifier is not None:
            self.models.classifier.update_config(cfg.classifier)
        return applied

    # --- operator designation (MAVLink camera track point / rectangle) --------------------------

    def designate(self, center_xy: Tuple[float, float], size_wh: Tuple[float, float]) -> None:
        """Local mode with the search region on an operator's point: the next frames' local
        detectors look there (the lock check judges what they find afresh) and, while this lock
        holds, no stronger hit elsewhere takes it (no retarget). Lost after max_local_misses as
        any lock; a target the global search then finds is an automatic one again."""
        self.region.start((float(center_xy[0]), float(center_xy[1])), (float(size_wh[0]), float(size_wh[1])), 0.0)
        self.switcher.reset()
        self.switcher.after(hit=True)  # local from the next frame
        self.lock.reset()
        self.verifier.reset()
        self.designated = True

    def release(self) -> None:
        """Back to automatic global search (operator's stop, or a designation not confirmed)."""
        self.region.reset()
        self.switcher.reset()
        self.lock.reset()
        self.verifier.reset()
        self.designated = False

    def reset(self) -> None:
        self.designated = False
        self.switcher.reset()
        self.region.reset()
        self.lock.reset()
        self.verifier.reset()
        self.scan.reset()
        self._prev = self._prev_t_ns = None

    # --- the per-frame step -------------------------------------------------------------

    def process(self, frame: Frame) -> GladResult:
        timings: Dict[str, float] = {}
        t0 = time.perf_counter()
        grey = GreyLevels.of(cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY))
        timings["grey"] = _ms(t0)
        self._observed, self._drone_p, self._homography = None, None, None
        self._degraded = {}
        mode = self.switcher.mode if self.region.active else GLOBAL
        if mode == LOCAL:
            result = self._local(frame, grey, timings)
        else:
            result = self._global(frame, grey, timings)
        self._prev = grey
        self._prev_t_ns = frame.t_capture_ns
        self._verify(frame, grey, result, timings)
        if result.target is not None:
            result = replace(result, lock_p=self.verifier.probability)
        if self._degraded:
            result = replace(result, degraded=self._degraded)
        verified = self.verifier.verified or self.designated  # the operator picked this one: it needs no drone verdict
        if not (self.lock.confirmed and verified) and (len(result.detections) or result.target is not None):
            # followed, not reported: the classifier has not confirmed this lock (LockCheck), or
            # its recent frames have not convinced the verifier (LockVerifier)
            result = replace(result, detections=Detections.empty(), target=None, following=True)
        return result

    def _verify(self, frame: Frame, grey: GreyLevels, result: GladResult, timings: Dict[str, float]) -> None:
        """Add this frame of the lock to the verifier (a frame without a lock ends it)."""
        self.last_lock_row = self.last_lock_box = None
        target = result.target
        if target is None:
            self.verifier.reset()
            return
        t = time.perf_counter()
        observed = self._observed if target.measured and self._observed is not None and len(self._observed) else None
        if observed is not None and self._drone_p is None and self.verifier.judging and self.models.classifier is not None:
            # the lock check did not ask the classifier this frame (it is off): the verifier's row needs it
            self._drone_p = float(self.models.classifier.probabilities(frame.image, observed)[0])
        row = self.verifier.features.row(
            grey.full, target.xyxy, observed.xyxy[0] if observed is not None else None,
            float(observed.score[0]) if observed is not None else 0.0,
            str(observed.module[0]) if observed is not None else "", self._drone_p, self._homography)
        self.verifier.add(row)
        self.last_lock_row = row
        self.last_lock_box = result.detections.xyxy[0].copy() if len(result.detections) else None
        timings["verifier"] = _ms(t)

    def _global(self, frame: Frame, grey: GreyLevels, timings: Dict[str, float]) -> GladResult:
        found = Detections.empty()
        candidates = []
        gad = self.models.global_appearance
        if gad is not None and self.cfg.global_.appearance.enabled:
            found = self._appearance(gad, frame.image, frame.image, (0, 0), timings, candidates)
        prev = self._prev
        if not len(found) and self.cfg.global_.motion.enabled and prev is not None and prev.full.shape == grey.full.shape:
            t = time.perf_counter()
            camera = self.ego_motion.estimate(prev, grey, fine=True)
            found = self._motion(self.gmd, frame.image, prev.full, grey.full, camera, (0, 0), t, timings, candidates)
        if not len(found) and gad is not None and self.cfg.global_.appearance.enabled:
            scanned = self._scan(frame, timings)
            candidates.append(scanned)
            # Four native-resolution tiles a frame meet many more birds than GAD's down-scaled
            # look: where GAD hits are checked, a scan hit must convince the classifier as much
            # as a lock must to be reported (a synthetic gull at 0.51 took the demo's lock).
            found = self._classify(frame.image, scanned, timings, threshold=max(
                self.cfg.classifier.threshold, self.cfg.classifier.confirm_threshold))
        best = found.sorted_by_score()[:1] if len(found) else found
        t = time.perf_counter()
        target = None
        if len(best):
            target = self._acquire(frame, best, timings)
        self.switcher.after(hit=bool(len(best)))
        timings["switcher"] = _ms(t)
        return GladResult(frame.index, frame.t_capture_ns, GLOBAL, best, Detections.concat(candidates), target, None, timings)

    def _local(self, frame: Frame, grey: GreyLevels, timings: Dict[str, float]) -> GladResult:
        t = time.perf_counter()
        camera = self.ego_motion.estimate(self._prev, grey, fine=False)
        self._homography = camera.matrix if self._prev is not None else None
        dt_s = (frame.t_capture_ns - self._prev_t_ns) / 1e9 if self._prev_t_ns is not None else 1.0 / 30
        predicted = self.region.predict(camera, dt_s)
        region = self.region.region_xyxy(frame.size_wh)
        timings["region"] = _ms(t)
        x1, y1, x2, y2 = (int(v) for v in region)
        found = Detections.empty()
        candidates = []
        lad = self.models.local_appearance
        if lad is not None and self.cfg.local.appearance.enabled:
            found = self._appearance(lad, frame.image, frame.image[y1:y2, x1:x2], (x1, y1), timings, candidates)
        prev = self._prev
        if not len(found) and self.cfg.local.motion.enabled and prev is not None and prev.full.shape == grey.full.shape:
            # the region's camera motion, not one of its own: one estimate a frame
            found = self._motion(self.lmd, frame.image, prev.full[y1:y2, x1:x2], grey.full[y1:y2, x1:x2],
                                 camera.for_crop((x1, y1)), (x1, y1), time.perf_counter(), timings, candidates)
        t = time.perf_counter()
        near, near_distance, far = self._gate(found, predicted)
        best = self._pick(near, near_distance)
        retarget = self._retarget(frame.image, far, best, timings)
        if len(retarget):
            # a confident, confirmed hit away from the prediction, stronger than anything near it:
            # the lock was on clutter or had lost the target; start again there
            target = self._acquire(frame, retarget, timings)
            self.switcher.after(hit=True)
            timings["switcher"] = _ms(t)
            return GladResult(frame.index, frame.t_capture_ns, LOCAL, retarget, Detections.concat(candidates),
                              target, region, timings)
        if len(best) and not self._lock_holds(frame.image, best, timings):
            # the classifier does not believe in what is being followed: search globally again
            self.region.reset()
            self.switcher.reset()
            timings["switcher"] = _ms(t)
            return GladResult(frame.index, frame.t_capture_ns, LOCAL, Detections.empty(), Detections.concat(candidates),
                              None, region, timings)
        if len(best):
            self._observed = best
            self.region.hit(tuple(best.centers[0]), tuple(best.xywh[0, 2:]), float(best.score[0]))
            best = best.resized(self.region.size_wh).rescored(self.region.score)
            target = self._target(frame, best, region=region)
        else:
            self.region.miss()
            target = Target(
                frame.index, frame.t_capture_ns, self.region.predicted_box(), 0.0, "", measured=False, region_xyxy=region
            )
        mode_next = self.switcher.after(hit=bool(len(best)))
        if mode_next == GLOBAL and not len(best):
            self.region.reset()
            target = None
        timings["switcher"] = _ms(t)
        return GladResult(frame.index, frame.t_capture_ns, LOCAL, best, Detections.concat(candidates), target, region, timings)

    # --- helpers ----------------------------------------------------------------------------

    def _scan(self, frame: Frame, timings: Dict[str, float]) -> Detections:
        """Native-resolution hits on this frame's scan tiles (payload.detect.scan), as GAD hits.
        Off without a local appearance detector, and on frames GAD's input hardly down-scales."""
        lad, gad, scan = self.models.local_appearance, self.models.global_appearance, self.cfg.global_.scan
        if lad is None or not self.cfg.local.appearance.enabled or not scan.tiles_per_frame:
            return Detections.empty()
        w, h = frame.size_wh
        if min(gad.input_wh[0] / float(w), gad.input_wh[1] / float(h)) > scan.max_input_scale:
            return Detections.empty()
        t = time.perf_counter()
        parts = [lad.detect(frame.image[y1:y2, x1:x2], offset_xy=(float(x1), float(y1)))
                 for x1, y1, x2, y2 in self.scan.next_tiles((w, h), lad.input_wh, scan.tiles_per_frame)]
        found = Detections.concat(parts)
        found = found[found.score >= self.cfg.global_.appearance.confidence]  # T0: these are GAD hits
        timings["scan"] = _ms(t)
        return Detections(found.xyxy, found.score, np.full(len(found), GAD, "<U3"))

    def _acquire(self, frame: Frame, best: Detections, timings: Dict[str, float]) -> Target:
        """A new target: the search region starts around it and its lock is judged afresh."""
        self.designated = False
        self.region.start(tuple(best.centers[0]), tuple(best.xywh[0, 2:]), float(best.score[0]))
        self.lock.reset()
        self.verifier.reset()
        self._observed = best
        self._lock_holds(frame.image, best, timings)
        return self._target(frame, best, region=None)

    def _retarget(self, image: np.ndarray, far: Detections, near_best: Detections,
                  timings: Dict[str, float]) -> Detections:
        """The strongest local appearance hit beyond the gate (``far``) if the global detector would
        have taken it (score > T0), the classifier confirms it, and it beats the chosen near hit."""
        if self.designated:
            return far[:0]  # the operator chose the target: it is not traded for a stronger one
        floor = max(self.cfg.global_.appearance.confidence, float(near_best.score[0]) if len(near_best) else 0.0)
        far = far[(far.module == LAD) & (far.score > floor)]
        if not len(far):
            return far
        return self._confirm(image, far.sorted_by_score()[:1], rescore=False, timings=timings)

    def _appearance(self, detector, image: np.ndarray, part: np.ndarray, offset_xy, timings: Dict[str, float],
                    candidates: List[Detections]) -> Detections:
        """GAD or LAD on ``part`` of the frame (at ``offset_xy``): its hits join ``candidates``,
        those the classifier confirms are returned."""
        t = time.perf_counter()
        found = detector.detect(part, offset_xy=offset_xy)
        timings[detector.module] = _ms(t)
        candidates.append(found)
        return self._classify(image, found, timings)

    def _motion(self, detector: MotionDetector, image: np.ndarray, prev: np.ndarray, cur: np.ndarray, camera,
                offset_xy, t_start: float, timings: Dict[str, float], candidates: List[Detections]) -> Detections:
        """GMD or LMD on the grey ``prev``/``cur`` (a crop at ``offset_xy``) under ``camera``'s motion,
        timed from ``t_start``: its hits join ``candidates`` (candidates it left out to keep its time
        budget are counted in the frame's ``degraded``), those the classifier confirms are returned."""
        motion = detector.detect(prev, cur, camera, offset_xy=offset_xy)
        timings[detector.module] = _ms(t_start)
        if motion.left_out:
            self._degraded[detector.module] = motion.left_out
        candidates.append(motion.detections)
        return self._classify(image, motion.detections, timings)

    def _classify(self, image: np.ndarray, dets: Detections, timings: Dict[str, float],
                  threshold: Optional[float] = None) -> Detections:
        """The hits the classifier confirms (at ``threshold``, default its own), for the modules it
        checks (cfg.classifier.modules).

        Motion hits take the classifier's probability as their score (the motion detector has no
        score of its own); appearance hits keep the detector's confidence.
        """
        if not len(dets) or dets.module[0] not in self.cfg.classifier.modules:
            return dets
        return self._confirm(image, dets, rescore=dets.module[0] in (GMD, LMD), timings=timings, threshold=threshold)

    def _confirm(self, image: np.ndarray, dets: Detections, rescore: bool, timings: Dict[str, float],
                 threshold: Optional[float] = None) -> Detections:
        """The hits the classifier confirms (at ``threshold``, default its own); all of them when it
        is off or absent."""
        classifier = self.models.classifier
        if not len(dets) or classifier is None or not self.cfg.classifier.enabled:
            return dets
        t = time.perf_counter()
        kept = classifier.filter(image, dets, rescore=rescore, threshold=threshold)
        timings["classifier"] = timings.get("classifier", 0.0) + _ms(t)
        return kept

    def _lock_holds(self, image: np.ndarray, best: Detections, timings: Dict[str, float]) -> bool:
        """Feed the chosen hit's drone probability to the lock check (cfg.classifier.lock_hits,
        confirm_hits)."""
        if not self.lock.active:
            return True
        t = time.perf_counter()
        probability = float(self.models.classifier.probabilities(image, best)[0])
        self._drone_p = probability
        timings["classifier"] = timings.get("classifier", 0.0) + _ms(t)
        return self.lock.add(probability)

    def _gate(self, found: Detections, predicted_xy) -> Tuple[Detections, np.ndarray, Detections]:
        """Local hits split at max_jump_px from the prediction: (near, their distances, far).
        With the gate off (0) every hit is near."""
        distance = np.hypot(*(found.centers - np.asarray(predicted_xy, np.float32)).T)
        jump = self.cfg.switcher.max_jump_px
        near = distance <= jump if jump > 0 else np.ones(len(found), bool)
        return found[near], distance[near], found[~near]

    def _pick(self, near: Detections, distance: np.ndarray) -> Detections:
        """Local choice among the near hits: by confidence or by distance to the prediction."""
        if not len(near):
            return near
        order = np.argsort(distance) if self.cfg.switcher.pick == "distance" else np.argsort(-near.score, kind="stable")
        return near[order[:1]]

    @staticmethod
    def _target(frame: Frame, best: Detections, region) -> Target:
        """The measured target: the chosen detection."""
        return Target(frame.index, frame.t_capture_ns, best.xyxy[0].copy(), float(best.score[0]),
                      str(best.module[0]), measured=True, region_xyxy=region)


def _ms(t_start: float) -> float:
    return (time.perf_counter() - t_start) * 1000.0
