"""training/augment.py: the photometric jitter the detector and classifier are trained with."""

import cv2
import numpy as np

from training import augment


def _no_extras(monkeypatch, **on):
    for name in ("BLUR_P", "NOISE_P", "JPEG_P"):
        monkeypatch.setattr(augment, name, on.get(name, 0.0))


def test_shape_dtype_and_seeded(rng):
    image = rng.integers(0, 256, (32, 40, 3), dtype=np.uint8)
    a = [augment.photometric(np.random.default_rng(7), image) for _ in range(2)]
    assert a[0].shape == image.shape and a[0].dtype == np.uint8
    assert np.array_equal(a[0], a[1])


def test_noise_drawn_at_its_rate(monkeypatch):
    """A flat grey image stays flat under contrast/brightness and blur; only the noise roughens it."""
    _no_extras(monkeypatch, BLUR_P=augment.BLUR_P, NOISE_P=augment.NOISE_P)
    rng = np.random.default_rng(0)
    flat = np.full((24, 24, 3), 100, np.uint8)
    noisy = np.mean([augment.photometric(rng, flat).std() > 0.5 for _ in range(600)])
    assert abs(noisy - augment.NOISE_P) < 0.06


def test_jpeg_removes_fine_detail(monkeypatch):
    """Pixel noise is what JPEG quantises away first: the Laplacian energy drops."""
    image = np.random.default_rng(1).integers(60, 196, (64, 64, 3), dtype=np.uint8)

    def detail(jpeg_p):
        _no_extras(monkeypatch, JPEG_P=jpeg_p)
        out = augment.photometric(np.random.default_rng(3), image, jpeg_quality=(40, 40))
        return float(np.abs(cv2.Laplacian(out.astype(np.float32), cv2.CV_32F)).mean())

    assert detail(1.0) < 0.7 * detail(0.0)
