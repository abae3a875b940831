"""training/onnx_init.py: fine-tuning starts from the shipped ONNX networks when their checkpoints are gone."""

import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # training/ needs the training environment
ort = pytest.importorskip("onnxruntime")

import payload.models  # noqa: E402
from training.onnx_init import freeze_batchnorm, load_onnx_classifier  # noqa: E402


def model_path(name):
    return os.path.join(os.path.dirname(payload.models.__file__), name)


def test_shipped_classifier_loads_with_its_exact_output():
    path = model_path("glad_classifier.onnx")
    net = load_onnx_classifier(path).eval()
    x = np.random.default_rng(0).random((32, 3, 32, 32), dtype=np.float32)
    want = ort.InferenceSession(path, providers=["CPUExecutionProvider"]).run(None, {"patches": x})[0]
    got = torch.softmax(net(torch.from_numpy(x)), 1).detach().numpy()
    assert np.abs(want - got).max() < 1e-5
    # trained with frozen BatchNorms, the train-mode output is the same function (dropout aside)
    net.train()
    freeze_batchnorm(net)
    for m in net.modules():
        if isinstance(m, torch.nn.Dropout):
            m.eval()
    got_train = torch.softmax(net(torch.from_numpy(x)), 1).detach().numpy()
    assert np.abs(want - got_train).max() < 1e-5
    assert all(not p.requires_grad for m in net.modules() if isinstance(m, torch.nn.BatchNorm2d) for p in m.parameters())


def test_a_detector_file_is_refused_as_a_classifier():
    with pytest.raises(ValueError, match="expected the PatchClassifier's"):
        load_onnx_classifier(model_path("glad_local.onnx"))
