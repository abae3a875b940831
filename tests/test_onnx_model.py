"""payload.detect.onnx_model: provider lists, one-line model errors, warm-up, no torch in the runtime."""

import logging
import os
import subprocess
import sys

import numpy as np
import onnxruntime
import pytest
from onnx_factories import bright_spot_detector, brightness_classifier

from payload.detect import onnx_model
from payload.detect.onnx_model import OnnxModel, providers_for
from payload.errors import BackendUnavailable, ModelError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def detector_onnx(tmp_path):
    return bright_spot_detector(tmp_path / "spot.onnx")


def test_cpu_backend_is_cpu_only():
    assert providers_for("cpu", True, None) == ["CPUExecutionProvider"]


@pytest.mark.parametrize(
    "backend, expected",
    [
        ("tensorrt", ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"]),
        ("cuda", ["CUDAExecutionProvider", "CPUExecutionProvider"]),
        ("cpu", ["CPUExecutionProvider"]),
    ],
)
def test_provider_order_when_all_are_offered(monkeypatch, backend, expected):
    # stands in for an onnxruntime-gpu build with TensorRT (what JetPack's wheel offers)
    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: list(expected) + ["AzureExecutionProvider"])
    got = providers_for(backend, True, "/var/cache/x")
    assert [p[0] if isinstance(p, tuple) else p for p in got] == expected
    if backend == "tensorrt":
        name, opts = got[0]
        assert opts == {"trt_fp16_enable": True, "trt_engine_cache_enable": True, "trt_engine_cache_path": "/var/cache/x"}


def test_tensorrt_without_cache_and_fp32(monkeypatch):
    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: ["TensorrtExecutionProvider", "CPUExecutionProvider"])
    (name, opts), cpu = providers_for("tensorrt", False, None)
    assert opts["trt_fp16_enable"] is False and opts["trt_engine_cache_enable"] is False
    assert "trt_engine_cache_path" not in opts and cpu == "CPUExecutionProvider"


def test_missing_providers_are_dropped_with_one_log_line_each(caplog):
    offered = set(onnxruntime.get_available_providers())
    if {"TensorrtExecutionProvider", "CUDAExecutionProvider"} <= offered:
        pytest.skip("this onnxruntime offers TensorRT and CUDA: nothing to drop")
    with caplog.at_level(logging.WARNING, logger=onnx_model.__name__):
        got = providers_for("tensorrt", True, None)
    dropped = [r.getMessage() for r in caplog.records if "provider dropped" in r.getMessage()]
    missing = [p for p in ("TensorrtExecutionProvider", "CUDAExecutionProvider") if p not in offered]
    assert len(dropped) == len(missing)
    for name in missing:
        assert any("provider=%s" % name in m for m in dropped)
    assert got[-1] == "CPUExecutionProvider"


def test_unknown_backend():
    with pytest.raises(BackendUnavailable, match="'vulkan'"):
        providers_for("vulkan", True, None)


def test_loads_warms_up_and_runs(detector_onnx, caplog):
    with caplog.at_level(logging.INFO, logger=onnx_model.__name__):
        model = OnnxModel(detector_onnx, backend="tensorrt", threads=1, warmup_hw=(64, 96))
    assert model.providers[-1] == "CPUExecutionProvider"
    assert any("model loaded" in r.getMessage() and "provider=" in r.getMessage() for r in caplog.records)
    x = np.zeros((2, 3, 64, 96), np.float32)
    x[1, :, 8:12, 20:24] = 1.0
    (maps,) = model.run({"images": x})
    assert maps.shape == (2, 5, 16, 24)
    assert maps[0, 0].max() == 0.0 and maps[1, 0, 2, 5] == pytest.approx(1.0)


def test_missing_file_is_one_line(tmp_path):
    path = str(tmp_path / "nope.onnx")
    with pytest.raises(ModelError) as err:
        OnnxModel(path, config_key="detector.local.appearance.model")
    msg = str(err.value)
    assert msg == "detector.local.appearance.model: %s: no such model file" % path


def test_not_an_onnx_file_is_one_line(tmp_path):
    path = tmp_path / "foo.onnx"
    path.write_bytes(b"this is not a protobuf \x00\x01\x02" * 10)
    with pytest.raises(ModelError) as err:
        OnnxModel(str(path), config_key="detector.global.appearance.model")
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("detector.global.appearance.model: %s: not a usable ONNX model" % path)


def test_wrong_input_name_names_expected_and_found(tmp_path):
    path = bright_spot_detector(tmp_path / "foo.onnx", input_name="input0")
    with pytest.raises(ModelError) as err:
        OnnxModel(path, config_key="detector.local.appearance.model")
    assert str(err.value) == (
        "detector.local.appearance.model: %s: expected input 'images' [N,3,H,W], found 'input0' [N,3,H,W]" % path
    )


def test_wrong_channel_count(tmp_path):
    path = bright_spot_detector(tmp_path / "grey.onnx", channels=1)
    with pytest.raises(ModelError, match=r"expected input 'images' \[N,3,H,W\], found 'images' \[N,1,H,W\]"):
        OnnxModel(path)


def test_classifier_expects_patches_input(detector_onnx):
    with pytest.raises(ModelError, match="expected input 'patches'"):
        OnnxModel(detector_onnx, expected_inputs={"patches": 3}, config_key="detector.classifier.model")


def test_runtime_never_imports_torch():
    code = (
        "import importlib, pkgutil, sys, numpy as np\n"
        "import payload\n"
        "for m in pkgutil.walk_packages(payload.__path__, 'payload.'):\n"
        "    if m.name.endswith('__main__'):\n"
        "        continue\n"
        "    try:\n"
        "        importlib.import_module(m.name)\n"
        "    except Exception:\n"
        "        pass\n"
        "from payload.config import DetectorConfig\n"
        "from payload.detect.factory import build_detectors, builtin_model_path\n"
        "import os\n"
        "if os.path.exists(builtin_model_path('global')):\n"
        "    d = build_detectors(DetectorConfig())\n"
        "    d.global_appearance.detect(np.zeros((512, 640, 3), np.uint8))\n"
        "print('torch' in sys.modules, 'payload.detect.factory' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "True"]


def test_input_fixed_to_another_size_is_one_line(tmp_path):
    path = bright_spot_detector(tmp_path / "fixed.onnx", hw=(100, 100))
    with pytest.raises(ModelError) as err:
        OnnxModel(path, config_key="detector.local.appearance.model", warmup_hw=(320, 320))
    assert str(err.value) == (
        "detector.local.appearance.model: %s: input 'images' is fixed at [N,3,100,100], expected [N,3,320,320] "
        "(detector.local.appearance.input_wh [320, 320]) or dynamic H, W" % path)
    assert OnnxModel(path, warmup_hw=(100, 100)).input_shapes == {"images": ["N", 3, 100, 100]}  # the size it is fed


def test_every_session_gets_the_process_thread_budget(detector_onnx):
    # detector.threads 0: one fewer than the cores this process may use, at least one; no inter-op pool
    cores = len(os.sched_getaffinity(0))
    opts = OnnxModel(detector_onnx, threads=0).session.get_session_options()
    assert opts.intra_op_num_threads == max(1, cores - 1)
    assert opts.inter_op_num_threads == 1 and opts.execution_mode == onnxruntime.ExecutionMode.ORT_SEQUENTIAL
    assert OnnxModel(detector_onnx, threads=3).session.get_session_options().intra_op_num_threads == 3


def test_the_factory_builds_every_model_with_detector_threads(tmp_path):
    from onnx_factories import brightness_classifier

    from payload.config import Config, config_with
    from payload.detect.factory import build_detectors

    spot = bright_spot_detector(tmp_path / "spot.onnx")
    cfg = config_with(Config(), **{"detector.threads": 2, "detector.global.appearance.model": spot,
                                   "detector.local.appearance.model": spot, "detector.verifier.enabled": False,
                                   "detector.classifier.model": brightness_classifier(tmp_path / "bright.onnx")})
    models = build_detectors(cfg.detector)
    sessions = [models.global_appearance.model, models.local_appearance.model, models.classifier.model]
    assert [m.session.get_session_options().intra_op_num_threads for m in sessions] == [2, 2, 2]


def test_padded_batches_give_the_unpadded_outputs(tmp_path):
    # on a GPU provider the classifier's batches are fed at one size (a change of batch size cost
    # ONNX Runtime's CUDA provider 19 ms a run on an H100); forced on here, on the CPU
    path = brightness_classifier(tmp_path / "cls.onnx")
    plain = OnnxModel(path, expected_inputs={"patches": 3}, varying_batch=True)
    assert not plain.pad_batch  # the CPU takes any batch size as it comes
    padded = OnnxModel(path, expected_inputs={"patches": 3}, varying_batch=True)
    padded.pad_batch = True
    fed = []
    run = padded.session.run
    padded.session.run = lambda names, feeds: fed.append(len(feeds["patches"])) or run(names, feeds)
    rng = np.random.default_rng(0)
    for n in (0, 1, 3, 31, 32, 33, 100):
        x = rng.random((n, 3, 32, 32), dtype=np.float32)
        want = plain.run({"patches": x})[0]
        got = padded.run({"patches": x})[0]
        assert got.shape == want.shape == (n, 2)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    assert set(fed) == {onnx_model.GPU_BATCH} and len(fed) == 1 + 1 + 1 + 1 + 1 + 2 + 4  # 100 rows: 4 runs


def test_gpu_padding_only_for_varying_batches_and_warmed_at_load(detector_onnx, monkeypatch):
    warmed = []
    monkeypatch.setattr(OnnxModel, "_warm_up", lambda self, hw, batch=1: warmed.append(batch))
    OnnxModel(detector_onnx, warmup_hw=(64, 64), varying_batch=True)
    assert warmed == [1]  # on the CPU: as it comes
    warmed.clear()
    # a GPU session (any provider but the CPU's): the one batch size it will be fed is warmed at load
    monkeypatch.setattr(onnx_model, "CPU", "NoSuchExecutionProvider")
    model = OnnxModel(detector_onnx, warmup_hw=(64, 64), varying_batch=True)
    assert model.pad_batch and warmed == [onnx_model.GPU_BATCH]
    warmed.clear()
    assert not OnnxModel(detector_onnx, warmup_hw=(64, 64)).pad_batch and warmed == [1]
