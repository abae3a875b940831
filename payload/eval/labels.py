"""Ground-truth boxes from the label formats we meet, as frame -> (k, 4) float32 ``xyxy``.

Boxes come out in 0-based full-frame pixels with exclusive right/bottom edges (as in
payload.types). A frame the annotation covers but that holds no counted object maps to an
empty (0, 4) array, so the keys tell which frames the labels know about; a frame absent
from the result has no object either.

Formats (``fmt``):
- ``halmstad``: CSV ``frame,class,x,y,w,h``; frame 0-based, x,y 1-based (MATLAB) -> minus 1;
  only ``classes`` count (a V_BIRD clip has no ground truth).
- ``voc``: a folder of Pascal VOC XML files, one per frame, frame number = the last number
  in the file name, 1-based as ARD-MAV's video2img.py writes them (``phantom16_0001.xml`` is
  frame 0); VOC corners are 1-based inclusive -> x1 = xmin - 1, x2 = xmax.
- ``mot``: MOTChallenge ``gt.txt``: ``frame,id,x,y,w,h[,conf,...]``, frame 1-based; rows with
  conf 0 are "ignore" rows and do not count; x,y used as written.
- ``txt``: one ``x y w h`` line per frame (spaces or commas), frame = line number - 1; an
  empty line, ``0 0 0 0`` or NaN means no target.
"""

import csv
import logging
import math
import os
import re
import xml.etree.ElementTree as ET
from typing import Dict, Iterable, List, Optional, Sequence

import numpy as np

from payload.errors import DataError
from payload.records import parse_finite

log = logging.getLogger(__name__)

FORMATS = ("halmstad", "voc", "mot", "txt")
_NUMBER_IN_NAME = re.compile(r"(\d+)(?!.*\d)")


def _empty() -> np.ndarray:
    return np.zeros((0, 4), np.float32)


def _read_text(path: str) -> str:
    try:
        with open(path, encoding="utf-8-sig") as handle:
            return handle.read()
    except UnicodeDecodeError:
        raise DataError("%s: not a UTF-8 text file" % path) from None
    except OSError as exc:
        raise DataError("%s: cannot read labels: %s" % (path, exc.strerror or exc)) from None


def _frame(path: str, line: int, text: str, first: int) -> int:
    try:
        frame = int(float(text))
    except ValueError:
        raise DataError("%s:%d: frame=%r is not an integer" % (path, line, text)) from None
    if frame < first:
        raise DataError("%s:%d: frame=%s, expected >= %d" % (path, line, text, first))
    return frame - first


def _size_ok(path: str, line: int, w: float, h: float) -> None:
    if w < 0 or h < 0:
        raise DataError("%s:%d: w=%g, h=%g must be >= 0" % (path, line, w, h))


def _collect(boxes: Dict[int, List[List[float]]]) -> Dict[int, np.ndarray]:
    return {
        frame: (np.array(rows, np.float32).reshape(-1, 4) if rows else _empty())
        for frame, rows in sorted(boxes.items())
    }


def _warn_no_class(path: str, seen: Iterable[str], classes: Optional[Sequence[str]], level: int) -> None:
    seen = sorted(set(seen))
    if seen and classes is not None:
        log.log(level,
            "labels path=%s counted_classes=%s seen_classes=%s: no object of a counted class, clip has no ground truth",
            path, ",".join(classes), ",".join(seen),
        )


def _load_halmstad(path: str, classes: Optional[Sequence[str]]) -> Dict[int, np.ndarray]:
    text = _read_text(path)
    reader = csv.reader(text.splitlines())
    header = [c.strip().lower() for c in next(reader, [])]
    expected = ["frame", "class", "x", "y", "w", "h"]
    if header != expected:
        raise DataError("%s:1: header %s, expected %s" % (path, ",".join(header) or "<empty file>", ",".join(expected)))
    wanted = None if classes is None else {c.upper() for c in classes}
    boxes: Dict[int, List[List[float]]] = {}
    seen = []
    for line, row in enumerate(reader, start=2):
        if not row or not "".join(row).strip():
            continue
        if len(row) != 6:
            raise DataError("%s:%d: %d fields, expected 6 (frame,class,x,y,w,h)" % (path, line, len(row)))
        frame = _frame(path, line, row[0], first=0)
        name = row[1].strip().upper()
        x, y, w, h = (parse_finite(path, line, n, t) for n, t in zip("xywh", row[2:]))
        _size_ok(path, line, w, h)
        rows = boxes.setdefault(frame, [])
        seen.append(name)
        if wanted is None or name in wanted:
            rows.append([x - 1.0, y - 1.0, x - 1.0 + w, y - 1.0 + h])
    if not any(boxes.values()):
        _warn_no_class(path, seen, classes, logging.INFO)  # a negative clip (birds, aircraft)
    return _collect(boxes)


def _load_voc(folder: str, classes: Optional[Sequence[str]]) -> Dict[int, np.ndarray]:
    try:
        names = sorted(n for n in os.listdir(folder) if n.lower().endswith(".xml"))
    except OSError as exc:
        raise DataError("%s: cannot list label folder: %s" % (folder, exc.strerror or exc)) from None
    if not names:
        raise DataError("%s: no .xml files (expected Pascal VOC, one file per frame)" % folder)
    wanted = None if classes is None else {c.upper() for c in classes}
    boxes: Dict[int, List[List[float]]] = {}
    seen = []
    for name in names:
        path = os.path.join(folder, name)
        match = _NUMBER_IN_NAME.search(os.path.splitext(name)[0])
        if match is None or int(match.group(1)) < 1:
            raise DataError("%s: no 1-based frame number in the file name (e.g. clip_0001.xml)" % path)
        frame = int(match.group(1)) - 1
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as exc:
            raise DataError("%s:%d: not valid XML: %s" % (path, exc.position[0], exc.msg)) from None
        except OSError as exc:
            raise DataError("%s: cannot read labels: %s" % (path, exc.strerror or exc)) from None
        rows = boxes.setdefault(frame, [])
        for obj in root.iter("object"):
            label = (obj.findtext("name") or "").strip().upper()
            seen.append(label)
            if wanted is not None and label not in wanted:
                continue
            box = obj.find("bndbox")
            if box is None:
                raise DataError("%s: object %r has no <bndbox>" % (path, label))
            corners = []
            for key in ("xmin", "ymin", "xmax", "ymax"):
                text = box.findtext(key)
                if text is None:
                    raise DataError("%s: object %r: <bndbox> has no <%s>" % (path, label, key))
                try:
                    corners.append(float(text))
                except ValueError:
                    corners.append(math.nan)
                if not math.isfinite(corners[-1]):
                    raise DataError("%s: object %r: <%s>%s</%s> is not a finite number" % (path, label, key, text.strip(), key))
            xmin, ymin, xmax, ymax = corners
            if xmax < xmin or ymax < ymin:
                raise DataError("%s: object %r: xmax/ymax (%g, %g) below xmin/ymin (%g, %g)" % (path, label, xmax, ymax, xmin, ymin))
            rows.append([xmin - 1.0, ymin - 1.0, xmax, ymax])
    if not any(boxes.values()):
        _warn_no_class(folder, seen, classes, logging.WARNING)  # likely a class-name mismatch
    return _collect(boxes)


def _load_mot(path: str) -> Dict[int, np.ndarray]:
    boxes: Dict[int, List[List[float]]] = {}
    for line, text in enumerate(_read_text(path).splitlines(), start=1):
        if not text.strip():
            continue
        row = [c.strip() for c in text.split(",")]
        if len(row) < 6:
            raise DataError("%s:%d: %d fields, expected >= 6 (frame,id,x,y,w,h,conf,...)" % (path, line, len(row)))
        frame = _frame(path, line, row[0], first=1)
        x, y, w, h = (parse_finite(path, line, n, t) for n, t in zip("xywh", row[2:6]))
        _size_ok(path, line, w, h)
        rows = boxes.setdefault(frame, [])
        if len(row) > 6 and parse_finite(path, line, "conf", row[6]) == 0:
            continue  # MOT ground truth marks regions to ignore with conf 0
        rows.append([x, y, x + w, y + h])
    return _collect(boxes)


def _load_txt(path: str) -> Dict[int, np.ndarray]:
    boxes: Dict[int, List[List[float]]] = {}
    lines = _read_text(path).splitlines()
    while lines and not lines[-1].strip():
        lines.pop()  # a trailing newline is not an extra frame
    for line, text in enumerate(lines, start=1):
        rows = boxes.setdefault(line - 1, [])
        fields = text.replace(",", " ").split()
        if not fields:
            continue
        if len(fields) != 4:
            raise DataError("%s:%d: %d fields, expected 4 (x y w h)" % (path, line, len(fields)))
        try:
            x, y, w, h = (float(f) for f in fields)
        except ValueError:
            raise DataError("%s:%d: %r is not four numbers x y w h" % (path, line, text.strip())) from None
        if any(math.isnan(v) for v in (x, y, w, h)) or (w == 0 and h == 0):
            continue
        if not all(math.isfinite(v) for v in (x, y, w, h)):
            raise DataError("%s:%d: %r must be finite" % (path, line, text.strip()))
        _size_ok(path, line, w, h)
        rows.append([x, y, x + w, y + h])
    return _collect(boxes)


def detect_format(path: str) -> str:
    """The format of a label file or folder, from its layout and first line."""
    if os.path.isdir(path):
        return "voc"
    if not os.path.exists(path):
        raise DataError("%s: no such label file or folder" % path)
    first = ""
    for text in _read_text(path).splitlines():
        if text.strip():
            first = text.strip()
            break
    if first.lower().replace(" ", "").startswith("frame,class,"):
        return "halmstad"
    if os.path.basename(path).lower() == "gt.txt" or len(first.split(",")) >= 6:
        return "mot"
    if len(first.replace(",", " ").split()) == 4 or not first:
        return "txt"
    raise DataError(
        "%s: unknown label format (first line %r); expected Halmstad CSV, VOC folder, MOT gt.txt or 'x y w h' lines"
        % (path, first[:60])
    )


def load_labels(
    path: str, fmt: Optional[str] = None, classes: Optional[Sequence[str]] = ("DRONE",)
) -> Dict[int, np.ndarray]:
    """Frame index (0-based) -> (k, 4) float32 ``xyxy`` ground-truth boxes, 0-based pixels.

    ``fmt`` is one of FORMATS or None to detect it. ``classes`` (case-insensitive) selects
    the counted objects in formats that name classes (halmstad, voc); None counts all.
    """
    if fmt is None:
        fmt = detect_format(path)
    if fmt not in FORMATS:
        raise DataError("%s: label format %r, expected one of %s" % (path, fmt, "|".join(FORMATS)))
    if fmt == "voc":
        if not os.path.isdir(path):
            raise DataError("%s: VOC labels must be a folder of .xml files" % path)
        labels = _load_voc(path, classes)
    elif os.path.isdir(path):
        raise DataError("%s: is a folder, %s labels are one file" % (path, fmt))
    elif fmt == "halmstad":
        labels = _load_halmstad(path, classes)
    elif fmt == "mot":
        labels = _load_mot(path)
    else:
        labels = _load_txt(path)
    log.debug("labels path=%s format=%s frames=%d boxes=%d", path, fmt, len(labels), sum(len(b) for b in labels.values()))
    return labels
