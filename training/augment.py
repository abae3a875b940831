"""Photometric augmentation shared by the detector and classifier training: what a field camera
does to a small target that the Halmstad recordings show too rarely.

Contrast and brightness (exposure), blur (focus, motion), additive sensor noise (a small
sensor at high gain, thermal cameras) and JPEG / H.264-like block artefacts (a compressed
video link). Each is drawn independently per image, so most images carry one or two.
"""

import cv2
import numpy as np

BLUR_P = 0.2
NOISE_P = 0.3
NOISE_STD = (2.0, 8.0)  # grey levels
JPEG_P = 0.3
JPEG_QUALITY = (30, 90)


def photometric(rng: np.random.Generator, image: np.ndarray, jpeg_quality=JPEG_QUALITY) -> np.ndarray:
    """One BGR uint8 image, jittered; same shape and dtype."""
    img = image.astype(np.float32)
    img = (img - 128.0) * rng.uniform(0.7, 1.3) + 128.0 + rng.uniform(-25, 25)
    if rng.random() < BLUR_P:
        img = cv2.GaussianBlur(img, (3, 3), 0)
    if rng.random() < NOISE_P:
        img = img + rng.normal(0.0, rng.uniform(*NOISE_STD), img.shape).astype(np.float32)
    out = np.clip(img, 0, 255).astype(np.uint8)
    if rng.random() < JPEG_P:
        quality = int(rng.integers(jpeg_quality[0], jpeg_quality[1] + 1))
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, quality])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR).reshape(out.shape)
    return out


def drone_alpha(patch: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """A soft matte of the drone in ``patch`` (BGR uint8): how far each pixel of the labelled box
    (``inner``, x0 y0 x1 y1 in patch pixels) stands out from the patch's border colour."""
    border = np.concatenate([patch[0], patch[-1], patch[:, 0], patch[:, -1]]).astype(np.float32)
    diff = np.abs(patch.astype(np.float32) - np.median(border, axis=0)).max(axis=2)
    alpha = np.clip((diff - 6.0) / 30.0, 0.0, 1.0)
    mask = np.zeros_like(alpha)
    x0, y0, x1, y1 = inner
    mask[y0:y1, x0:x1] = 1.0
    alpha *= mask
    if alpha.sum() < 1.0:  # no contrast to go by: the box itself, feathered
        alpha = cv2.GaussianBlur(mask, (3, 3), 0)
    return alpha


def paste_drone(rng: np.random.Generator, background: np.ndarray, source: np.ndarray, box: np.ndarray,
                span_px: float):
    """A real drone (``box`` in ``source``, both from a recording) cut out, shrunk to ``span_px``
    across, recoloured at random (as it is, inverted: a dark drone made light, or a flat grey) and
    pasted at a random place of ``background`` (a real frame without a drone). Returns the image
    and the pasted drone's box, or (background, None) if the box is unusable."""
    h, w = source.shape[:2]
    bx0, by0, bx1, by1 = (int(round(v)) for v in box)
    bx0, by0, bx1, by1 = max(bx0, 0), max(by0, 0), min(bx1, w), min(by1, h)
    bw, bh = bx1 - bx0, by1 - by0
    if bw < 2 or bh < 2:
        return background, None
    m = max(2, int(0.3 * max(bw, bh)))
    px0, py0, px1, py1 = max(bx0 - m, 0), max(by0 - m, 0), min(bx1 + m, w), min(by1 + m, h)
    patch = np.asarray(source[py0:py1, px0:px1])
    alpha = drone_alpha(patch, (bx0 - px0, by0 - py0, bx1 - px0, by1 - py0))
    f = float(span_px) / max(bw, bh)
    pw, ph = max(1, int(round(patch.shape[1] * f))), max(1, int(round(patch.shape[0] * f)))
    interp = cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR
    colour = cv2.resize(patch, (pw, ph), interpolation=interp).astype(np.float32)
    alpha = cv2.resize(alpha, (pw, ph), interpolation=interp)
    kind = rng.random()
    if kind < 0.35:  # a light airframe: the drone's luminance turned over, its hue kept
        colour = 255.0 - colour
    elif kind < 0.6:  # a flat grey or white one
        colour = np.full_like(colour, rng.uniform(20, 240)) + (colour - colour.mean()) * 0.3
    bg = background.copy()
    H, W = bg.shape[:2]
    if pw >= W or ph >= H:
        return background, None
    x, y = int(rng.integers(0, W - pw)), int(rng.integers(0, H - ph))
    roi = bg[y:y + ph, x:x + pw].astype(np.float32)
    a = alpha[..., None]
    bg[y:y + ph, x:x + pw] = np.clip(roi * (1 - a) + colour * a, 0, 255).astype(np.uint8)
    ys, xs = np.nonzero(alpha > 0.2)
    if len(xs) == 0:
        return background, None
    return bg, np.array([x + xs.min(), y + ys.min(), x + xs.max() + 1, y + ys.max() + 1], np.float32)


def thermal_polarity(rng: np.random.Generator, image: np.ndarray, p: float = 0.3) -> np.ndarray:
    """A grey (thermal) image flipped between white-hot and black-hot with probability p;
    colour images are returned as they are."""
    if p > 0 and image.ndim == 3 and rng.random() < p:
        b, g, r = image[..., 0], image[..., 1], image[..., 2]
        if np.array_equal(b, g) and np.array_equal(g, r):
            return 255 - image
    return image
