"""Box maths on ``xyxy`` arrays (pixels, x1 y1 x2 y2): overlap, suppression, merging, tiling.

One place for what the detectors, the evaluation and the baselines all do with boxes:
IoU (the evaluation's matching), class-agnostic NMS (the appearance detectors, the tiled
baseline), merging nearby boxes (the motion detector's blobs), and the tiles that cover a
frame at the detector's input size (the native-resolution scan, the tiled baseline).
"""

from typing import List, Tuple

import cv2
import numpy as np

#: Default share of a tile that overlaps its neighbour (SAHI's default is 0.2).
DEFAULT_OVERLAP = 0.2


def tile_starts(length_px: int, tile_px: int, overlap: float) -> List[int]:
    """Start offsets of tiles of ``tile_px`` along ``length_px`` with at least ``overlap`` shared.

    The last tile is aligned to the far edge, so the tiles cover the whole length; a length
    not longer than a tile gives one tile at 0.
    """
    if not 0.0 <= overlap < 1.0:
        raise ValueError("tile overlap %r: expected 0 <= overlap < 1" % (overlap,))
    if tile_px <= 0:
        raise ValueError("tile size %r px: expected > 0" % (tile_px,))
    if length_px <= tile_px:
        return [0]
    stride = max(1, int(tile_px * (1.0 - overlap)))
    starts = list(range(0, length_px - tile_px, stride))
    starts.append(length_px - tile_px)
    return sorted(set(starts))


def tiles_xyxy(size_wh: Tuple[int, int], tile_wh: Tuple[int, int], overlap: float = DEFAULT_OVERLAP) -> np.ndarray:
    """Tiles covering an image of ``size_wh``: (K, 4) int ``xyxy``, row by row."""
    w, h = int(size_wh[0]), int(size_wh[1])
    tw, th = min(int(tile_wh[0]), w), min(int(tile_wh[1]), h)
    tiles = [(x, y, x + tw, y + th) for y in tile_starts(h, th, overlap) for x in tile_starts(w, tw, overlap)]
    return np.array(tiles, np.int64).reshape(-1, 4)


def iou_matrix(a_xyxy: np.ndarray, b_xyxy: np.ndarray) -> np.ndarray:
    """(n, m) IoU between two sets of ``xyxy`` boxes (areas as continuous w*h, no +1)."""
    a = np.asarray(a_xyxy, np.float64).reshape(-1, 4)
    b = np.asarray(b_xyxy, np.float64).reshape(-1, 4)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0.0, None), axis=2)
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0.0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0.0, None), axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def nms(xyxy: np.ndarray, score: np.ndarray, iou: float) -> np.ndarray:
    """Indices kept by class-agnostic non-maximum suppression, highest score first."""
    if len(score) == 0:
        return np.zeros((0,), np.int64)
    xywh = np.concatenate([xyxy[:, :2], xyxy[:, 2:] - xyxy[:, :2]], axis=1)
    keep = cv2.dnn.NMSBoxes(xywh.tolist(), score.tolist(), 0.0, float(iou))
    keep = np.asarray(keep, np.int64).reshape(-1)
    return keep[np.argsort(-score[keep], kind="stable")]


def merge_boxes(xyxy: np.ndarray, distance_px: float) -> np.ndarray:
    """Union of boxes whose gap is smaller than ``distance_px``, transitively.

    The gap is the Euclidean distance between the rectangles' nearest edges (0 when they touch
    or overlap), not between their centres: a long blob split in two is merged however long it
    is. Merging repeats until no two merged boxes are closer than the distance.
    """
    boxes = np.asarray(xyxy, np.float32).reshape(-1, 4)
    while len(boxes) > 1:
        gap_x = np.maximum(
            0.0, np.maximum(boxes[:, None, 0] - boxes[None, :, 2], boxes[None, :, 0] - boxes[:, None, 2])
        )
        gap_y = np.maximum(
            0.0, np.maximum(boxes[:, None, 1] - boxes[None, :, 3], boxes[None, :, 1] - boxes[:, None, 3])
        )
        near = np.hypot(gap_x, gap_y) < distance_px
        if near.sum() == len(boxes):  # only the diagonal
            break
        # Connected components of the "near" graph by label propagation (N <= max_blobs).
        labels = np.arange(len(boxes))
        while True:
            spread = np.where(near, labels[None, :], len(boxes)).min(axis=1)
            if np.array_equal(spread, labels):
                break
            labels = spread
        groups = np.unique(labels)
        boxes = np.array(
            [
                np.concatenate([boxes[labels == g, :2].min(axis=0), boxes[labels == g, 2:].max(axis=0)])
                for g in groups
            ],
            np.float32,
        )
    return boxes
