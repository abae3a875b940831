"""The 32x32 patch around a candidate box: one definition shared by the classifier and its training.

A patch is a square centred on the box, ``context`` times its longer side (at least
``min_side_px``), resampled to ``patch_px`` square. Pixels outside the image repeat the
border so a candidate at the frame edge still gets a full patch.
"""

import cv2
import numpy as np

PATCH_PX = 32
CONTEXT = 1.5  # the box plus a margin: the classifier sees the drone against its background
MIN_SIDE_PX = 12.0


def patch_squares(xyxy: np.ndarray, context: float = CONTEXT, min_side_px: float = MIN_SIDE_PX) -> np.ndarray:
    """Centre (cx, cy) and side of the square patch for each box: [N, 3] float32."""
    xyxy = np.asarray(xyxy, np.float32).reshape(-1, 4)
    center = (xyxy[:, :2] + xyxy[:, 2:]) / 2.0
    side = np.maximum((xyxy[:, 2:] - xyxy[:, :2]).max(axis=1) * context, min_side_px)
    return np.concatenate([center, side[:, None]], axis=1)


def crop_patches(
    image_bgr: np.ndarray,
    xyxy: np.ndarray,
    patch_px: int = PATCH_PX,
    context: float = CONTEXT,
    min_side_px: float = MIN_SIDE_PX,
) -> np.ndarray:
    """BGR uint8 patches [N, patch_px, patch_px, 3], one per box (full-frame ``xyxy``)."""
    squares = patch_squares(xyxy, context, min_side_px)
    out = np.empty((len(squares), patch_px, patch_px, 3), np.uint8)
    h, w = image_bgr.shape[:2]
    for i, (cx, cy, side) in enumerate(squares):
        half = side / 2.0
        x1, y1 = int(np.floor(cx - half)), int(np.floor(cy - half))
        x2, y2 = int(np.ceil(cx + half)), int(np.ceil(cy + half))
        pad = (max(0, -y1), max(0, y2 - h), max(0, -x1), max(0, x2 - w))
        cx1, cy1 = min(max(0, x1), w), min(max(0, y1), h)
        cx2, cy2 = max(min(w, x2), cx1), max(min(h, y2), cy1)
        crop = image_bgr[cy1:cy2, cx1:cx2]
        if crop.size == 0:  # the square lies wholly outside the image
            out[i] = 114
            continue
        if any(pad):
            crop = cv2.copyMakeBorder(crop, pad[0], pad[1], pad[2], pad[3], cv2.BORDER_REPLICATE)
        interp = cv2.INTER_AREA if crop.shape[0] > patch_px else cv2.INTER_LINEAR
        out[i] = cv2.resize(crop, (patch_px, patch_px), interpolation=interp)
    return out


def patches_to_input(patches_bgr: np.ndarray) -> np.ndarray:
    """Network input [N, 3, H, W] float32: RGB scaled to [0, 1], as in training."""
    x = np.ascontiguousarray(patches_bgr[..., ::-1].transpose(0, 3, 1, 2), dtype=np.float32)
    return x * np.float32(1.0 / 255.0)

