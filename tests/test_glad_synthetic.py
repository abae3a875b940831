"""GLAD end to end on synthetic 1080p moving-camera clips with tiny (6-20 px) targets.

The paper's point: after down-scaling, the global appearance detector alone misses most tiny
targets; motion and the local detector at native resolution find them. Three seeded clips (the
same since this test was written), pooled: GLAD reaches F >= 0.8 (issue 3), the global appearance
detector alone is far worse. A wider seeded set is scored by `glad-payload eval --synthetic`
(docs/results.md), where GLAD does not reach F 0.8 on every clip.
"""

import numpy as np
import pytest

from payload.config import Config, config_with
from payload.detect.pipeline import Glad
from payload.eval.metrics import pool, score_clip
from payload.synth.scene import Scene
from payload.types import Frame

pytestmark = pytest.mark.slow

SEEDS = (7, 11, 23)
FRAMES = 150
GAD_ONLY = {
    "detector.global.motion.enabled": False,
    "detector.local.appearance.enabled": False,
    "detector.local.motion.enabled": False,
}


@pytest.fixture(scope="module")
def clips():
    out = {}
    for seed in SEEDS:
        frames, truth = [], {}
        for sf in Scene(seed=seed, width=1920, height=1080, fps=30.0, frames=FRAMES, target_px=(6.0, 20.0)):
            frames.append(Frame(sf.image, sf.index, int(sf.index * 1e9 / 30), 0))
            truth[sf.index] = np.zeros((0, 4), np.float32) if sf.target_xyxy is None else sf.target_xyxy.reshape(1, 4)
        out[seed] = (frames, truth)
    return out


def score(cfg, clips):
    scores, modes, modules = [], [], set()
    for seed, (frames, truth) in clips.items():
        glad = Glad(cfg.detector)
        results = [glad.process(f) for f in frames]
        modes += [r.mode for r in results]
        modules |= {m for r in results for m in r.detections.module}
        scores.append(score_clip(str(seed), {r.frame_index: r.detections for r in results}, truth, frames=FRAMES))
    return pool(scores), modes, modules


def test_glad_finds_tiny_targets_the_global_detector_misses(clips):
    assert all(sum(len(b) for b in t.values()) > 0.6 * FRAMES for _, t in clips.values())  # target mostly in view
    glad, glad_modes, _ = score(Config(), clips)
    alone, _, alone_modules = score(config_with(Config(), **GAD_ONLY), clips)
    print("GLAD P=%.2f R=%.2f F=%.2f | GAD alone P=%.2f R=%.2f F=%.2f"
          % (glad.precision, glad.recall, glad.f1, alone.precision, alone.recall, alone.f1))
    assert glad.f1 >= 0.8
    assert glad.recall >= np.nan_to_num(alone.recall) + 0.3
    assert glad.f1 >= np.nan_to_num(alone.f1) + 0.3
    assert alone_modules <= {"GAD"}  # the ablation row really ran the global appearance detector only
    assert glad_modes.count("local") > 0.5 * len(glad_modes)  # GLAD tracked locally once it had a target
