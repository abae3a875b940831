"""GLAD: the global-local detector around the four modules (paper Fig. 2).

Per frame, chosen by each target's switcher:
- global: appearance (GAD) on the down-scaled full frame; only if it finds nothing, motion
  (GMD) on the full frame, its candidates checked by the 32x32 classifier. On a frame GAD
  down-scales strongly (1080p) there are two more looks at native resolution: the local
  detector on a few tiles of the frame in turn (payload.detect.scan), and isolated 2-8 px spots
  over the whole frame, a band of rows a turn (payload.detect.points); there the four looks
  take turns, one a global frame, so that a searching frame costs what one look costs (issue
  19's time budget);
- local: appearance (LAD) inside the target's search region at native resolution; only if it
  finds nothing, motion (LMD) inside the region, checked by the classifier; on frames the scan
  searches, then isolated spots in the region, checked by the classifier (for a target no larger
  than a spot also when every hit lies farther than a spot from the prediction: a bird beside it).
A hit moves/keeps the switcher on local and updates the search region; a local miss grows
the region around its prediction until the switcher gives up. Local hits farther than
max_jump_px from the prediction are ignored, unless one would have started a target globally
(score >= T0, confirmed by the classifier) and beats the hits near the prediction: then the
target starts again there.

More than one drone in view (detector.targets, payload.detect.tracks): GLAD follows up to
``max`` targets, each a ``Track`` with its own region, switcher, lock check and verifier, each
searched by the local stage in its own region. The global stage runs on every frame no target is
followed locally; with ``max`` > 1 and room for another target also while targets are followed:
on every frame while none is reported, else every ``search_every`` frames. There (and beyond a
track's jump gate in the local stage) a strong (score >= T0), confirmed hit that belongs to no
track starts a new one; while there is no room a local one retargets its track as above. Tracks
that come to overlap are merged (the older id stays). Of the reported targets the ``primary``
rule picks the one sent to the autopilot. With ``max`` 1 this is the single-target GLAD, but for
one thing: a lock the classifier has neither confirmed nor dropped over LockCheck's window
(``lock_hits`` frames, at least ``search_every``; a speck) does not blind the search. While every
place is held and such a stale lock is among them, the global stage runs every ``search_every``
frames (every frame once the verifier has refused it: nothing is reported meanwhile), and a strong,
confirmed hit that belongs to no track takes the stalest one's place.
"""

import logging
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import cv2
import numpy as np

from payload.config import DetectorConfig, section_changes
from payload.detect.ego_motion import CameraMotion, EgoMotion, GreyLevels
from payload.detect.factory import DetectorModels, build_detectors
from payload.detect.motion import MotionDetector
from payload.detect.points import PointDetector
from payload.detect.scan import NativeScan
from payload.detect.switcher import GLOBAL, LOCAL
from payload.detect.tracks import Track, TrackedTarget, is_far, merge_overlapping, overlap, primary_of
from payload.types import GAD, GMD, LAD, LMD, Detections, Frame, Target

SCAN = "scan"  # the global stage's native-resolution looks: the local network on tiles (payload.detect.scan)
GREY = "grey"  # Frame.prepared: the frame's GreyLevels, made by Glad.prepare
CAMERA = "camera"  # ... and the camera motion from the frame prepared before it
POINTS = "points"  # ... and isolated spots over the whole frame (payload.detect.points), a band a turn
# at most this many pixels a band (a 1080p frame in three, 1280x720 in two): ~6 ms on one core, the
# three colour channels' spots costing twice the grey level's
SPOT_BAND_PX = 700_000
#: The spots' isolation bar in a search region (the whole frame's is 1.5: PointDetector): where the
#: prediction says a lock's target is, a spot 1.2x the largest response around it is enough for the
#: classifier to judge. A 4 px white drone on a noisy sky stands 1.1-1.5x above the noise's extremes
#: in its ring, and the lock coasted through those frames (docs/results.md, 2026-12-06).
LOCAL_SPOT_ISOLATION = 1.2

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class GladResult:
    """What GLAD decided for one frame. ``detections``, ``target``, ``region_xyxy``, ``lock_p`` and
    ``following`` are the primary target's (the one sent to the autopilot); ``targets`` lists every
    reported one."""

    frame_index: int
    t_capture_ns: int
    mode: str  # the detector that ran: 'global', or 'local' when any target was searched locally
    detections: Detections  # the primary target as 0 or 1 rows (what is reported and scored)
    candidates: Detections  # every box the modules that ran produced (debugging)
    target: Optional[Target]  # measured or predicted (coasting) primary target; None when none is reported
    region_xyxy: Optional[np.ndarray]  # the search region searched this frame (local mode)
    timings_ms: Dict[str, float] = field(default_factory=dict)  # per module, for the benchmark
    # a lock is followed but not reported: LockCheck or the verifier is not yet convinced of it
    following: bool = False
    lock_p: float = float("nan")  # the verifier's drone probability for the lock (nan: not judged)
    # per module, the work it left out this frame to stay within its time budget (e.g. GMD:
    # candidates over motion.max_candidates not judged); empty on a frame done in full
    degraded: Dict[str, int] = field(default_factory=dict)
    targets: Tuple[TrackedTarget, ...] = ()  # every reported target, the primary flagged

    @property
    def state(self) -> str:
        """The one vocabulary of the target state: 'searching', 'following' (a lock not reported
        yet), 'detected' (a measured target) or 'coasting' (the search region's prediction)."""
        if self.target is None:
            return "following" if self.following else "searching"
        return "detected" if self.target.measured else "coasting"

    @property
    def designated_measured(self) -> bool:
        """Whether the operator's own target was reported measured this frame (what confirms a
        designation); for a detector that lists no targets, whether its one target was."""
        if not self.targets:
            return self.target is not None and self.target.measured
        return any(t.designated and t.target.measured for t in self.targets)


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
        self.scan = NativeScan()
        self.points = PointDetector()
        self._spot_band = 0  # the band of the frame the spots' next turn searches
        self.tracks: List[Track] = []  # the targets followed, oldest (lowest id) first
        self._next_id = 1
        self._primary_id: Optional[int] = None  # last frame's primary: kept unless another is clearly better
        self._since_search = 0  # frames since the global stage last ran
        self._turn = -1  # the global look whose turn it was last (payload.detect.pipeline._spread)
        self._look_order: List[str] = []  # the looks that took turns on the last global frame (none: no turns)
        self._gad_next = True  # whether the next frame's global look may be GAD's (Glad.prepare)
        self._gmd_next = True  # ... may be GMD's
        # this frame's camera motion for the local stage (one estimate for every track) and its matrix
        self._camera: Optional[CameraMotion] = None
        self._homography: Optional[np.ndarray] = None
        self._degraded: Dict[str, int] = {}
        self._prev: Optional[GreyLevels] = None
        self._prev_t_ns: Optional[int] = None
        self._prepared_prev: Optional[GreyLevels] = None  # the capture thread's: the last frame it prepared

    def prepare(self, frame: Frame) -> None:
        """Work a coming frame step will need, done on the capture thread (``FrameSource.prepare``):
        the frame's grey levels and camera motion (``_prepare_camera``) and, on a frame GAD
        down-scales strongly (1080p: ~3 ms of its ~13 on one core) while the next global look may be
        GAD's, GAD's input (down-scaled, padded, in float). It overlaps detection when the detector
        is still busy with the previous frame; at camera rate it only comes before the hand-over.
        Reads settings and flags the frame step leaves (``tracks``, ``_gad_next``, ``_gmd_next``); a
        frame read ahead may find them stale: the frame step then does the work itself."""
        self._prepare_camera(frame)
        gad = self.models.global_appearance
        if gad is None or not self._gad_next or not self.cfg.global_.appearance.enabled or not self._scanned(frame):
            return
        frame.prepared[GAD] = gad.letterbox(frame.image)

    def _prepare_camera(self, frame: Frame) -> None:
        """The frame's grey levels and the camera motion from the frame prepared before it, made on
        the capture thread: the local stage's (coarse) while a target is followed, GMD's (fine)
        when its look may come next (``_gmd_next``). The frame step uses a motion only if the frame
        it processed last is that one, with the settings in force (``_prepared_camera``; after a
        dropped frame or a reset it estimates its own)."""
        grey = GreyLevels.of(cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY))
        frame.prepared[GREY] = grey
        prev, self._prepared_prev = self._prepared_prev, grey
        if prev is None or prev.full.shape != grey.full.shape:
            return
        gmd = self._gmd_next and self.cfg.global_.motion.enabled
        levels = ([False] if self.tracks else []) + ([True] if gmd else [])
        if levels:
            motion = self.ego_motion
            frame.prepared[CAMERA] = (prev, motion.cfg, {fine: motion.estimate(prev, grey, fine=fine) for fine in levels})

    @property
    def designated(self) -> bool:
        """Whether a followed target is an operator's (designate)."""
        return any(t.designated for t in self.tracks)

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

    def _new_track(self) -> Track:
        track = Track(self._next_id, self.cfg, self._lock_settings(self.cfg), self.models.verifier,
                      self._local_available(self.cfg))
        self._next_id += 1
        return track

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
        for track in self.tracks:
            track.update_config(cfg, self._lock_settings(cfg), self._local_available(cfg))
        if len(self.tracks) > cfg.targets.max:
            # fewer targets allowed: keep the reported ones, the operator's first, then the oldest
            keep = sorted(self.tracks, key=lambda t: (not t.designated, not t.reported, t.id))[:cfg.targets.max]
            self.tracks = sorted(keep, key=lambda t: t.id)
        if self.models.global_appearance is not None:
            self.models.global_appearance.update_config(cfg.global_.appearance)
        if self.models.local_appearance is not None:
            self.models.local_appearance.update_config(cfg.local.appearance)
        if self.models.classifier is not None:
            self.models.classifier.update_config(cfg.classifier)
        return applied

    # --- operator designation (MAVLink camera track point / rectangle) --------------------------

    def designate(self, center_xy: Tuple[float, float], size_wh: Tuple[float, float]) -> None:
        """Local mode with a search region on an operator's point: the next frames' local
        detectors look there (the lock check judges what they find afresh) and, while this lock
        holds, no stronger hit elsewhere takes it (no retarget). Lost after max_local_misses as
        any lock; a target the global search then finds is an automatic one again. A followed
        target under the point becomes the operator's (its id kept); else a new one starts, in
        place of the youngest unreported (else youngest) target when there is no room."""
        cx, cy, w, h = float(center_xy[0]), float(center_xy[1]), float(size_wh[0]), float(size_wh[1])
        box = np.array([cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0], np.float32)
        for track in self.tracks:
            track.designated = False
        track = next((t for t in self.tracks if overlap(t.box(), box)), None)
        if track is None:
            if len(self.tracks) >= self.cfg.targets.max:
                drop = max(self.tracks, key=lambda t: (not t.reported, t.id))
                self.tracks.remove(drop)
            track = self._new_track()
            self.tracks.append(track)
        track.designate((cx, cy), (w, h))

    def release(self) -> None:
        """The operator's target ends (operator's stop, or a designation not confirmed); without
        one, every target does: back to automatic global search."""
        chosen = [t for t in self.tracks if t.designated]
        self.tracks = [t for t in self.tracks if not t.designated] if chosen else []

    def reset(self) -> None:
        self.tracks = []
        self._next_id = 1
        self._primary_id = None
        self._since_search = 0
        self._turn = -1
        self._spot_band = 0
        self.scan.reset()
        self._look_order, self._gad_next, self._gmd_next = [], True, True
        self._prev = self._prev_t_ns = None

    # --- the per-frame step -------------------------------------------------------------

    def process(self, frame: Frame) -> GladResult:
        timings: Dict[str, float] = {}
        t0 = time.perf_counter()
        grey = frame.prepared.get(GREY)
        if not isinstance(grey, GreyLevels) or grey.full.shape != frame.image.shape[:2]:
            grey = GreyLevels.of(cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY))
        timings["grey"] = _ms(t0)
        self._camera, self._homography = None, None
        self._degraded = {}
        candidates: List[Detections] = []
        # a target without a local stage to follow it (global-only) lives one frame: every global
        # hit starts a new lock
        self.tracks = [t for t in self.tracks if t.local]
        searched = list(self.tracks)  # the tracks the local stage searches this frame, oldest first
        search = self._search_due()
        for track in searched:
            track.begin_frame()
        found_far: List[Detections] = []  # strong, confirmed local hits belonging to no track
        for track in searched:
            self._local(track, frame, grey, timings, candidates, found_far)
        self.tracks = [t for t in searched if t.target is not None]  # the others were lost or judged false
        started = self._start_far(frame, found_far, timings)
        if search:
            started += self._global(frame, grey, timings, candidates)
            self._since_search = 0
        else:
            self._since_search += 1
        self._prev = grey
        self._prev_t_ns = frame.t_capture_ns
        self.tracks = merge_overlapping(sorted(self.tracks, key=lambda t: t.id))
        for track in self.tracks:
            self._verify(track, grey, frame, timings)
        reported = [t for t in self.tracks if t.verified]
        for track in self.tracks:
            track.reported = track in reported
            track.unreported = 0 if track.reported else track.unreported + 1
        primary = primary_of(reported, self.cfg.targets.primary, frame.size_wh, self._primary_id)
        self._primary_id = primary.id if primary is not None else None
        stepped = searched + started
        focus = primary if primary is not None else (stepped[0] if stepped else None)
        lock_p = float("nan")
        judged = primary if primary is not None else (self.tracks[0] if self.tracks else None)
        if judged is not None:
            lock_p = judged.verifier.probability
        search_next = self._search_due()
        order = self._look_order
        self._gad_next = search_next and (not order or (self._turn + 1) % len(order) == 0)
        # without turns GMD runs whenever GAD finds nothing
        self._gmd_next = search_next and (not order or order[(self._turn + 1) % len(order)] == GMD)
        targets = tuple(TrackedTarget(t.id, t.target, t.detections, t is primary, t.designated, t.verifier.probability)
                        for t in reported)
        if len(reported) > 1:
            log.debug("frame=%d targets=%s primary=%d", frame.index, [t.id for t in reported], primary.id)
        return GladResult(
            frame.index, frame.t_capture_ns, LOCAL if searched else GLOBAL,
            primary.detections if primary is not None else Detections.empty(), Detections.concat(candidates),
            primary.target if primary is not None else None, focus.region_xyxy if focus is not None else None,
            timings, following=primary is None and bool(self.tracks), lock_p=lock_p, degraded=self._degraded,
            targets=targets)

    def _on_spot(self, hit: Detections, grey: GreyLevels, image: np.ndarray) -> Detections:
        """A small local hit moved onto the centre of the isolated spot in it
        (payload.detect.points.PointDetector.centre), else as it is. A 3-6 px drone's network box sits
        a pixel or three off it, on a 4-8 px grid: where the track is measured there, the lock
        verifier's row measures sky beside the drone and its verdict falls for that frame (seed
        301 of configs/tiny-light-sky.yaml: 0.99 -> 0.01 with the box 3 px off, docs/results.md).
        The spot is looked for in the grey level, and only where it has none in the colour channels:
        a white drone on a pale sky can be the sky's grey yet stand out in its blue (seed 304); where
        the grey level had a spot, the colour channels' own noise had moved boxes that were right."""
        centre = self.points.centre(grey.full, hit.xyxy[0])
        if centre is None and image.ndim == 3:
            centre = self.points.centre(image, hit.xyxy[0])
        if centre is None:
            return hit
        c = hit.centers[0]
        return hit.shifted(centre[0] - c[0], centre[1] - c[1])

    def _where_expected(self, track: Track, near_distance: np.ndarray) -> bool:
        """Whether a local hit lies where the track's target should be: any hit within the jump gate;
        for a target no larger than the spot kernel (11 px), one within a kernel of the prediction.
        A bird 25-50 px beside a 3-6 px drone was a hit within the gate, the spots did not look for
        the drone, the lock went to the bird and its verifier began again on the drone's next frame
        (seeds 304 and 309 of configs/tiny-light-sky.yaml: 4 frames of 6 unreported)."""
        if not len(near_distance):
            return False
        kernel = self.points.kernel_px
        return max(track.region.size_wh) > kernel or float(near_distance.min()) <= kernel

    def _search_due(self) -> bool:
        """Whether the global stage runs this frame: always while no target is followed locally;
        with room for another target, every frame while none is reported, else every search_every;
        with no room, every search_every while a stale lock could give its place, every frame while
        the verifier refuses it (a bird or clutter held the only place while the drone was in view)."""
        if not self.tracks:
            return True
        t = self.cfg.targets
        if len(self.tracks) >= t.max:
            stale = self._stalest()
            return stale is not None and (stale.verifier.refused or self._since_search + 1 >= t.search_every)
        if not any(track.reported for track in self.tracks):
            return True
        return self._since_search + 1 >= t.search_every

    def _verify(self, track: Track, grey: GreyLevels, frame: Frame, timings: Dict[str, float]) -> None:
        """Add this frame of the track's lock to its verifier."""
        target = track.target
        t = time.perf_counter()
        observed = track.observed if target.measured and track.observed is not None and len(track.observed) else None
        if observed is not None and track.drone_p is None and track.verifier.judging and self.models.classifier is not None:
            # the lock check did not ask the classifier this frame (it is off): the verifier's row needs it
            track.drone_p = float(self.models.classifier.probabilities(frame.image, observed)[0])
        row = track.verifier.features.row(
            grey.full, target.xyxy, observed.xyxy[0] if observed is not None else None,
            float(observed.score[0]) if observed is not None else 0.0,
            str(observed.module[0]) if observed is not None else "", track.drone_p, self._homography)
        track.verifier.add(row)
        track.last_row = row
        track.last_box = track.detections.xyxy[0].copy() if len(track.detections) else None
        _add(timings, "verifier", _ms(t))

    def _global(self, frame: Frame, grey: GreyLevels, timings: Dict[str, float],
                candidates: List[Detections]) -> List[Track]:
        """The global stage; returns the tracks it started. With no target followed, its best hit
        starts one (as the single-target GLAD); beside followed ones, only hits that belong to none
        of them count (``_new_targets``)."""
        existing = list(self.tracks)

        def keep(found: Detections) -> Detections:
            return self._new_targets(found, existing) if existing else found

        found = Detections.empty()
        gad = self.models.global_appearance
        prev = self._prev
        looks = []
        if gad is not None and self.cfg.global_.appearance.enabled:
            looks.append(GAD)
        if self.cfg.global_.motion.enabled and prev is not None and prev.full.shape == grey.full.shape:
            looks.append(GMD)
        if GAD in looks and self._scan_available(frame):
            looks.append(SCAN)
        if GAD in looks and self.cfg.global_.scan.points and self._scanned(frame):
            looks.append(POINTS)
        if self._scanned(frame) and len(looks) > 1:
            spots_along = POINTS in looks and not existing
            looks = self._spread(looks)
            if spots_along and looks[0] in (GMD, SCAN):
                # With nothing followed the local stage costs nothing this frame: GMD's and the scan's
                # turns (~15 ms on 1080p) have room for a band of spots (~6 ms) after them. The spots
                # then cover a 1080p frame in 4 frames instead of 12, and a 3-6 px drone is found
                # as soon as it is in view (configs/tiny-light-sky.yaml seeds 300-309: centre recall
                # 0.681 -> 0.714, docs/results.md). GAD's turn (its network on the whole frame, the
                # dearest look) stays alone.
                looks.append(POINTS)
        if GAD in looks:
            found = keep(self._appearance(gad, frame.image, frame.image, (0, 0), timings, candidates,
                                          letterboxed=frame.prepared.get(GAD)))
        if not len(found) and GMD in looks:
            t = time.perf_counter()
            camera = self._prepared_camera(frame, fine=True)
            if camera is None:
                camera = self.ego_motion.estimate(prev, grey, fine=True)
            found = keep(self._motion(self.gmd, frame.image, prev.full, grey.full, camera, (0, 0), t, timings, candidates))
        if not len(found) and SCAN in looks:
            scanned = self._scan(frame, timings)
            candidates.append(scanned)
            # Native-resolution tiles meet many more birds than GAD's down-scaled
            # look: where GAD hits are checked, a scan hit must convince the classifier as much
            # as a lock must to be reported (a synthetic gull at 0.51 took the demo's lock).
            found = keep(self._classify(frame.image, scanned, timings, threshold=max(
                self.cfg.classifier.threshold, self.cfg.classifier.confirm_threshold)))
        if not len(found) and POINTS in looks:
            # a 3-6 px white drone on the sky: the networks hardly answer to it (docs/results.md,
            # tiny light drones); the spots, like the scan's hits, need the lock bar
            t = time.perf_counter()
            spots = self._spots(frame.image)
            _add(timings, POINTS, _ms(t))
            candidates.append(spots)
            # a spot has no confidence of its own (its score maps its isolation): as a motion hit, it
            # takes the classifier's probability, so that one the classifier is sure of may start a
            # target in place of a refused lock as a network's hit over T0 may (seed 309 of the tiny
            # white drones: the drone's spot at p 0.98-1.00 but isolation scores 0.33-0.49)
            found = keep(self._classify(frame.image, spots, timings, threshold=max(
                self.cfg.classifier.threshold, self.cfg.classifier.confirm_threshold), rescore=True))
        t = time.perf_counter()
        started = self._start(frame, found.sorted_by_score(), timings)
        _add(timings, "switcher", _ms(t))
        return started

    def _spread(self, looks: List[str]) -> List[str]:
        """The one look this global frame takes on a frame GAD down-scales strongly (1080p): GAD,
        GMD, the scan and the spots in turn. All in one frame cost ~55 ms there, beyond a 30 FPS
        camera's 33 ms; one a frame stays near the dearest one's ~15 ms. On synthetic 1080p scenes
        GAD, GMD and the scan in turn found as much as all three at once (docs/results.md). With
        nothing followed, ``_global`` adds a band of spots to GMD's and the scan's turns."""
        self._look_order = list(looks)
        self._turn = (self._turn + 1) % len(looks)
        return [looks[self._turn]]

    def _new_targets(self, found: Detections, tracks: List[Track]) -> Detections:
        """The hits that could start another target beside ``tracks``: strong (score >= T0, the
        classifier having confirmed those it checks) and belonging to none of them."""
        strong = found[found.score >= self.cfg.global_.appearance.confidence]
        gate = self.cfg.switcher.max_jump_px
        return strong[np.array([is_far(box, tracks, gate) for box in strong.xyxy], bool)] if len(strong) else strong

    def _start(self, frame: Frame, hits: Detections, timings: Dict[str, float]) -> List[Track]:
        """New tracks on ``hits`` (best first) while there is room: the first one whatever it is
        when no target is followed, the others only if they belong to no track."""
        started = []
        for i in range(len(hits)):
            hit = hits[i:i + 1]
            if self.tracks and not len(self._new_targets(hit, self.tracks)):
                continue
            if len(self.tracks) >= self.cfg.targets.max:
                stale = self._stalest()
                if stale is None:
                    break
                log.info("frame=%d target %d followed %d frames unreported gives its place to a new hit",
                         frame.index, stale.id, stale.unreported)
                self.tracks.remove(stale)
            track = self._new_track()
            track.target = self._acquire(track, frame, hit, timings)
            track.detections = hit
            track.switcher.after(hit=True)
            self.tracks.append(track)
            started.append(track)
        return started

    def _stale_after(self) -> int:
        """Frames a lock may go unconfirmed before it is stale: LockCheck's whole window (lock_hits),
        at least search_every. Stale after 5, a false lock on tests/test_glad_synthetic.py's seed 11
        gave its place to the next false hit, and that to the next, where LockCheck would have
        dropped the first after its 10 hits and the search would have run every frame (F 0.94 -> 0.77)."""
        return max(self.cfg.classifier.lock_hits, self.cfg.targets.search_every)

    def _stalest(self) -> Optional[Track]:
        """The stale track (Track.stale) longest followed without being reported (ties: the
        oldest); None when no track is stale."""
        stale = [t for t in self.tracks if t.stale(self._stale_after())]
        return max(stale, key=lambda t: (t.unreported, -t.id)) if stale else None

    def _start_far(self, frame: Frame, found_far: List[Detections], timings: Dict[str, float]) -> List[Track]:
        """New tracks on the local stage's strong, confirmed hits beyond every track's gate."""
        if not found_far:
            return []
        t = time.perf_counter()
        started = self._start(frame, Detections.concat(found_far).sorted_by_score(), timings)
        _add(timings, "switcher", _ms(t))
        return started

    def _prepared_camera(self, frame: Frame, fine: bool) -> Optional[CameraMotion]:
        """The camera motion at this level of detail made by ``prepare`` for this frame, if it was
        made from the very grey levels this step holds as the previous frame's and with the
        settings in force; else None."""
        prepared = frame.prepared.get(CAMERA)
        if not (isinstance(prepared, tuple) and len(prepared) == 3 and isinstance(prepared[2], dict)):
            return None
        prev, cfg, made = prepared
        camera = made.get(fine)
        if self._prev is None or prev is not self._prev or cfg is not self.ego_motion.cfg or not isinstance(camera, CameraMotion):
            return None
        return camera

    def _local_camera(self, frame: Frame, grey: GreyLevels) -> CameraMotion:
        """This frame's camera motion for the local stage: made ahead (``prepare``) or estimated
        here, once, shared by every track."""
        if self._camera is None:
            self._camera = self._prepared_camera(frame, fine=False)
            if self._camera is None:
                self._camera = self.ego_motion.estimate(self._prev, grey, fine=False)
            self._homography = self._camera.matrix if self._prev is not None else None
        return self._camera

    def _local(self, track: Track, frame: Frame, grey: GreyLevels, timings: Dict[str, float],
               candidates: List[Detections], found_far: List[Detections]) -> None:
        """The local stage in ``track``'s search region: sets the track's target for this frame
        (None: lost, or judged false). A strong confirmed hit beyond the gate that belongs to no
        other track goes to ``found_far`` while there is room for another target, else it may
        retarget this track."""
        t = time.perf_counter()
        camera = self._local_camera(frame, grey)
        dt_s = (frame.t_capture_ns - self._prev_t_ns) / 1e9 if self._prev_t_ns is not None else 1.0 / 30
        predicted = track.region.predict(camera, dt_s)
        region = track.region.region_xyxy(frame.size_wh)
        track.region_xyxy = region
        _add(timings, "region", _ms(t))
        x1, y1, x2, y2 = (int(v) for v in region)
        found = Detections.empty()
        lad = self.models.local_appearance
        if lad is not None and self.cfg.local.appearance.enabled:
            found = self._appearance(lad, frame.image, frame.image[y1:y2, x1:x2], (x1, y1), timings, candidates)
        prev = self._prev
        if not len(found) and self.cfg.local.motion.enabled and prev is not None and prev.full.shape == grey.full.shape:
            # the region's camera motion, not one of its own: one estimate a frame
            found = self._motion(self.lmd, frame.image, prev.full[y1:y2, x1:x2], grey.full[y1:y2, x1:x2],
                                 camera.for_crop((x1, y1)), (x1, y1), time.perf_counter(), timings, candidates)
        gated = self._gate(found, predicted)
        if self.cfg.global_.scan.points and self._scanned(frame) and not self._where_expected(track, gated[1]):
            # nothing where the target should be (a hit elsewhere in the region, a bird, is no
            # reason not to look for a small target's spot there)
            t = time.perf_counter()
            spots = self.points.detect(frame.image[y1:y2, x1:x2], offset_xy=(x1, y1), module=LAD,
                                       min_isolation=LOCAL_SPOT_ISOLATION)
            candidates.append(spots)
            _add(timings, "points", _ms(t))
            found = Detections.concat([found, self._confirm(frame.image, spots, rescore=True, timings=timings)])
            gated = self._gate(found, predicted)
        t = time.perf_counter()
        near, near_distance, far = gated
        best = self._pick(near, near_distance)
        others = [o for o in self.tracks if o is not track]
        if others and len(far):
            # a hit another target's own: that track follows it
            far = far[np.array([is_far(box, others, self.cfg.switcher.max_jump_px) for box in far.xyxy], bool)]
        retarget = far[:0]
        if len(self.tracks) + len(found_far) < self.cfg.targets.max:
            # room for another target: it starts beside this one, which keeps its own lock
            new = self._strong_far(frame.image, far, 0.0, timings)
            if len(new):
                found_far.append(new)
        else:
            retarget = self._retarget(track, frame.image, far, best, timings)
        if len(retarget):
            # a confident, confirmed hit away from the prediction, stronger than anything near it:
            # the lock was on clutter or had lost the target; start again there, a new target
            track.id, self._next_id = self._next_id, self._next_id + 1
            track.target = self._acquire(track, frame, retarget, timings)
            track.detections = retarget
            track.switcher.after(hit=True)
            _add(timings, "switcher", _ms(t))
            return
        if len(best) and not self._lock_holds(track, frame.image, best, timings):
            # the classifier does not believe in what is being followed: this target ends
            track.region.reset()
            track.switcher.reset()
            _add(timings, "switcher", _ms(t))
            return
        if len(best):
            best = self._on_spot(best, grey, frame.image)
            track.observed = best
            track.region.hit(tuple(best.centers[0]), tuple(best.xywh[0, 2:]), float(best.score[0]))
            best = best.resized(track.region.size_wh).rescored(track.region.score)
            track.target = self._target(frame, best, region=region)
        else:
            track.region.miss()
            track.target = Target(frame.index, frame.t_capture_ns, track.region.predicted_box(), 0.0, "",
                                  measured=False, region_xyxy=region)
        track.detections = best
        mode_next = track.switcher.after(hit=bool(len(best)))
        gone = not track.designated and not overlap(track.target.xyxy, np.float32([0, 0, *frame.size_wh]))
        if not len(best) and (mode_next == GLOBAL or gone):
            # lost; or an automatic lock predicted wholly out of the picture: it has left the view
            # (coasting on, its prediction ran to y = 4,000 px on a 1080p scene and blinded the
            # search meanwhile). The operator's lock ends as the switcher or the operator decides.
            track.region.reset()
            track.target = None
        _add(timings, "switcher", _ms(t))

    # --- helpers ----------------------------------------------------------------------------

    def _scan(self, frame: Frame, timings: Dict[str, float]) -> Detections:
        """Native-resolution hits on this frame's scan tiles (payload.detect.scan), as GAD hits.
        Off without a local appearance detector, and on frames GAD's input hardly down-scales."""
        lad, scan = self.models.local_appearance, self.cfg.global_.scan
        if not self._scan_available(frame):
            return Detections.empty()
        t = time.perf_counter()
        tiles = self.scan.next_tiles(frame.size_wh, lad.input_wh, scan.tiles_per_frame)
        parts = [lad.detect(frame.image[y1:y2, x1:x2], offset_xy=(float(x1), float(y1))) for x1, y1, x2, y2 in tiles]
        found = Detections.concat(parts)
        found = found[found.score >= self.cfg.global_.appearance.confidence]  # T0: these are GAD hits
        timings["scan"] = _ms(t)
        return Detections(found.xyxy, found.score, np.full(len(found), GAD, "<U3"))

    def _spots(self, image: np.ndarray) -> Detections:
        """The isolated spots (as GAD hits) in this turn's band of rows: the frame cut into bands of
        at most SPOT_BAND_PX pixels, searched in turn, so that a turn stays within a module's budget
        (issue 19); each band read with a margin, so that what is found is what the whole frame gives."""
        h, w = image.shape[:2]
        bands = max(1, -(-h * w // SPOT_BAND_PX))
        k = self._spot_band % bands
        self._spot_band = (k + 1) % bands
        y0, y1 = h * k // bands, h * (k + 1) // bands
        margin = self.points.margin_px
        top = max(0, y0 - margin)
        found = self.points.detect(image[top:min(h, y1 + margin)], offset_xy=(0.0, float(top)))
        if not len(found):
            return found
        cy = found.centers[:, 1]
        return found[(cy >= y0) & (cy < y1)]

    def _scan_available(self, frame: Frame) -> bool:
        return (self.models.local_appearance is not None and self.cfg.local.appearance.enabled
                and bool(self.cfg.global_.scan.tiles_per_frame) and self._scanned(frame))

    def _scanned(self, frame: Frame) -> bool:
        """Whether GAD's input down-scales this frame enough to need the native-resolution looks."""
        gad, scan = self.models.global_appearance, self.cfg.global_.scan
        w, h = frame.size_wh
        return gad is not None and min(gad.input_wh[0] / float(w), gad.input_wh[1] / float(h)) <= scan.max_input_scale

    def _acquire(self, track: Track, frame: Frame, best: Detections, timings: Dict[str, float]) -> Target:
        """A new target for ``track``: its search region starts around it, its lock judged afresh."""
        track.start(best)
        self._lock_holds(track, frame.image, best, timings)
        return self._target(frame, best, region=None)

    def _retarget(self, track: Track, image: np.ndarray, far: Detections, near_best: Detections,
                  timings: Dict[str, float]) -> Detections:
        """The strongest local appearance hit beyond the gate (``far``) if the global detector would
        have taken it (score > T0), the classifier confirms it, and it beats the chosen near hit."""
        if track.designated:
            return far[:0]  # the operator chose the target: it is not traded for a stronger one
        return self._strong_far(image, far, float(near_best.score[0]) if len(near_best) else 0.0, timings)

    def _strong_far(self, image: np.ndarray, far: Detections, floor: float, timings: Dict[str, float]) -> Detections:
        """The strongest local appearance hit of ``far`` scoring above T0 and ``floor``, if the
        classifier confirms it (0 or 1 row)."""
        floor = max(self.cfg.global_.appearance.confidence, floor)
        far = far[(far.module == LAD) & (far.score > floor)]
        if not len(far):
            return far
        return self._confirm(image, far.sorted_by_score()[:1], rescore=False, timings=timings)

    def _appearance(self, detector, image: np.ndarray, part: np.ndarray, offset_xy, timings: Dict[str, float],
                    candidates: List[Detections], letterboxed=None) -> Detections:
        """GAD or LAD on ``part`` of the frame (at ``offset_xy``; ``letterboxed``: ``part`` already made
        the detector's input, by ``prepare``): its hits join ``candidates``, those the classifier
        confirms are returned."""
        t = time.perf_counter()
        found = detector.detect(part, offset_xy=offset_xy, letterboxed=letterboxed)
        _add(timings, detector.module, _ms(t))
        candidates.append(found)
        return self._classify(image, found, timings)

    def _motion(self, detector: MotionDetector, image: np.ndarray, prev: np.ndarray, cur: np.ndarray, camera,
                offset_xy, t_start: float, timings: Dict[str, float], candidates: List[Detections]) -> Detections:
        """GMD or LMD on the grey ``prev``/``cur`` (a crop at ``offset_xy``) under ``camera``'s motion,
        timed from ``t_start``: its hits join ``candidates`` (candidates it left out to keep its time
        budget are counted in the frame's ``degraded``), those the classifier confirms are returned."""
        motion = detector.detect(prev, cur, camera, offset_xy=offset_xy)
        _add(timings, detector.module, _ms(t_start))
        if motion.left_out:
            self._degraded[detector.module] = self._degraded.get(detector.module, 0) + motion.left_out
        candidates.append(motion.detections)
        return self._classify(image, motion.detections, timings)

    def _classify(self, image: np.ndarray, dets: Detections, timings: Dict[str, float],
                  threshold: Optional[float] = None, rescore: bool = False) -> Detections:
        """The hits the classifier confirms (at ``threshold``, default its own), for the modules it
        checks (cfg.classifier.modules).

        Motion hits take the classifier's probability as their score (the motion detector has no
        score of its own), and so do others with ``rescore``; appearance hits keep the detector's
        confidence.
        """
        if not len(dets) or dets.module[0] not in self.cfg.classifier.modules:
            return dets
        return self._confirm(image, dets, rescore=rescore or dets.module[0] in (GMD, LMD), timings=timings,
                             threshold=threshold)

    def _confirm(self, image: np.ndarray, dets: Detections, rescore: bool, timings: Dict[str, float],
                 threshold: Optional[float] = None) -> Detections:
        """The hits the classifier confirms (at ``threshold``, default its own); all of them when it
        is off or absent."""
        classifier = self.models.classifier
        if not len(dets) or classifier is None or not self.cfg.classifier.enabled:
            return dets
        t = time.perf_counter()
        kept = classifier.filter(image, dets, rescore=rescore, threshold=threshold)
        _add(timings, "classifier", _ms(t))
        return kept

    def _lock_holds(self, track: Track, image: np.ndarray, best: Detections, timings: Dict[str, float]) -> bool:
        """Feed the chosen hit's drone probability to the track's lock check (cfg.classifier.lock_hits,
        confirm_hits)."""
        if not track.lock.active:
            return True
        t = time.perf_counter()
        probability = float(self.models.classifier.probabilities(image, best)[0])
        track.drone_p = probability
        _add(timings, "classifier", _ms(t))
        return track.lock.add(probability)

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


def _add(timings: Dict[str, float], key: str, ms: float) -> None:
    """Add to a frame's time of ``key`` (a module may run once per target)."""
    timings[key] = timings.get(key, 0.0) + ms


def _ms(t_start: float) -> float:
    return (time.perf_counter() - t_start) * 1000.0
