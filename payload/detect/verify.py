"""Lock verification: judge a lock over its recent frames, not one crop (issue 16).

A single 32x32 crop cannot tell a drone from a bird, an airliner or a bright patch of clutter
often enough for an autopilot that steers toward what it is told. What does tell them apart
shows over time: how the target moves against the camera-compensated background (a drone hovers
and turns, a bird glides and flaps, an airliner crawls), how its look and size hold (rotor
flicker vs wing beat, shape stability), what lies around it (smooth sky or textured ground), and
how the classifier's verdicts run. ``LockFeatures`` turns each frame of a lock into one row of
such measurements (the same code at training and at run time), and where the network asks for
them the ``LOOK_FEATURES`` of the target's own pixels (``target_patch``, ``look_row``): the shape
of what stands out at half its peak, and how that look holds from frame to frame, where the box
alone cannot tell a wing beat (a fast bird of one thermal session, counted a drone on 5 % of its
frames by the rows alone, docs/results.md). ``LockVerifier`` keeps the last ``window`` rows of the
current lock and asks a small ONNX network of our own (training/train_verifier.py) for the
probability that the lock is a drone.

Network contract: input 'tracks' [N, T, F] float32 (F = len(FEATURES), or that plus
len(LOOK_FEATURES): the network's F says which; rows oldest first, missing rows all zero: their
'present' feature is 0); output [N, 1] drone probability.
"""

import logging
from collections import deque
from typing import Optional, Tuple

import cv2
import numpy as np

from payload.types import GAD, GMD, LAD, LMD

log = logging.getLogger(__name__)

FEATURES = (
    "present",  # 1 for a frame of the lock, 0 for padding
    "measured",  # a detector found it this frame (0: the search region coasts)
    "gad", "gmd", "lad", "lmd",  # which module found it
    "score",  # the module's score
    "drone_p",  # the 32x32 classifier's drone probability (the last one while coasting)
    "log2_w", "log2_h",  # size of the measured box (px, as detected)
    "rel_dx", "rel_dy",  # motion against the compensated background, in box sizes per frame
    "log_rel_px",  # log1p of that motion in pixels
    "log_ego_px",  # log1p of the camera's own motion at the target (px per frame)
    "contrast",  # (mean inside - mean of the ring around) / (ring std + 4): sign = polarity
    "log_std_in",  # log1p of the grey std inside the box: texture / blur of the target
    "log_std_ring",  # log1p of the ring's std: smooth sky or textured ground
    "motion_valid",  # the previous frame and its camera motion were known
)
N_FEATURES = len(FEATURES)
# after FEATURES where the network asks for them (its F = N_FEATURES + N_LOOK): the target's own pixels
LOOK_FEATURES = (
    "look_log_area",  # log2 of the target's pixels (at half its peak) in the box-scaled patch
    "look_aniso",  # (l1 - l2) / (l1 + l2) of their second moments: 0 round, 1 a line
    "look_cos2", "look_sin2",  # their orientation (2 theta), scaled by the anisotropy
    "look_peak",  # log1p of the peak against the patch border's spread
    "look_ncc",  # normalised correlation with the lock's previous patch (0: none)
    "look_sharp",  # mean |Laplacian| at the centre of the native patch against its spread: rotor blur
)
N_LOOK = len(LOOK_FEATURES)
_MODULES = (GAD, GMD, LAD, LMD)


class LockFeatures:
    """Per-frame measurements of one lock (``row``), remembering where it was last frame. With
    ``look``, each row goes on with the LOOK_FEATURES of the target's own pixels."""

    def __init__(self, look: bool = False) -> None:
        self.look = look
        self.reset()
        self.box = np.zeros(4)  # the box this frame's row measured (the detector's, else the prediction)

    def reset(self) -> None:
        self._prev_center: Optional[np.ndarray] = None
        self._prev_patch: Optional[np.ndarray] = None
        self._last = np.zeros(N_FEATURES, np.float32)

    def row(self, grey: np.ndarray, target_xyxy: np.ndarray, measured_xyxy: Optional[np.ndarray],
            score: float, module: str, drone_p: Optional[float], homography: Optional[np.ndarray]) -> np.ndarray:
        """One row for this frame. ``measured_xyxy`` is the box a detector found (None while the
        region coasts on ``target_xyxy``, its prediction); ``homography`` maps last frame's pixels to
        this frame's (None when unknown, e.g. on the frame a lock starts)."""
        r = np.zeros(N_FEATURES, np.float32)
        r[0] = 1.0
        box = self.box = np.asarray(measured_xyxy if measured_xyxy is not None else target_xyxy, np.float64)
        center = np.array([(box[0] + box[2]) / 2.0, (box[1] + box[3]) / 2.0])
        w, h = max(1.0, box[2] - box[0]), max(1.0, box[3] - box[1])
        if measured_xyxy is not None:
            r[1] = 1.0
            if module in _MODULES:
                r[2 + _MODULES.index(module)] = 1.0
            r[6] = _finite(score)
            r[8], r[9] = np.log2(w), np.log2(h)
            r[14:17] = _surroundings(grey, box)
        else:
            r[8:10] = self._last[8:10]
            r[14:17] = self._last[14:17]
        r[7] = _finite(drone_p) if drone_p is not None else self._last[7]
        if self._prev_center is not None and homography is not None and np.all(np.isfinite(homography)):
            p = homography @ np.array([self._prev_center[0], self._prev_center[1], 1.0])
            if abs(p[2]) > 1e-9:
                carried = p[:2] / p[2]
                rel = center - carried
                size = np.sqrt(w * h)
                r[10:12] = np.clip(rel / size, -10.0, 10.0)
                r[12] = np.log1p(min(1e4, float(np.hypot(*rel))))
                r[13] = np.log1p(min(1e4, float(np.hypot(*(carried - self._prev_center)))))
                r[17] = 1.0
        self._prev_center = center
        self._last = r
        if not self.look:
            return r
        patch = target_patch(grey, box)
        look = look_row(patch, target_patch(grey, box, native=True), self._prev_patch)
        self._prev_patch = patch
        return np.concatenate([r, look])


PATCH_PX = 16
#: The square a patch is made from at most: a frame-sized box would cost milliseconds to shrink,
#: and no lock in the verifier's training was larger than 300 px (a 600 px square).
MAX_PATCH_SIDE_PX = 640


def target_patch(grey: np.ndarray, box: np.ndarray, native: bool = False) -> np.ndarray:
    """The target's own pixels: PATCH_PX x PATCH_PX uint8 grey around the box's centre, of a square
    twice the box's larger side (at least PATCH_PX / 2 px), or with ``native`` of the frame's own
    pixels; the frame's edge repeated where the square leaves it."""
    H, W = grey.shape[:2]
    cx = min(W - 1.0, max(0.0, (box[0] + box[2]) / 2.0))
    cy = min(H - 1.0, max(0.0, (box[1] + box[3]) / 2.0))
    side = PATCH_PX if native else max(PATCH_PX // 2, int(round(2 * max(box[2] - box[0], box[3] - box[1]))))
    side = min(side, MAX_PATCH_SIDE_PX)
    x1, y1 = int(round(cx - side / 2.0)), int(round(cy - side / 2.0))
    crop = grey[max(0, y1):min(H, y1 + side), max(0, x1):min(W, x1 + side)]
    crop = cv2.copyMakeBorder(crop, max(0, -y1), max(0, y1 + side - H), max(0, -x1), max(0, x1 + side - W),
                              cv2.BORDER_REPLICATE)
    if side == PATCH_PX:
        return np.ascontiguousarray(crop)
    return cv2.resize(crop, (PATCH_PX, PATCH_PX), interpolation=cv2.INTER_AREA if side > PATCH_PX else cv2.INTER_LINEAR)


def _finite(value) -> float:
    v = float(value)
    return v if np.isfinite(v) else 0.0


def _surroundings(grey: np.ndarray, box: np.ndarray) -> Tuple[float, float, float]:
    """(contrast, log1p std inside, log1p std of the ring out to twice the box) on the grey frame."""
    H, W = grey.shape[:2]
    x1, y1, x2, y2 = (int(round(v)) for v in box)
    x1, y1 = max(0, min(W - 1, x1)), max(0, min(H - 1, y1))
    x2, y2 = max(x1 + 1, min(W, x2)), max(y1 + 1, min(H, y2))
    bw, bh = x2 - x1, y2 - y1
    ox1, oy1 = max(0, x1 - bw // 2 - 2), max(0, y1 - bh // 2 - 2)
    ox2, oy2 = min(W, x2 + bw // 2 + 2), min(H, y2 + bh // 2 + 2)
    outer = grey[oy1:oy2, ox1:ox2].astype(np.float32)
    inner = grey[y1:y2, x1:x2].astype(np.float32)
    n_out, n_in = outer.size, inner.size
    s_out, s_in = float(outer.sum()), float(inner.sum())
    q_out, q_in = float((outer * outer).sum()), float((inner * inner).sum())
    n_ring = n_out - n_in
    mean_in = s_in / n_in
    std_in = np.sqrt(max(0.0, q_in / n_in - mean_in * mean_in))
    if n_ring <= 0:
        return 0.0, float(np.log1p(std_in)), 0.0
    mean_ring = (s_out - s_in) / n_ring
    std_ring = np.sqrt(max(0.0, (q_out - q_in) / n_ring - mean_ring * mean_ring))
    contrast = float(np.clip((mean_in - mean_ring) / (std_ring + 4.0), -10.0, 10.0))
    return contrast, float(np.log1p(std_in)), float(np.log1p(std_ring))


#: A lock whose drone probability stayed below REFUSED_BELOW over REFUSED_AFTER of the verifier's
#: verdicts in a row is refused (``LockVerifier.refused``): the tiny white drones' birds and clutter
#: held 0.00-0.39 for 150 frames, their drone locks reached 0.8-0.99 within every window. Each verdict
#: already weighs the model's whole window of rows (32 frames); a whole window of verdicts more (as
#: before) kept the search blind for 35 frames while seed 309's drone stood in view (docs/results.md).
REFUSED_BELOW = 0.5
REFUSED_AFTER = 8


class LockVerifier:
    """The current lock's recent rows and the network's verdict on them.

    ``verified`` turns True once the lock has at least ``min_frames`` rows and the network's drone
    probability reaches ``threshold``; it turns False again (the lock stops being reported) when
    the probability falls below ``release_threshold``. Without a model, or switched off, every lock
    counts as verified (rows are still kept: training/mine_tracks.py reads them). The window T is
    the model's (its input [N, T, F]).
    """

    def __init__(self, model=None, min_frames: int = 8, threshold: float = 0.5, release_threshold: float = 0.3,
                 enabled: bool = True, window: int = 16) -> None:
        self.model = model
        self._input_name = None
        self.n_features = N_FEATURES
        if model is not None:
            self._input_name, shape = next(iter(model.input_shapes.items()))
            window, self.n_features = int(shape[1]), int(shape[2])
        self.window = window
        self.features = LockFeatures(look=self.n_features == N_FEATURES + N_LOOK)
        self.rows: deque = deque(maxlen=window)
        self.update_config(min_frames, threshold, release_threshold, enabled)
        self.reset()

    @property
    def judging(self) -> bool:
        return self.enabled and self.model is not None

    def update_config(self, min_frames: int, threshold: float, release_threshold: float, enabled: bool = True) -> None:
        self.min_frames, self.threshold, self.release_threshold = min_frames, threshold, release_threshold
        self.enabled = enabled
        if not self.judging:
            self.verified = True

    def reset(self) -> None:
        """A new lock (or none)."""
        self.features.reset()
        self.rows.clear()
        self.probability = float("nan")  # the network's last verdict on this lock (nan: none yet)
        self.verified = not self.judging
        self.below = 0  # verdicts in a row under REFUSED_BELOW

    def add(self, row: np.ndarray) -> bool:
        """Record this frame's row of the lock; returns whether the lock is verified now."""
        self.rows.append(row)
        if not self.judging:
            return True
        if len(self.rows) < self.min_frames:
            return self.verified
        self.probability = float(self.model.run({self._input_name: self.window_array()[None]})[0].reshape(-1)[0])
        self.below = self.below + 1 if not self.probability >= REFUSED_BELOW else 0
        if not np.isfinite(self.probability):
            self.verified = False
        elif self.verified:
            self.verified = self.probability >= self.release_threshold
        else:
            self.verified = self.probability >= self.threshold
        return self.verified

    @property
    def refused(self) -> bool:
        """Whether the network has judged the lock not a drone over REFUSED_AFTER verdicts in a row
        (never REFUSED_BELOW or more), not merely held it back."""
        return self.judging and self.below >= REFUSED_AFTER

    def window_array(self) -> np.ndarray:
        """The last ``window`` rows [T, F], oldest first, zero rows in front while fewer."""
        out = np.zeros((self.window, self.n_features), np.float32)
        if self.rows:
            out[self.window - len(self.rows):] = np.stack(self.rows)
        return out


_BORDER = np.zeros((PATCH_PX, PATCH_PX), bool)
_BORDER[0] = _BORDER[-1] = _BORDER[:, 0] = _BORDER[:, -1] = True


def look_row(rel: np.ndarray, nat: np.ndarray, prev_rel: Optional[np.ndarray]) -> np.ndarray:
    """[len(LOOK_FEATURES)] from patches [PATCH_PX, PATCH_PX] uint8 (target_patch): the box-scaled one,
    the native one, and the lock's previous box-scaled one (None on the lock's first frame)."""
    c = PATCH_PX // 2
    p = rel.astype(np.float32)
    border = p[_BORDER]
    bg, noise = float(np.median(border)), float(border.std())
    # the target's polarity from its centre: warm on cold sky, or dark on bright
    sign = 1.0 if float(p[c - 2:c + 2, c - 2:c + 2].mean()) >= bg else -1.0
    a = np.maximum(sign * (p - bg), 0.0)
    peak = float(a[c // 2:c + c // 2, c // 2:c + c // 2].max())
    area, cxx, cyy, cxy = 0, 0.0, 0.0, 0.0
    if peak > 0:
        on = a >= 0.5 * peak
        area = int(np.count_nonzero(on))
        m = cv2.moments(np.where(on, a, 0.0).astype(np.float32))
        m00 = m["m00"] + 1e-6
        cxx, cyy, cxy = m["mu20"] / m00, m["mu02"] / m00, m["mu11"] / m00
    disc = np.sqrt((cxx - cyy) ** 2 / 4.0 + cxy ** 2)
    l1, l2 = (cxx + cyy) / 2.0 + disc, max(0.0, (cxx + cyy) / 2.0 - disc)
    aniso = (l1 - l2) / (l1 + l2 + 1e-6)
    theta2 = np.arctan2(2.0 * cxy, cxx - cyy)
    ncc = 0.0
    if prev_rel is not None:
        q = prev_rel.astype(np.float32)
        pz, qz = p - p.mean(), q - q.mean()
        ncc = float((pz * qz).sum() / np.sqrt((pz * pz).sum() * (qz * qz).sum() + 1e-6))
    lap = cv2.Laplacian(nat, cv2.CV_32F)
    sharp = float(np.abs(lap[c - 4:c + 4, c - 4:c + 4]).mean()) / (float(nat.std()) + 4.0)
    return np.array([np.log2(area + 1.0), aniso, aniso * np.cos(theta2), aniso * np.sin(theta2),
                     np.log1p(peak / (noise + 4.0)), ncc, sharp], np.float32)
