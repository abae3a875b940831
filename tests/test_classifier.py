"""payload.detect.classifier and payload.detect.patches: patch cutting, batching, threshold filter."""

import os

import numpy as np
import pytest
from onnx_factories import brightness_classifier

from payload.config import ClassifierConfig, DetectorConfig
from payload.detect.classifier import AppearanceClassifier
from payload.detect.factory import build_detectors, builtin_model_path
from payload.detect.onnx_model import OnnxModel
from payload.detect.patches import crop_patches, patch_squares, patches_to_input
from payload.types import Detections


class CountingModel(OnnxModel):
    """The real ONNX session, counting its inference calls."""

    calls = 0

    def run(self, feeds):
        self.calls += 1
        return super().run(feeds)


@pytest.fixture
def brightness(tmp_path):
    return CountingModel(brightness_classifier(tmp_path / "bright.onnx"), expected_inputs={"patches": 3}, threads=1)


def scene():
    """Black frame with a white 10x10 square at (100, 50) and a grey one at (300, 200)."""
    image = np.zeros((480, 640, 3), np.uint8)
    image[50:60, 100:110] = 255
    image[200:210, 300:310] = 60
    return image


def test_patches_are_centred_squares_with_context():
    sq = patch_squares(np.array([[100, 50, 110, 60], [0, 0, 40, 20], [5, 5, 6, 6]], np.float32))
    assert np.allclose(sq[0], [105, 55, 15])  # 1.5 x the longer side
    assert np.allclose(sq[1], [20, 10, 60])
    assert np.allclose(sq[2], [5.5, 5.5, 12])  # tiny boxes get the minimum side


def test_crop_patches_shape_content_and_border():
    image = scene()
    p = crop_patches(image, np.array([[100, 50, 110, 60], [620, 460, 640, 480], [-50, -50, -40, -40]], np.float32))
    assert p.shape == (3, 32, 32, 3) and p.dtype == np.uint8
    # the white square fills the middle 2/3 of its patch, black context around it
    assert p[0, 12:20, 12:20].min() == 255 and p[0, :3].max() == 0
    assert p[1].max() == 0  # a corner box: border pixels repeated, no garbage
    assert (p[2] == 114).all()  # wholly outside: a grey patch, not a wrapped-around slice
    x = patches_to_input(p)
    assert x.shape == (3, 3, 32, 32) and x.dtype == np.float32 and x.max() == 1.0


def test_probabilities_are_batched_in_one_run(brightness):
    clf = AppearanceClassifier(brightness, ClassifierConfig(threshold=0.2))
    brightness.calls = 0
    dets = Detections(np.array([[100, 50, 110, 60], [300, 200, 310, 210], [500, 400, 510, 410]], np.float32),
                      [0.1, 0.2, 0.3], "GMD")
    prob = clf.probabilities(scene(), dets)
    assert brightness.calls == 1
    assert prob.shape == (3,) and prob.dtype == np.float32
    # each batched value equals the patch alone: 100 of 225 patch pixels white in a 15 px patch
    singles = [clf.probabilities(scene(), dets[i])[0] for i in range(3)]
    assert np.allclose(prob, singles, atol=1e-6)
    assert prob[0] > prob[1] > prob[2] == 0.0


def test_filter_keeps_threshold_and_scores_by_probability(brightness):
    dets = Detections(np.array([[100, 50, 110, 60], [300, 200, 310, 210], [500, 400, 510, 410]], np.float32),
                      [0.1, 0.2, 0.3], ["GMD", "LMD", "GMD"])
    clf = AppearanceClassifier(brightness, ClassifierConfig(threshold=0.2))
    kept = clf.filter(scene(), dets)
    assert len(kept) == 1
    assert np.allclose(kept.xyxy[0], [100, 50, 110, 60]) and kept.module[0] == "GMD"
    assert kept.score[0] == pytest.approx(clf.probabilities(scene(), dets)[0])
    clf.update_config(ClassifierConfig(threshold=0.05))
    assert len(clf.filter(scene(), dets)) == 2


def test_no_candidates_no_inference(brightness):
    clf = AppearanceClassifier(brightness, ClassifierConfig())
    brightness.calls = 0
    assert len(clf.filter(scene(), Detections.empty())) == 0
    assert brightness.calls == 0


def test_shipped_classifier_prefers_the_drone_to_background(halmstad_dir):
    if not os.path.exists(builtin_model_path("classifier")):
        pytest.skip("shipped classifier not built yet")
    from test_appearance import _val_frame

    image, truth = _val_frame(halmstad_dir)
    w, h = truth[2] - truth[0], truth[3] - truth[1]
    rng = np.random.default_rng(3)
    background = []
    while len(background) < 20:  # sky/trees boxes of drone size away from the drone
        x, y = rng.uniform(0, 640 - w), rng.uniform(0, 512 - h)
        if abs(x - truth[0]) > 3 * w or abs(y - truth[1]) > 3 * h:
            background.append([x, y, x + w, y + h])
    dets = Detections(np.concatenate([truth[None], np.array(background, np.float32)]), np.ones(21), "GMD")
    clf = build_detectors(DetectorConfig.model_validate(
        {"global": {"appearance": {"enabled": False}}, "local": {"appearance": {"enabled": False}}})).classifier
    prob = clf.probabilities(image, dets)
    assert prob[0] >= 0.5
    assert np.mean(prob[1:] < 0.5) >= 0.9
