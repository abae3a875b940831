"""Grouped cross-validation folds over whole blocks of consecutive Halmstad clip numbers.

Clips with neighbouring numbers were usually filmed in one session (same day, place, drone and
light), so a split that puts V_DRONE_013 in training and V_DRONE_014 in validation measures
the session, not the detector. Here every clip kind (``V_DRONE``, ``IR_DRONE``, ``V_BIRD``,
``IR_AIRPLANE``, ...: sensor prefix + class) is cut into blocks of ``block_size`` consecutive
numbers (001-010, 011-020, ...), and each fold takes one *contiguous run* of whole blocks of
every kind. Contiguous runs leave only K - 1 block boundaries per kind between folds, so a
session that straddles a block boundary can be split at most there, and each fold is a stretch
of recording days the others never saw (as footage from a new session would be).

The runs are cut where the kind's cumulative frame count comes nearest to 1/K, 2/K, ... of its
total (frames balanced per kind, hence per sensor and per drone/negative). The two sensors are
numbered independently (V_DRONE_001 and IR_DRONE_001 are different recordings: their tracks
differ), so each kind is cut on its own.

The definition ships as ``folds.json`` beside this module: per kind, the inclusive clip-number
range of each fold; the first range starts at 1 and the last ends at 999, so a clip number not
present when the file was made (clips kept aside as unseen material) still has a fold.
Regenerate it (only on purpose: models trained per fold depend on it) with
``python -m payload.eval.folds --write`` from the repository root.
"""

import argparse
import json
import os
import re
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

from payload.errors import DataError

FOLDS_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "folds.json")
BLOCK_SIZE = 10
DEFAULT_K = 3
MAX_NUMBER = 999
_CLIP = re.compile(r"^((?:V|IR)_[A-Z]+)_(\d{1,3})$")

ABOUT = ("Grouped CV folds (payload/eval/folds.py): per clip kind, the inclusive clip-number range each "
         "fold holds out, whole blocks of block_size consecutive numbers; frames: the frames of each fold "
         "when the file was made")

Range = Tuple[int, int]  # inclusive clip numbers


def parse_clip(name: str) -> Tuple[str, int]:
    """``IR_DRONE_042`` -> (``IR_DRONE``, 42); DataError for a name outside the scheme."""
    match = _CLIP.match(name)
    if match is None:
        raise DataError("clip %r: expected a Halmstad clip name like V_DRONE_013 or IR_BIRD_004" % name)
    return match.group(1), int(match.group(2))


def block_of(number: int, block_size: int = BLOCK_SIZE) -> int:
    """0 for clip numbers 1..block_size, 1 for the next block, ..."""
    return (number - 1) // block_size


def _cuts(block_frames: Sequence[int], k: int) -> List[int]:
    """Indices into the ordered blocks where folds 1..k-1 start: each at the block boundary whose
    cumulative frame count is nearest to j/k of the total, every fold at least one block."""
    n = len(block_frames)
    if n < k:
        raise DataError("%d blocks cannot fill %d folds (each fold needs a whole block)" % (n, k))
    cumulative = [0]
    for frames in block_frames:
        cumulative.append(cumulative[-1] + frames)
    total = cumulative[-1]
    cuts: List[int] = []
    for j in range(1, k):
        lo = (cuts[-1] + 1) if cuts else 1
        hi = n - (k - j)  # leave a block for each later fold
        target = total * j / k
        cuts.append(min(range(lo, hi + 1), key=lambda i: (abs(cumulative[i] - target), i)))
    return cuts


def make_folds(frames_by_clip: Mapping[str, int], k: int = DEFAULT_K,
               block_size: int = BLOCK_SIZE) -> Dict[str, object]:
    """The fold definition (as written to folds.json) from each clip's frame count.

    Deterministic: the same clips and counts give the same folds, whatever their order.
    """
    if k < 2:
        raise DataError("k=%d: cross-validation needs at least 2 folds" % k)
    blocks: Dict[str, Dict[int, int]] = {}
    for name, frames in frames_by_clip.items():
        kind, number = parse_clip(name)
        per_kind = blocks.setdefault(kind, {})
        per_kind[block_of(number, block_size)] = per_kind.get(block_of(number, block_size), 0) + int(frames)
    kinds: Dict[str, List[List[int]]] = {}
    balance: Dict[str, List[int]] = {}
    for kind in sorted(blocks):
        order = sorted(blocks[kind])
        try:
            cuts = _cuts([blocks[kind][b] for b in order], k)
        except DataError as exc:
            raise DataError("%s: %s" % (kind, exc)) from None
        starts = [0] + cuts
        ranges = []
        for j, start in enumerate(starts):
            first = 1 if j == 0 else order[start] * block_size + 1
            last = MAX_NUMBER if j == k - 1 else order[starts[j + 1]] * block_size
            ranges.append([first, last])
        kinds[kind] = ranges
        ends = starts + [len(order)]
        balance[kind] = [sum(blocks[kind][b] for b in order[ends[j]:ends[j + 1]]) for j in range(k)]
    return {"k": k, "block_size": block_size, "kinds": kinds, "frames": balance}


class Folds:
    """A loaded fold definition: which fold holds a clip."""

    def __init__(self, data: Mapping[str, object], source: str = "<folds>") -> None:
        self.source = source
        try:
            self.k = int(data["k"])  # type: ignore[arg-type]
            self.block_size = int(data["block_size"])  # type: ignore[arg-type]
            kinds = data["kinds"]
            self.ranges: Dict[str, List[Range]] = {
                str(kind): [(int(r[0]), int(r[1])) for r in ranges] for kind, ranges in kinds.items()  # type: ignore[union-attr]
            }
        except (KeyError, TypeError, ValueError, IndexError, AttributeError):
            raise DataError("%s: expected {\"k\": K, \"block_size\": N, \"kinds\": {KIND: [[first, last], ...]}}"
                            % source) from None
        if self.k < 2:
            raise DataError("%s: k=%d, expected at least 2 folds" % (source, self.k))
        for kind, ranges in self.ranges.items():
            if len(ranges) != self.k:
                raise DataError("%s: %s has %d ranges, expected k=%d" % (source, kind, len(ranges), self.k))
            expected_first = 1
            for first, last in ranges:
                if first != expected_first or last < first or (first - 1) % self.block_size:
                    raise DataError("%s: %s ranges %s must tile 1..%d in whole blocks of %d"
                                    % (source, kind, ranges, MAX_NUMBER, self.block_size))
                expected_first = last + 1
            if expected_first != MAX_NUMBER + 1:
                raise DataError("%s: %s ranges %s must end at %d" % (source, kind, ranges, MAX_NUMBER))

    def fold_of(self, name: str) -> int:
        kind, number = parse_clip(name)
        ranges = self.ranges.get(kind)
        if ranges is None:
            raise DataError("clip %s: kind %s has no folds in %s (have: %s)"
                            % (name, kind, self.source, ", ".join(sorted(self.ranges))))
        for fold, (first, last) in enumerate(ranges):
            if first <= number <= last:
                return fold
        raise DataError("clip %s: number %d outside every fold of %s in %s" % (name, number, kind, self.source))

    def split(self, names: Sequence[str]) -> List[List[str]]:
        """The names held out in each fold (input order kept)."""
        out: List[List[str]] = [[] for _ in range(self.k)]
        for name in names:
            out[self.fold_of(name)].append(name)
        return out

    def training(self, names: Sequence[str], fold: int) -> List[str]:
        """The names a model of ``fold`` may train on: every clip outside it."""
        return [name for name in names if self.fold_of(name) != fold]

    def describe(self) -> List[str]:
        """One line per fold: the clip-number ranges of each kind it holds out."""
        lines = []
        for fold in range(self.k):
            parts = ["%s %03d-%03d" % (kind, r[fold][0], r[fold][1]) for kind, r in sorted(self.ranges.items())]
            lines.append("fold %d: %s" % (fold, ", ".join(parts)))
        return lines


def load_folds(path: Optional[str] = None) -> Folds:
    path = path or FOLDS_FILE
    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except OSError as exc:
        raise DataError("%s: cannot read folds: %s" % (path, exc.strerror or exc)) from None
    except ValueError as exc:
        raise DataError("%s: not valid JSON: %s" % (path, exc)) from None
    if not isinstance(data, dict):
        raise DataError("%s: expected a JSON object" % path)
    return Folds(data, path)


def clip_frames(data_dir: str) -> Dict[str, int]:
    """Frame count of every clip under ``data_dir``/{visible,ir} (from the container's header)."""
    import cv2

    counts = {}
    for sub in ("visible", "ir"):
        folder = os.path.join(data_dir, sub)
        for entry in sorted(os.listdir(folder)):
            stem, ext = os.path.splitext(entry)
            if ext.lower() != ".mp4" or _CLIP.match(stem) is None:
                continue
            cap = cv2.VideoCapture(os.path.join(folder, entry))
            counts[stem] = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            cap.release()
    return counts


def folds_text(folds: Mapping[str, object]) -> str:
    """folds.json's text: one line per kind, so that a change shows as a one-line diff."""
    lines = ['{"about": %s,' % json.dumps(ABOUT), ' "k": %d, "block_size": %d,' % (folds["k"], folds["block_size"])]
    for key in ("kinds", "frames"):
        table = folds[key]
        rows = ['  %s: %s' % (json.dumps(kind), json.dumps(table[kind])) for kind in sorted(table)]  # type: ignore[index]
        lines.append(' %s: {\n%s\n }%s' % (json.dumps(key), ",\n".join(rows), "," if key == "kinds" else "}"))
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m payload.eval.folds",
                                 description="print (or --write) the grouped CV folds of the Halmstad clips")
    ap.add_argument("--data", default=None, help="Halmstad folder (default: ../shared/data/halmstad)")
    ap.add_argument("--k", type=int, default=DEFAULT_K)
    ap.add_argument("--block-size", type=int, default=BLOCK_SIZE)
    ap.add_argument("--write", action="store_true", help="write %s" % FOLDS_FILE)
    args = ap.parse_args(argv)
    from payload.offline import find_splits

    data_dir = args.data or os.path.dirname(find_splits(None))
    text = folds_text(make_folds(clip_frames(data_dir), args.k, args.block_size))
    print(text)
    if args.write:
        with open(FOLDS_FILE, "w", encoding="utf-8") as handle:
            handle.write(text + "\n")
        print("wrote %s" % FOLDS_FILE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
