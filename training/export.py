"""Export trained checkpoints to ONNX (opset 17, dynamic N/H/W) and check ORT against torch.

  python training/export.py det  training/runs/det1/last.pt payload/models/glad_global.onnx
  python training/export.py cls  training/runs/cls1/last.pt payload/models/glad_classifier.onnx
"""

import os
import sys
import warnings

import numpy as np
import onnx
import onnxruntime as ort
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from training.net import ClassifierExport, DetectorExport, PatchClassifier, TinyCenterNet  # noqa: E402


def export(kind, ckpt, out):
    ck = torch.load(ckpt, weights_only=False, map_location="cpu")
    if kind == "det":
        net = TinyCenterNet(ck.get("width", 1.0))
        net.load_state_dict(ck["model"])
        model, name_in, name_out = DetectorExport(net).eval(), "images", "maps"
        shapes = [(1, 3, 320, 320), (2, 3, 384, 640), (1, 3, 512, 640)]
        dyn = {"images": {0: "N", 2: "H", 3: "W"}, "maps": {0: "N", 2: "h", 3: "w"}}
    else:
        net = PatchClassifier()
        net.load_state_dict(ck["model"])
        model, name_in, name_out = ClassifierExport(net).eval(), "patches", "prob"
        shapes = [(1, 3, 32, 32), (7, 3, 32, 32)]
        dyn = {"patches": {0: "N"}, "prob": {0: "N"}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(model, torch.zeros(shapes[0]), out, input_names=[name_in], output_names=[name_out],
                          opset_version=17, dynamic_axes=dyn, dynamo=False)
    m = onnx.load(out)
    onnx.checker.check_model(m)
    m.doc_string = "glad-payload %s model from %s (step %s)" % (kind, os.path.basename(os.path.dirname(ckpt)), ck.get("step"))
    onnx.save(m, out)
    sess = ort.InferenceSession(out, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    for shape in shapes:
        x = rng.random(shape, dtype=np.float32)
        with torch.no_grad():
            ref = model(torch.from_numpy(x)).numpy()
        got = sess.run(None, {name_in: x})[0]
        if kind == "det":
            # the peak mask may flip on exact ties; compare where both agree it is (not) a peak
            same = (ref[:, 0] > 0) == (got[:, 0] > 0)
            err = max(np.abs(ref[:, 0] - got[:, 0])[same].max(), np.abs(ref[:, 1:] - got[:, 1:]).max() / max(1.0, np.abs(ref[:, 1:]).max()))
            print("shape=%s max_err=%.2e peak_agree=%.5f" % (shape, err, same.mean()))
            assert err < 1e-3 and same.mean() > 0.999
        else:
            err = np.abs(ref - got).max()
            print("shape=%s max_err=%.2e" % (shape, err))
            assert err < 1e-4
    print("wrote %s (%d bytes)" % (out, os.path.getsize(out)))


if __name__ == "__main__":
    export(*sys.argv[1:4])
