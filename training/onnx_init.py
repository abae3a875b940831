"""Start fine-tuning from a shipped ONNX detector when its PyTorch checkpoint is gone.

The exported graph has every BatchNorm folded into the convolution before it. Its Conv weights
are copied, in graph order, into a fresh TinyCenterNet (same order as its nn.Conv2d modules);
each BatchNorm is then set so that it passes its input through unchanged both in eval mode
(running mean/var) and, approximately, in train mode (gamma/beta = the channel's measured
batch std/mean on a few training batches), so fine-tuning starts from the shipped behaviour.
"""

import numpy as np
import onnx
import torch
import torch.nn as nn
from onnx import numpy_helper

from training.net import PatchClassifier, TinyCenterNet


def load_onnx_detector(path: str, width: float, calibration_batches) -> TinyCenterNet:
    model = onnx.load(path)
    weights = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    net = TinyCenterNet(width)
    modules = [m for m in net.modules() if isinstance(m, nn.Conv2d)]
    if len(convs) != len(modules):
        raise ValueError("%s: %d Conv nodes, the width-%s network has %d" % (path, len(convs), width, len(modules)))
    biases = {}
    with torch.no_grad():
        for node, conv in zip(convs, modules):
            w = _copy_weight(path, node, conv, weights)
            b = torch.from_numpy(weights[node.input[2]].copy()) if len(node.input) > 2 else torch.zeros(w.shape[0])
            if conv.bias is not None:
                conv.bias.copy_(b)
            else:
                biases[conv] = b  # folded BatchNorm shift: carried by the BatchNorm after this conv
    # each bias-free conv is followed by its BatchNorm (training/net.py cbr)
    pairs = [(c, bn) for c, bn in zip(modules, _batchnorms_after(net, modules)) if bn is not None]
    stats = {bn: [] for _, bn in pairs}
    hooks = [c.register_forward_hook(lambda m, i, o, bn=bn, b=biases[c]: stats[bn].append(
        ((o + b.view(1, -1, 1, 1)).mean((0, 2, 3)), (o + b.view(1, -1, 1, 1)).std((0, 2, 3)))))
        for c, bn in pairs]
    with torch.no_grad():
        for _, bn in pairs:  # identity in eval mode first, so the calibration pass sees the shipped network
            _set_bn(bn, torch.zeros(bn.num_features), torch.ones(bn.num_features), biases[_conv_of(pairs, bn)])
        net.eval()
        for x in calibration_batches:
            net(x)
    for h in hooks:
        h.remove()
    with torch.no_grad():
        for conv, bn in pairs:
            mean = torch.stack([m for m, _ in stats[bn]]).mean(0)
            std = torch.stack([s for _, s in stats[bn]]).mean(0).clamp(min=1e-3)
            # train mode: (y - mean_b) / std_b * std + mean ~= y; eval: running stats give y exactly
            bn.weight.copy_(std)
            bn.bias.copy_(mean)
            bn.running_mean.copy_(mean - biases[conv])
            bn.running_var.copy_(std ** 2 - bn.eps)
    return net


def _copy_weight(path: str, node, layer: nn.Module, weights) -> torch.Tensor:
    """The weight of ONNX ``node`` copied into ``layer`` (shapes must agree); returns it."""
    w = torch.from_numpy(weights[node.input[1]].copy())
    if w.shape != layer.weight.shape:
        raise ValueError("%s: %s %s has shape %s, expected %s"
                         % (path, node.op_type, node.name, tuple(w.shape), tuple(layer.weight.shape)))
    layer.weight.copy_(w)
    return w


def _conv_of(pairs, bn):
    return next(c for c, b in pairs if b is bn)


def _set_bn(bn, mean, var, shift):
    bn.weight.fill_(1.0)
    bn.bias.copy_(shift)
    bn.running_mean.copy_(mean)
    bn.running_var.copy_(var - bn.eps)


def _batchnorms_after(net, convs):
    order = list(net.modules())
    out = []
    for c in convs:
        i = order.index(c)
        nxt = order[i + 1] if i + 1 < len(order) else None
        out.append(nxt if isinstance(nxt, nn.BatchNorm2d) else None)
    return out


def max_abs_diff(net, path: str, x: torch.Tensor) -> float:
    import onnxruntime as ort

    from training.net import DetectorExport

    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    ref = sess.run(None, {sess.get_inputs()[0].name: x.numpy()})[0]
    with torch.no_grad():
        mine = DetectorExport(net.eval())(x).numpy()
    return float(np.abs(mine - ref).max())


def load_onnx_classifier(path: str) -> PatchClassifier:
    """The shipped patch classifier as a PatchClassifier: its two Conv nodes (BatchNorm folded in)
    and three Gemm nodes copied in; each BatchNorm is the identity in eval mode, so fine-tune it with
    the BatchNorms frozen (``freeze_batchnorm``)."""
    model = onnx.load(path)
    weights = {t.name: numpy_helper.to_array(t) for t in model.graph.initializer}
    net = PatchClassifier()
    layers = [m for m in net.modules() if isinstance(m, (nn.Conv2d, nn.Linear))]
    nodes = [n for n in model.graph.node if n.op_type in ("Conv", "Gemm")]
    if [n.op_type for n in nodes] != ["Conv" if isinstance(m, nn.Conv2d) else "Gemm" for m in layers]:
        raise ValueError("%s: layers %s, expected the PatchClassifier's" % (path, [n.op_type for n in nodes]))
    with torch.no_grad():
        for node, layer in zip(nodes, layers):
            _copy_weight(path, node, layer, weights)
            layer.bias.copy_(torch.from_numpy(weights[node.input[2]].copy()))
        for bn in (m for m in net.modules() if isinstance(m, nn.BatchNorm2d)):
            _set_bn(bn, torch.zeros(bn.num_features), torch.ones(bn.num_features), torch.zeros(bn.num_features))
    return net


def freeze_batchnorm(net: nn.Module) -> None:
    """BatchNorms in eval mode with fixed parameters (call after every net.train())."""
    for m in net.modules():
        if isinstance(m, nn.BatchNorm2d):
            m.eval()
            m.weight.requires_grad_(False)
            m.bias.requires_grad_(False)
