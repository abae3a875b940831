"""The networks: a tiny CenterNet-style detector (stride 4) and the paper's shallow 32x32 classifier.

Detector ONNX contract (what payload.detect.appearance decodes):
  input  'images' [N, 3, H, W] float32, RGB in [0, 1], H and W multiples of 32 (dynamic);
  output 'maps'   [N, 5, H/4, W/4]: 0 = centre score in [0, 1], already reduced to local
          maxima (3x3), 1-2 = sub-cell centre offset (cells), 3-4 = box width, height (input px).
Classifier ONNX contract: input 'patches' [N, 3, 32, 32] float32 RGB [0, 1];
  output 'prob' [N, 2] softmax, column 1 = drone.
"""

import os

import torch
import torch.nn as nn
import torch.nn.functional as F

STRIDE = 4


def cbr(cin, cout, k=3, s=1, groups=1):
    return nn.Sequential(
        nn.Conv2d(cin, cout, k, s, k // 2, groups=groups, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


def dws(cin, cout, s=1):
    """Depthwise-separable 3x3 block."""
    return nn.Sequential(cbr(cin, cin, 3, s, groups=cin), cbr(cin, cout, 1))


class TinyCenterNet(nn.Module):
    def __init__(self, width=1.0):
        super().__init__()
        c4, c8, c16, ch = int(32 * width), int(64 * width), int(128 * width), int(32 * width)
        self.stem = nn.Sequential(cbr(3, 16, 3, 2), dws(16, c4, 2), dws(c4, c4), dws(c4, c4))
        self.s8 = nn.Sequential(dws(c4, c8, 2), dws(c8, c8), dws(c8, c8))
        self.s16 = nn.Sequential(dws(c8, c16, 2), dws(c16, c16), dws(c16, c16), dws(c16, c16))
        self.lat16 = cbr(c16, c8, 1)
        self.fuse8 = dws(c8, c8)
        self.lat8 = cbr(c8, c4, 1)
        self.fuse4 = dws(c4, ch)
        self.head = dws(ch, ch)
        self.out = nn.Conv2d(ch, 5, 1)
        nn.init.constant_(self.out.bias, 0.0)
        with torch.no_grad():
            self.out.bias[0] = -4.6  # prior: centres are rare (focal-loss init)

    def forward(self, x):
        f4 = self.stem(x)
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        p8 = self.fuse8(f8 + F.interpolate(self.lat16(f16), scale_factor=2.0, mode="nearest"))
        p4 = self.fuse4(f4 + F.interpolate(self.lat8(p8), scale_factor=2.0, mode="nearest"))
        return self.out(self.head(p4))  # raw: logit, offset xy, log(w/4), log(h/4)


class DetectorExport(nn.Module):
    """The network plus the decoding that belongs in the graph (sigmoid, 3x3 peak, exp sizes)."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, images):
        raw = self.net(images)
        score = torch.sigmoid(raw[:, 0:1])
        peak = score * (F.max_pool2d(score, 3, 1, 1) == score).float()
        offset = raw[:, 1:3]
        size = torch.exp(raw[:, 3:5].clamp(-4.0, 6.0)) * STRIDE
        return torch.cat([peak, offset, size], 1)


class PatchClassifier(nn.Module):
    """The paper's shallow CNN on 32x32 patches: two 5x5 conv + pool, FC 120-84-2."""

    def __init__(self):
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 16, 5), nn.BatchNorm2d(16), nn.ReLU(inplace=True), nn.MaxPool2d(2),
            nn.Conv2d(16, 32, 5), nn.BatchNorm2d(32), nn.ReLU(inplace=True), nn.MaxPool2d(2),
        )
        self.fc = nn.Sequential(
            nn.Flatten(), nn.Linear(32 * 5 * 5, 120), nn.ReLU(inplace=True), nn.Dropout(0.2),
            nn.Linear(120, 84), nn.ReLU(inplace=True), nn.Linear(84, 2),
        )

    def forward(self, x):
        return self.fc(self.features(x))


class ClassifierExport(nn.Module):
    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, patches):
        return torch.softmax(self.net(patches), dim=1)


def count_params(m):
    return sum(p.numel() for p in m.parameters())


def save_checkpoint(path: str, net: nn.Module, opt: torch.optim.Optimizer, step: int, **extra) -> None:
    """Model, optimizer and step to ``path``, replaced at once: a run killed while writing keeps
    its previous checkpoint to resume from."""
    torch.save({"model": net.state_dict(), "opt": opt.state_dict(), "step": step, **extra}, path + ".tmp")
    os.replace(path + ".tmp", path)


def load_weights(path: str, net: nn.Module, device: torch.device) -> dict:
    """The network weights of a checkpoint written by save_checkpoint into ``net`` (``--init``);
    returns the whole checkpoint."""
    ck = torch.load(path, weights_only=False, map_location=device)
    net.load_state_dict(ck["model"])
    return ck


def resume(path: str, net: nn.Module, opt: torch.optim.Optimizer, device: torch.device) -> int:
    """Load a checkpoint written by save_checkpoint into ``net`` and ``opt``; returns its step."""
    ck = load_weights(path, net, device)
    opt.load_state_dict(ck["opt"])
    print("resumed %s step=%d" % (path, ck["step"]), flush=True)
    return int(ck["step"])


def training_device() -> torch.device:
    """The CUDA GPU when there is one (training runs there), else the CPU."""
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    print("training on %s" % (torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"), flush=True)
    return device
