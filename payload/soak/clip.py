"""The soak's camera: a synthetic clip as a folder of JPEGs that loops without a jump, and the
corruption of a few of its frames."""

import os
from typing import Dict, List

import cv2

from payload.errors import SourceError
from payload.synth.scene import Scene


def render_folder(folder: str, seed: int, width: int, height: int, fps: float, frames: int) -> List[str]:
    """Render ``frames`` frames of the scene, then the same backwards (ends not repeated), as
    numbered JPEGs: a looping folder source then sees a camera that never jumps. Returns the paths."""
    os.makedirs(folder, exist_ok=True)
    scene = Scene(seed=seed, width=width, height=height, fps=fps, frames=frames, target_px=(16.0, 48.0))
    encoded = []
    for frame in scene:
        ok, data = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise SourceError("soak: cannot encode a JPEG of %dx%d" % (width, height))
        encoded.append(data.tobytes())
    order = encoded + encoded[-2:0:-1]
    paths = []
    for i, data in enumerate(order):
        path = os.path.join(folder, "frame_%05d.jpg" % i)
        _replace(path, data)
        paths.append(path)
    return paths


def corrupt(paths: List[str]) -> Dict[str, bytes]:
    """Make the given frames unreadable (zero bytes, truncated, random bytes, in turn); returns
    their original bytes for restore()."""
    originals = {}
    for i, path in enumerate(paths):
        with open(path, "rb") as fh:
            data = fh.read()
        originals[path] = data
        kind = i % 3
        bad = b"" if kind == 0 else data[: len(data) // 3] if kind == 1 else os.urandom(len(data))
        _replace(path, bad)
    return originals


def restore(originals: Dict[str, bytes]) -> None:
    for path, data in originals.items():
        _replace(path, data)


def _replace(path: str, data: bytes) -> None:
    """Write atomically: the service never reads a half-written file that is not meant to be one."""
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)
