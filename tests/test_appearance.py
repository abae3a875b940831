"""payload.detect.appearance: letterbox mapping, decoding, and the shipped detectors on real frames."""

import os

import cv2
import numpy as np
import pytest
from onnx_factories import bright_spot_detector

from payload.boxes import iou_matrix
from payload.config import AppearanceConfig, DetectorConfig
from payload.detect.appearance import AppearanceDetector, letterbox
from payload.detect.factory import build_detectors, builtin_model_path
from payload.detect.onnx_model import OnnxModel
from payload.errors import ModelError


@pytest.fixture
def spot_model(tmp_path):
    return OnnxModel(bright_spot_detector(tmp_path / "spot.onnx"), threads=1)


def detector(model, input_wh, confidence=0.5, module="GAD", fit=False):
    return AppearanceDetector(model, AppearanceConfig(confidence=confidence, input_wh=input_wh), module, fit=fit)


@pytest.mark.parametrize(
    "image_wh, input_wh, scale_xy",
    [((1280, 768), (640, 384), (0.5, 0.5)), ((640, 512), (640, 384), (0.75, 0.75)), ((200, 150), (320, 320), (1, 1))],
)
def test_letterbox_scales_down_only_and_round_trips(image_wh, input_wh, scale_xy):
    image = np.zeros((image_wh[1], image_wh[0], 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = 7, 70, 200  # blue, green, red
    out = np.full((1, 3, input_wh[1], input_wh[0]), -1.0, np.float32)  # a reused buffer: every pixel rewritten
    blob, box = letterbox(image, input_wh, out=out)
    assert blob is out and blob.shape == (1, 3, input_wh[1], input_wh[0]) and blob.dtype == np.float32
    assert min(box.scale_xy) == pytest.approx(min(scale_xy), abs=2e-3)
    # the image lands top-left as RGB in [0, 1], the rest is grey padding
    new_w, new_h = round(image_wh[0] * box.scale_xy[0]), round(image_wh[1] * box.scale_xy[1])
    for channel, value in enumerate((200, 70, 7)):
        plane = blob[0, channel]
        assert np.allclose(plane[:new_h, :new_w], value / 255.0, rtol=0, atol=1e-6)
        assert np.allclose(plane[new_h:], 114 / 255.0, rtol=0, atol=1e-6)
        assert np.allclose(plane[:, new_w:], 114 / 255.0, rtol=0, atol=1e-6)
    xyxy = np.array([[10.0, 20.0, 50.0, 44.0]], np.float32)
    assert np.allclose(box.to_image(box.to_input(xyxy)), xyxy, atol=1e-3)


def test_letterbox_is_the_network_input_the_detectors_were_trained_on():
    # RGB in [0, 1] of the INTER_AREA down-scale, padded with 114: bit for bit what
    # cv2.dnn.blobFromImage made of the padded uint8 image before the input was written in place
    image = np.random.default_rng(0).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    blob, _ = letterbox(image, (640, 384))
    canvas = np.full((384, 640, 3), 114, np.uint8)
    canvas[:360] = cv2.resize(image, (640, 360), interpolation=cv2.INTER_AREA)
    assert np.array_equal(blob, cv2.dnn.blobFromImage(canvas, 1.0 / 255.0, swapRB=True))


def test_box_maps_back_through_downscale_non_square_input_and_offset(spot_model):
    # 1280x768 into 640x384 is a 0.5 down-scale: an 8x8 white square at (400, 200) becomes the
    # 4x4 input cell (200, 100), which the bright-spot network reports as that cell's box
    image = np.zeros((768, 1280, 3), np.uint8)
    image[200:208, 400:408] = 255
    dets = detector(spot_model, (640, 384)).detect(image, offset_xy=(1000, 50))
    assert len(dets) == 1
    assert np.allclose(dets.xyxy[0], [1400, 250, 1408, 258], atol=0.01)
    assert dets.module[0] == "GAD" and dets.score[0] == pytest.approx(1.0)


def test_small_crop_is_detected_at_native_resolution(spot_model):
    crop = np.zeros((150, 200, 3), np.uint8)
    crop[80:84, 40:44] = 255  # a 4x4 square: it would blur away if the crop were up- or down-scaled
    dets = detector(spot_model, (320, 320), confidence=0.9, module="LAD").detect(crop, offset_xy=(300, 600))
    assert len(dets) == 1
    assert np.allclose(dets.xyxy[0], [340, 680, 344, 684], atol=0.01)
    assert dets.module[0] == "LAD"


@pytest.mark.parametrize("image_wh, input_wh, run_wh", [
    ((640, 512), (640, 384), (480, 384)),  # a Halmstad frame into GAD's input
    ((1920, 1080), (640, 384), (640, 368)),
    ((300, 300), (320, 320), (304, 304)),
    ((500, 400), (320, 320), (320, 256)),  # down-scaled into the input
    ((20, 10), (320, 320), (32, 16)),
])
def test_a_fitted_network_of_any_size_sees_the_image_not_the_whole_input(spot_model, image_wh, input_wh, run_wh):
    # issue 19: the input is the fitted image's size rounded up to 16, not input_wh: a 640x512
    # frame costs GAD's network 480x384, not 640x384; the boxes map back the same
    det = detector(spot_model, input_wh, confidence=0.9, fit=True)
    assert det.multiple == 16
    w, h = image_wh
    scale = min(input_wh[0] / w, input_wh[1] / h, 1.0)
    side = int(np.ceil(4 / scale))  # a spot of 4 input px: one network cell
    x, y = (w - side) // 4 * 4 if scale == 1 else 0, (h - side) // 4 * 4 if scale == 1 else 0  # at the edge
    image = np.zeros((h, w, 3), np.uint8)
    image[y:y + side, x:x + side] = 255
    seen, run = [], spot_model.run
    spot_model.run = lambda feeds: seen.append(next(iter(feeds.values())).shape) or run(feeds)
    dets = det.detect(image, offset_xy=(100, 50))
    assert seen == [(1, 3, run_wh[1], run_wh[0])]
    assert len(dets) == 1
    assert np.allclose(dets.xyxy[0], [100 + x, 50 + y, 100 + x + side, 50 + y + side], atol=0.6 / scale)


@pytest.mark.parametrize("why", ["fixed size", "gpu provider", "not fitted"])
def test_a_network_that_cannot_take_any_size_always_gets_its_whole_input(tmp_path, why):
    # a model exported at one size refuses others; on a GPU provider every new size would build
    # the engine again (seconds in the air); LAD is not fitted (its search region at its own size
    # lost thermal and synthetic F): all run at input_wh
    path = bright_spot_detector(tmp_path / "spot.onnx", hw=(320, 320) if why == "fixed size" else ("H", "W"))
    model = OnnxModel(path, threads=1)
    if why == "gpu provider":
        model.providers = ["CUDAExecutionProvider", "CPUExecutionProvider"]  # what a GPU session reports
    det = detector(model, (320, 320), confidence=0.9, module="LAD", fit=why != "not fitted")
    assert det.multiple == 0
    seen, run = [], model.run
    model.run = lambda feeds: seen.append(next(iter(feeds.values())).shape) or run(feeds)
    crop = np.zeros((300, 300, 3), np.uint8)
    crop[40:44, 80:84] = 255
    dets = det.detect(crop)
    assert seen == [(1, 3, 320, 320)] and len(dets) == 1 and np.allclose(dets.xyxy[0], [80, 40, 84, 44])


def test_confidence_threshold_and_hot_reload(spot_model):
    image = np.zeros((128, 128, 3), np.uint8)
    image[16:20, 16:20] = 255
    image[64:68, 64:68] = 100  # score 100/255 = 0.39
    det = detector(spot_model, (128, 128), confidence=0.3)
    assert len(det.detect(image)) == 2
    det.update_config(AppearanceConfig(confidence=0.5, input_wh=(128, 128)))
    dets = det.detect(image)
    assert len(dets) == 1 and np.allclose(dets.xyxy[0], [16, 16, 20, 20])


def test_empty_image_gives_empty_detections(spot_model):
    dets = detector(spot_model, (128, 128)).detect(np.zeros((0, 0, 3), np.uint8))
    assert len(dets) == 0 and dets.xyxy.shape == (0, 4)


def test_model_with_wrong_output_layout_is_refused(tmp_path):
    # a classifier-shaped graph fed as a detector: input name right, output wrong
    import onnx
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("images", TensorProto.FLOAT, ["N", 3, "H", "W"])
    y = helper.make_tensor_value_info("out", TensorProto.FLOAT, ["N", 1, "H", "W"])
    g = helper.make_graph([helper.make_node("ReduceMean", ["images"], ["out"], axes=[1], keepdims=1)], "g", [x], [y])
    path = str(tmp_path / "wrong.onnx")
    model = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)
    with pytest.raises(ModelError, match=r"expected output \[N,5,H/s,W/s\]"):
        detector(OnnxModel(path), (128, 128))


def _shipped(name):
    path = builtin_model_path(name)
    if not os.path.exists(path):
        pytest.skip("shipped model %s not built yet" % path)
    return path


def _val_frame(halmstad_dir, clip="V_DRONE_013", index=60):
    import csv
    import json

    with open(os.path.join(halmstad_dir, "splits.json")) as fh:
        assert clip in json.load(fh)["val"]
    cap = cv2.VideoCapture(os.path.join(halmstad_dir, "visible", clip + ".mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, image = cap.read()
    assert ok
    with open(os.path.join(halmstad_dir, "labels", clip + ".csv")) as fh:
        row = next(r for r in csv.DictReader(fh) if int(r["frame"]) == index and r["class"] == "DRONE")
    x, y, w, h = (float(row[k]) for k in "xywh")
    return image, np.array([x - 1, y - 1, x - 1 + w, y - 1 + h], np.float32)


def test_shipped_global_detector_finds_the_drone_in_a_val_frame(halmstad_dir):
    _shipped("global")
    image, truth = _val_frame(halmstad_dir)
    models = build_detectors(DetectorConfig())
    dets = models.global_appearance.detect(image)
    assert len(dets) >= 1
    best = dets.sorted_by_score()[0]
    assert iou_matrix(best.xyxy[0], truth)[0, 0] > 0.5, (best.xyxy, truth)
    assert best.module[0] == "GAD"


def test_shipped_local_detector_finds_the_drone_in_a_search_region(halmstad_dir):
    _shipped("local")
    image, truth = _val_frame(halmstad_dir)
    cx, cy = int((truth[0] + truth[2]) / 2), int((truth[1] + truth[3]) / 2)
    x0, y0 = max(0, cx - 200), max(0, cy - 100)  # the drone off-centre in a 300x300 region
    models = build_detectors(DetectorConfig())
    dets = models.local_appearance.detect(image[y0:y0 + 300, x0:x0 + 300], offset_xy=(x0, y0))
    assert len(dets) >= 1
    best = dets.sorted_by_score()[0]
    assert iou_matrix(best.xyxy[0], truth)[0, 0] > 0.5, (best.xyxy, truth)
    assert best.module[0] == "LAD"


def test_the_shipped_global_detector_runs_at_the_frames_own_size_the_local_at_its_input():
    _shipped("global")
    _shipped("local")
    models = build_detectors(DetectorConfig())
    assert (models.global_appearance.multiple, models.local_appearance.multiple) == (16, 0)


def test_build_detectors_respects_enabled_switches():
    _shipped("global")
    cfg = DetectorConfig.model_validate(
        {"global": {"appearance": {"enabled": False}}, "classifier": {"enabled": False}}
    )
    models = build_detectors(cfg)
    assert models.global_appearance is None and models.classifier is None
    assert models.local_appearance is not None and models.local_appearance.input_wh == (320, 320)


def test_build_detectors_reports_a_missing_configured_model(tmp_path):
    cfg = DetectorConfig.model_validate({"local": {"appearance": {"model": str(tmp_path / "x.onnx")}}, "global": {"appearance": {"enabled": False}}, "classifier": {"enabled": False}})
    with pytest.raises(ModelError, match="^detector.local.appearance.model: .*x.onnx: no such model file$"):
        build_detectors(cfg)
