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


def _dark_drone_crop(rng):
    """A 96x96 sky-coloured crop with a dark 30x20 drone-like blob (body and arms) at a known box."""
    crop = np.full((96, 96, 3), (200, 160, 120), np.uint8)
    crop = np.clip(crop + rng.normal(0, 2, crop.shape), 0, 255).astype(np.uint8)
    cv2.rectangle(crop, (40, 40), (60, 52), (30, 30, 30), -1)
    cv2.line(crop, (30, 38), (70, 58), (35, 35, 35), 2)
    cv2.line(crop, (30, 58), (70, 38), (35, 35, 35), 2)
    return crop, np.array([29.0, 37.0, 71.0, 59.0], np.float32)


def test_paste_drone_shrinks_it_to_the_size_asked_and_boxes_it():
    rng = np.random.default_rng(1)
    source, box = _dark_drone_crop(rng)
    background = np.full((128, 128, 3), 90, np.uint8)
    spans = []
    for _ in range(60):
        image, pasted = augment.paste_drone(rng, background, source, box, 6.0)
        assert image.shape == background.shape and image.dtype == np.uint8
        assert pasted is not None
        x0, y0, x1, y1 = pasted.astype(int)
        changed = np.any(image != background, axis=2)
        # the drone is inside its box and the box holds changed pixels; nothing changed far from it
        assert changed[y0:y1, x0:x1].any()
        outside = changed.copy()
        outside[max(y0 - 2, 0):y1 + 2, max(x0 - 2, 0):x1 + 2] = False
        assert not outside.any()
        spans.append(max(x1 - x0, y1 - y0))
    assert 4 <= np.median(spans) <= 7
    assert np.array_equal(background, np.full((128, 128, 3), 90, np.uint8))  # not drawn in place


def test_paste_drone_makes_light_drones_too():
    """Some pasted drones are lighter than the sky they came from (a dark drone turned light)."""
    rng = np.random.default_rng(2)
    source, box = _dark_drone_crop(rng)
    background = np.full((64, 64, 3), 128, np.uint8)
    lighter = darker = 0
    for _ in range(80):
        image, pasted = augment.paste_drone(rng, background, source, box, 8.0)
        x0, y0, x1, y1 = pasted.astype(int)
        mean = float(image[y0:y1, x0:x1].mean())
        lighter += mean > 132
        darker += mean < 124
    assert lighter >= 10 and darker >= 10


def test_paste_drone_refuses_a_degenerate_box():
    rng = np.random.default_rng(3)
    source, _ = _dark_drone_crop(rng)
    background = np.zeros((32, 32, 3), np.uint8)
    image, pasted = augment.paste_drone(rng, background, source, np.array([10, 10, 11, 40], np.float32), 5.0)
    assert pasted is None and image is background


def test_thermal_polarity_flips_grey_images_only():
    rng = np.random.default_rng(4)
    grey = np.repeat(np.arange(64, dtype=np.uint8).reshape(8, 8, 1), 3, axis=2)
    colour = grey.copy()
    colour[..., 2] = 255
    flipped = sum(np.array_equal(augment.thermal_polarity(rng, grey, 0.5), 255 - grey) for _ in range(400))
    assert 160 < flipped < 240
    assert all(np.array_equal(augment.thermal_polarity(rng, colour, 1.0), colour) for _ in range(20))
    assert np.array_equal(augment.thermal_polarity(rng, grey, 0.0), grey)
