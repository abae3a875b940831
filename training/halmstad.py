"""Reading the Halmstad clips: splits, per-frame boxes (0-based xyxy), decoded frames."""

import csv
import json
import os
from collections import defaultdict
from typing import Dict, Iterator, List, Tuple

import cv2
import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HALMSTAD = os.environ.get("HALMSTAD_DIR", os.path.join(os.path.dirname(REPO), "shared", "data", "halmstad"))


def splits(root: str = HALMSTAD) -> Dict[str, List[str]]:
    with open(os.path.join(root, "splits.json")) as fh:
        return json.load(fh)


def labels(clip: str, root: str = HALMSTAD) -> Dict[int, List[Tuple[str, np.ndarray]]]:
    """frame index -> [(class, xyxy)], xyxy 0-based pixels (the CSV's x, y are 1-based)."""
    out: Dict[int, List[Tuple[str, np.ndarray]]] = defaultdict(list)
    with open(os.path.join(root, "labels", clip + ".csv")) as fh:
        for row in csv.DictReader(fh):
            x, y, w, h = (float(row[k]) for k in ("x", "y", "w", "h"))
            xyxy = np.array([x - 1, y - 1, x - 1 + w, y - 1 + h], np.float32)
            out[int(row["frame"])].append((row["class"], xyxy))
    return out


def frames(clip: str, root: str = HALMSTAD) -> Iterator[Tuple[int, np.ndarray]]:
    folder = "ir" if clip.startswith("IR_") else "visible"
    cap = cv2.VideoCapture(os.path.join(root, folder, clip + ".mp4"))
    i = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        yield i, img
        i += 1
    cap.release()
