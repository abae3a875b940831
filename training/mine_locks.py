"""Mine the patches of what the whole pipeline reports, for the classifier's hard examples.

The lock confirmation makes the classifier decide which locks are reported, so the examples
that matter are the boxes GLAD itself locks on: birds, aircraft and clutter it follows, and the
drones it follows with its own box sizes. This runs GLAD (the shipped models, confirmation off so
that every lock is seen) over Halmstad clips and synthetic scenes and keeps the classifier patch
of each reported box every ``--every``'th frame, labelled against the ground truth as in
mine_candidates.py (drone / clutter / dropped when ambiguous; every box on a negatives clip is
clutter).

  python training/mine_locks.py --name locks1 --halmstad train negatives_train --scenes 40
writes training/cache/<name>_cls.npz (x [K,32,32,3], y [K]).
"""

import argparse
import os
import sys
from collections import Counter

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import load_config  # noqa: E402
from payload.detect.patches import crop_patches  # noqa: E402
from payload.detect.pipeline import Glad  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from payload.types import Frame  # noqa: E402
from training.build_cache import CACHE, clip_frames, save_extra_sets  # noqa: E402
from training.halmstad import splits  # noqa: E402
from training.mine_candidates import label  # noqa: E402

FIRST_SEED = 4000  # apart from the build (1000-1179), mining (2000-3029) and eval (7-36, 100-109, 200-214) seeds


class Collector:
    def __init__(self, every):
        self.every = every
        self.x, self.y = [], []
        self.counts = Counter()

    def add(self, source, index, image, result, gt):
        if index % self.every or not len(result.detections):
            return
        box = result.detections.xyxy[0]
        y = label(box, gt)
        if y < 0:
            return
        self.x.append(crop_patches(image, box[None])[0])
        self.y.append(y)
        self.counts[(source, y)] += 1


def run_clip(glad, collector, source, frames, fps=30.0):
    """GLAD from a fresh start over ``frames``: (index, image, the drone's xyxy or None)."""
    glad.reset()
    for index, image, gt in frames:
        t_ns = int(index * 1e9 / fps)
        frame = Frame(image=image, index=index, t_capture_ns=t_ns, t_wall_ns=t_ns)
        collector.add(source, index, image, glad.process(frame), gt)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--name", required=True)
    ap.add_argument("--halmstad", nargs="*", default=[], help="splits whose clips are run (e.g. train negatives_train)")
    ap.add_argument("--scenes", type=int, default=0, help="synthetic 1920x1080 scenes, seeds from --first-seed")
    ap.add_argument("--first-seed", type=int, default=FIRST_SEED)
    ap.add_argument("--target-px", type=float, nargs=2, default=(4.0, 20.0))
    ap.add_argument("--frames", type=int, default=150, help="frames per synthetic scene")
    ap.add_argument("--every", type=int, default=3, help="keep a patch every N-th frame (a lock repeats itself)")
    args = ap.parse_args()

    cfg = load_config(None)
    # one target at a time: the patches are the lock's, as the classifier sees it in the single-target GLAD
    detector = cfg.detector.model_copy(update={
        "classifier": cfg.detector.classifier.model_copy(update={"confirm_hits": 0}),
        "targets": cfg.detector.targets.model_copy(update={"max": 1})})
    glad = Glad(detector)
    collector = Collector(args.every)
    all_splits = splits()
    for split in args.halmstad:
        for ci, clip in enumerate(all_splits[split]):
            run_clip(glad, collector, split,
                     ((i, image, drones[0] if drones else None) for i, image, drones, _ in clip_frames(clip)))
            print("%s %d/%d %s %s" % (split, ci + 1, len(all_splits[split]), clip, dict(collector.counts)), flush=True)
    for k in range(args.scenes):
        scene = Scene(seed=args.first_seed + k, frames=args.frames, target_px=tuple(args.target_px))
        run_clip(glad, collector, "synthetic", ((sf.index, sf.image, sf.target_xyxy) for sf in scene))
        print("scene %d/%d %s" % (k + 1, args.scenes, dict(collector.counts)), flush=True)
    save_extra_sets(args.name, collector.x, collector.y)
    print("wrote %s: %d patches, %d drone; %s" % (os.path.join(CACHE, args.name + "_cls.npz"), len(collector.y),
                                                  sum(collector.y), dict(collector.counts)))


if __name__ == "__main__":
    main()
