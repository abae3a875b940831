"""Appearance classifier: the paper's shallow CNN on 32x32 patches, MAV vs clutter.

It checks motion-detector candidates: one batched inference for all candidates of a frame.
Patches are cut by payload.detect.patches.crop_patches, the same function training uses.
Network contract (training/net.py): input 'patches' [N, 3, 32, 32] RGB in [0, 1]; output
[N, 2] probabilities, column 1 = drone.
"""

import logging
from collections import deque
from typing import Optional

import numpy as np

from payload.config import ClassifierConfig
from payload.detect.onnx_model import OnnxModel
from payload.detect.patches import PATCH_PX, crop_patches, patches_to_input
from payload.errors import ModelError
from payload.types import Detections

log = logging.getLogger(__name__)


class AppearanceClassifier:
    def __init__(self, model: OnnxModel, cfg: ClassifierConfig) -> None:
        self.model = model
        self.cfg = cfg
        self._input_name = next(iter(model.input_shapes))
        out = model.run({self._input_name: np.zeros((2, 3, PATCH_PX, PATCH_PX), np.float32)})[0]
        if out.shape != (2, 2):
            raise ModelError("%s: expected output [N,2] (clutter, drone probabilities), found %s" % (model.where, list(out.shape)))

    def update_config(self, cfg: ClassifierConfig) -> None:
        """Hot reload: the threshold."""
        self.cfg = cfg

    def probabilities(self, image_bgr: np.ndarray, dets: Detections) -> np.ndarray:
        """Drone probability per detection [N] float32; one inference for all of them."""
        if not len(dets):
            return np.zeros((0,), np.float32)
        x = patches_to_input(crop_patches(image_bgr, dets.xyxy))
        return self.model.run({self._input_name: x})[0][:, 1].astype(np.float32)

    def filter(self, image_bgr: np.ndarray, dets: Detections, rescore: bool = True,
               threshold: Optional[float] = None) -> Detections:
        """The detections whose drone probability reaches ``threshold`` (default cfg.threshold);
        ``rescore``: scored by that probability."""
        prob = self.probabilities(image_bgr, dets)
        keep = prob >= (self.cfg.threshold if threshold is None else threshold)
        log.debug("classifier candidates=%d kept=%d", len(dets), int(keep.sum()))
        kept = dets[keep]
        return Detections(kept.xyxy, prob[keep], kept.module) if rescore else kept


class LockCheck:
    """Track confirmation by the classifier: a lock is reported once confirmed and stands while
    the classifier believes in it on average.

    Confirmation: a new lock is reported from the first time ``confirm_hits`` hits in a row
    average at least ``confirm_threshold`` drone probability; until then it is followed without
    being reported (and the global detector cannot take the same bird again meanwhile). One
    frame's verdict on a bird is a coin toss; two in a row rarely both pass a high bar, while a
    drone that the classifier doubts at first (turning, half hidden) is reported once it shows
    itself. ``confirm_hits`` 0 = every lock is reported at once.

    Hold: the local detector follows whatever it was started on (a bird, a branch) as long as it
    keeps scoring above T1; the lock is dropped when the mean over its last ``hits`` hits falls
    below ``threshold``. Judged once that many hits are in; ``hits`` 0 = off. A lock not yet
    confirmed is judged on its last ``EARLY_HITS`` already: while it holds the only place, the
    global stage hardly searches, and on 1080p scenes false locks the classifier put at 0.0-0.2
    from their second hit held it 10 frames of every 12 (docs/results.md).
    """

    EARLY_HITS = 4

    def __init__(self, hits: int, threshold: float, confirm_hits: int = 0, confirm_threshold: float = 0.0) -> None:
        self.hits, self.threshold = hits, threshold
        self.confirm_hits, self.confirm_threshold = confirm_hits, confirm_threshold
        self._probs: deque = deque(maxlen=max(1, hits))
        self._recent: deque = deque(maxlen=max(1, confirm_hits))
        self.confirmed = not confirm_hits

    @property
    def active(self) -> bool:
        """Whether it needs the classifier's probabilities at all."""
        return bool(self.hits or self.confirm_hits)

    def update_config(self, hits: int, threshold: float, confirm_hits: int = 0, confirm_threshold: float = 0.0) -> None:
        if hits != self.hits:
            self._probs = deque(self._probs, maxlen=max(1, hits))
        if confirm_hits != self.confirm_hits:
            self._recent = deque(self._recent, maxlen=max(1, confirm_hits))
        self.hits, self.threshold = hits, threshold
        self.confirm_hits, self.confirm_threshold = confirm_hits, confirm_threshold
        self.confirmed = self.confirmed or not confirm_hits

    def reset(self) -> None:
        """A new lock."""
        self._probs.clear()
        self._recent.clear()
        self.confirmed = not self.confirm_hits

    def add(self, drone_probability: float) -> bool:
        """Record a hit's drone probability; False when the lock is judged false."""
        p = float(drone_probability)
        if not self.confirmed:
            self._recent.append(p)
            self.confirmed = len(self._recent) == self.confirm_hits and float(np.mean(self._recent)) >= self.confirm_threshold
        if not self.hits:
            return True
        self._probs.append(p)
        if not self.confirmed and len(self._probs) >= self.EARLY_HITS:
            if float(np.mean(list(self._probs)[-self.EARLY_HITS:])) < self.threshold:
                return False
        return len(self._probs) < self.hits or float(np.mean(self._probs)) >= self.threshold
