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
