"""False targets on drone-free 1080p scenes with ground movers under ego-motion (issue 16's third
negatives group, on seeds the verifier never saw).

The scenes are training/mine_tracks.py's SYN_EMPTY kind (150 frames, 8 cars, birds and near clutter,
the camera turning, no drone rendered), so "a target reported" is a false target in every frame.
Prints per seed the frames with a target, then the share over all of them.

    python bench/drone_free.py                 # seeds 6100-6107 (mining uses 6000-6095 and 6200-6295)
    python bench/drone_free.py --first-seed 6100 --scenes 100 --config my.yaml
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from payload.config import Config, load_config  # noqa: E402
from payload.detect.pipeline import Glad  # noqa: E402
from payload.errors import ConfigError  # noqa: E402
from payload.types import Frame  # noqa: E402
from training.mine_tracks import DRONE_FREE_BENCH_SEEDS, synthetic_scene  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--first-seed", type=int, default=DRONE_FREE_BENCH_SEEDS.start,
                    help="the first scene's seed (mining uses 6000-6095 and 6200-6295)")
    ap.add_argument("--scenes", type=int, default=len(DRONE_FREE_BENCH_SEEDS), help="scenes: seeds FIRST .. FIRST + SCENES - 1")
    ap.add_argument("--frames", type=int, default=150, help="frames per scene")
    ap.add_argument("--config", "-c", default=None, help="YAML file (default: built-in defaults)")
    args = ap.parse_args()
    if args.first_seed < 0 or args.scenes < 1 or args.frames < 1:
        raise SystemExit("--first-seed %d --scenes %d --frames %d: expected a seed >= 0 and at least 1 scene and 1 frame"
                         % (args.first_seed, args.scenes, args.frames))
    seeds = range(args.first_seed, args.first_seed + args.scenes)
    try:
        cfg = load_config(args.config) if args.config else Config()
    except ConfigError as exc:
        raise SystemExit(str(exc)) from None
    hits = 0
    for seed in seeds:
        glad = Glad(cfg.detector)
        scene = synthetic_scene(seed, args.frames, with_drone=False)
        n = 0
        for sf in scene:
            n += len(glad.process(Frame(sf.image, sf.index, int(sf.index * 1e9 / scene.fps), 0)).detections) > 0
        print("seed %d: a target in %d of %d frames" % (seed, n, args.frames), flush=True)
        hits += n
    total = len(seeds) * args.frames
    print("drone-free scenes %d-%d: a false target in %d of %d frames (%.1f %%)"
          % (seeds[0], seeds[-1], hits, total, 100.0 * hits / total))
    return 0


if __name__ == "__main__":
    sys.exit(main())
