"""training/mine_locks.py: the patches of what GLAD itself reports, labelled against the truth."""

import numpy as np

from payload.config import Config
from payload.detect.patches import PATCH_PX
from payload.detect.pipeline import Glad
from payload.synth.scene import Scene
from training import mine_locks


def test_collects_the_locked_drone_as_drone_patches():
    scene = Scene(seed=11, width=1920, height=1080, frames=120, target_px=(6.0, 20.0))
    collector = mine_locks.Collector(every=2)
    glad = Glad(Config().detector)
    mine_locks.run_clip(glad, collector, "synthetic", ((sf.index, sf.image, sf.target_xyxy) for sf in scene))
    assert collector.x, "GLAD locked on nothing in 120 frames of seed 11"
    assert all(p.shape == (PATCH_PX, PATCH_PX, 3) and p.dtype == np.uint8 for p in collector.x)
    # seed 11's drone (a clip of tests/test_glad_synthetic.py) is reported from frame 12 or 53 (when GMD's
    # turn meets it moving: the turns' phase moves with the platform's numerics and with clutter spots
    # the classifier passes); then drone patches, one every second frame at most
    assert collector.counts.get(("synthetic", 1), 0) >= 30
    assert sum(collector.counts.values()) <= 60


def test_every_box_on_a_clip_without_drones_is_clutter():
    collector = mine_locks.Collector(every=1)

    class Result:
        def __init__(self, xyxy):
            from payload.types import Detections

            self.detections = Detections(np.array([xyxy], np.float32), np.array([0.9]), "LAD")

    image = np.zeros((100, 100, 3), np.uint8)
    collector.add("negatives_train", 0, image, Result([10, 10, 30, 30]), None)
    truth = np.array([10, 10, 30, 30], np.float32)
    collector.add("train", 1, image, Result([11, 10, 31, 30]), truth)   # on the drone
    collector.add("train", 2, image, Result([60, 60, 80, 80]), truth)   # far from it
    collector.add("train", 3, image, Result([25, 10, 45, 30]), truth)   # half on it: dropped
    assert collector.y == [0, 1, 0]
