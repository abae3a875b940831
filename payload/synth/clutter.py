"""Near, non-planar clutter: tree tops, poles and building corners a few tens of metres away.

They stand on a ground plane below the moving camera and are projected with the full 3-D
camera (rotation *and* translation), so they slide against the distant backdrop (parallax) —
the motion a ground-homography cannot explain. They are drawn in front of the target and so
occlude it now and then.
"""

import math
from dataclasses import dataclass
from typing import List, Optional

import cv2
import numpy as np

from payload.synth.camera import CameraPose, Lens

#: Ground level for the clutter, metres below the camera's start (world y is down).
CLUTTER_GROUND_Y_M = 25.0


@dataclass
class _Item:
    polys: List[np.ndarray]  # 3-D world polygons (N, 3), drawn in order
    colours: List[tuple]


@dataclass(frozen=True)
class Shape:
    """One projected polygon: integer frame pixels (N, 2) and a BGR colour."""

    points_px: np.ndarray
    colour: tuple


def _tree(rng: np.random.Generator, base: np.ndarray) -> _Item:
    height = rng.uniform(8, 18)
    radius = rng.uniform(2.0, 5.0)
    top = base + [0, -height, 0]
    n = 24
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    r = radius * (1 + 0.18 * rng.standard_normal(n)).clip(0.6, 1.4)
    crown = np.stack([top[0] + r * np.cos(t), top[1] + 0.8 * r * np.sin(t), np.full(n, top[2])], 1)
    trunk_w = radius * 0.08
    trunk = np.array([[base[0] - trunk_w, base[1], base[2]], [base[0] + trunk_w, base[1], base[2]],
                      [top[0] + trunk_w, top[1], top[2]], [top[0] - trunk_w, top[1], top[2]]])
    green = np.array([40, 75, 45]) * rng.uniform(0.6, 1.2)
    polys, colours = [trunk, crown], [(40, 50, 60), tuple(green.tolist())]
    for _ in range(4):  # lighter and darker clumps of leaves
        c = top + [rng.uniform(-0.5, 0.5) * radius, rng.uniform(-0.5, 0.4) * radius, -0.01]
        rr = radius * rng.uniform(0.25, 0.45) * (1 + 0.2 * rng.standard_normal(10)).clip(0.6, 1.4)
        tt = np.linspace(0, 2 * math.pi, 10, endpoint=False)
        polys.append(np.stack([c[0] + rr * np.cos(tt), c[1] + rr * np.sin(tt), np.full(10, c[2])], 1))
        colours.append(tuple((green * rng.uniform(0.7, 1.35)).tolist()))
    return _Item(polys, colours)


def _pole(rng: np.random.Generator, base: np.ndarray) -> _Item:
    height = rng.uniform(9, 22)
    w = rng.uniform(0.12, 0.25)
    top = base + [0, -height, 0]
    pole = np.array([base + [-w, 0, 0], base + [w, 0, 0], top + [w, 0, 0], top + [-w, 0, 0]])
    arm = np.array([top + [-1.2, 0.6, 0], top + [1.2, 0.6, 0], top + [1.2, 0.9, 0], top + [-1.2, 0.9, 0]])
    shade = tuple(float(c) for c in np.array([55, 60, 70]) * rng.uniform(0.6, 1.4))
    return _Item([pole, arm], [shade, shade])


def _building(rng: np.random.Generator, base: np.ndarray) -> _Item:
    height = rng.uniform(5, 14)
    lx, lz = rng.uniform(6, 20, 2)
    b = base
    front = np.array([b, b + [lx, 0, 0], b + [lx, -height, 0], b + [0, -height, 0]])
    side = np.array([b, b + [0, 0, lz], b + [0, -height, lz], b + [0, -height, 0]])
    roof = np.array([b + [0, -height, 0], b + [lx, -height, 0], b + [lx, -height, lz], b + [0, -height, lz]])
    wall = np.array([[150, 160, 170], [120, 140, 170], [140, 140, 140]][int(rng.integers(3))]) * rng.uniform(0.7, 1.1)
    return _Item([side, front, roof], [tuple((wall * 0.75).tolist()), tuple(wall.tolist()), (70, 70, 110)])


class Clutter:
    """``count`` near objects kept around the camera; those left behind are placed anew ahead.

    ``buildings=False`` keeps to trees and poles (over a real video, whose ground level is
    unknown, a building would float; a tree or pole usually reaches below the frame).
    """

    def __init__(self, rng: np.random.Generator, lens: Lens, count: int, buildings: bool = True):
        self.rng, self.lens, self.count, self.buildings = rng, lens, count, buildings
        self.items: List[Optional[_Item]] = [None] * count
        self.hidden_frames = [0] * count

    def _spawn(self, pose: CameraPose, in_view: bool) -> _Item:
        rng = self.rng
        half = math.atan(self.lens.width / 2 / (self.lens.focal_px * pose.zoom))
        if in_view:
            yaw = pose.yaw_rad + rng.uniform(-1.0, 1.0) * half
        else:  # just outside the view, so that it drifts in rather than pops up
            yaw = pose.yaw_rad + rng.choice([-1.0, 1.0]) * half * rng.uniform(1.05, 1.6)
        dist = rng.uniform(30, 160)
        base = pose.position_m + np.array([dist * math.sin(yaw), 0.0, dist * math.cos(yaw)])
        base[1] = CLUTTER_GROUND_Y_M
        kind = rng.random()
        if kind < 0.55:
            return _tree(rng, base)
        if kind < 0.85 or not self.buildings:
            return _pole(rng, base)
        base = pose.position_m + (base - pose.position_m) * 1.8  # buildings stand farther off
        base[1] = CLUTTER_GROUND_Y_M
        return _building(rng, base)

    def shapes(self, pose: CameraPose, first: bool) -> List[Shape]:
        """Advance (respawn what is behind or long out of view) and project for this pose."""
        w, h = self.lens.width, self.lens.height
        out = []
        for i in range(self.count):
            if self.items[i] is None:
                self.items[i] = self._spawn(pose, in_view=first)
            item = self.items[i]
            projected = []
            visible = False
            for poly, colour in zip(item.polys, item.colours):
                uv, depth = self.lens.project(pose, poly)
                if (depth < 1.0).any():
                    projected = []
                    visible = False
                    break
                projected.append(Shape(np.round(uv).astype(np.int32), colour))
                x0, y0 = uv.min(axis=0)
                x1, y1 = uv.max(axis=0)
                visible |= bool(x1 >= 0 and y1 >= 0 and x0 < w and y0 < h)
            self.hidden_frames[i] = 0 if visible else self.hidden_frames[i] + 1
            if self.hidden_frames[i] > 45 or (not projected and not first):
                self.items[i] = None  # gone: a new one is placed next frame
                self.hidden_frames[i] = 0
            if visible:
                out.extend(projected)
        return out


def draw(image: np.ndarray, shapes: List[Shape]) -> None:
    # Hard edges (no anti-aliasing): the occlusion mask for the label must match the pixels.
    for s in shapes:
        cv2.fillPoly(image, [s.points_px], s.colour, cv2.LINE_8)


def mask_in(shapes: List[Shape], x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """uint8 (h, w) mask of the shapes inside the window at (x0, y0): 1 where they cover."""
    mask = np.zeros((h, w), np.uint8)
    for s in shapes:
        pts = s.points_px - np.array([x0, y0], np.int32)
        cv2.fillPoly(mask, [pts], 1, cv2.LINE_8)
    return mask
