"""The global stage's native-resolution scan: a few detector-sized tiles of the frame per frame, in turn.

GAD sees the whole frame down-scaled to its input (a 1080p frame to a third), where a 4-10 px
drone is a pixel or two and gone; GMD finds such a drone only while it moves against the
background. A small drone that hovers, or flies with the background, is then never acquired.
The scan runs the local (native-resolution) appearance detector on ``tiles_per_frame`` of the
overlapping tiles that cover the frame (payload.detect.tiled), the next ones each global frame,
so the whole frame is seen at native resolution every ceil(K / tiles_per_frame) global frames
(1080p with 320 px tiles: 32 tiles, 16 scans at 2 a frame) for two local detector runs a scan.
Frames the global input already holds at nearly native resolution are not scanned.
"""

from typing import Dict, Tuple

import numpy as np

from payload.boxes import tiles_xyxy


class NativeScan:
    """Which tiles of the frame to search this frame: the next few, row by row, round and round."""

    def __init__(self) -> None:
        self._next = 0
        self._tiles: Dict[Tuple[Tuple[int, int], Tuple[int, int]], np.ndarray] = {}

    def next_tiles(self, size_wh: Tuple[int, int], tile_wh: Tuple[int, int], tiles_per_frame: int) -> np.ndarray:
        """(k, 4) int ``xyxy``: the next ``tiles_per_frame`` tiles to search; none when that is 0."""
        key = ((int(size_wh[0]), int(size_wh[1])), (int(tile_wh[0]), int(tile_wh[1])))
        tiles = self._tiles.get(key)
        if tiles is None:
            tiles = self._tiles[key] = tiles_xyxy(*key)
        k = min(int(tiles_per_frame), len(tiles))
        if k <= 0:
            return tiles[:0]
        index = (self._next + np.arange(k)) % len(tiles)
        self._next = int(index[-1] + 1) % len(tiles)
        return tiles[index]

    def reset(self) -> None:
        self._next = 0
