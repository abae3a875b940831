"""Mine the locks GLAD follows, frame by frame, for the lock verifier (payload/detect/verify.py).

Runs GLAD with the default config (the shipped models, or with --fold-models DIR each clip's fold's
networks from DIR/fold{k}/, so that a fold is mined by networks that never saw it; a synthetic scene
by its seed's fold, ``fold_of``) over Halmstad clips and synthetic scenes, and keeps, for every frame in which GLAD follows a lock (reported or
not), the verifier's feature row, the lock's number within the clip, whether LockCheck has
confirmed it, the box that frame would report, and the drone's labelled box nearest to it. The
rows are written per clip to OUT/<clip>.npz, so an interrupted run resumes where it stopped and
several shards can run side by side:

  python training/mine_tracks.py --out training/cache/tracks --shard 0 --shards 2
  python training/mine_tracks.py --out training/cache/tracks --synthetic 24 --shard 0 --shards 1
  python training/mine_tracks.py --out training/cache/tracks --synthetic 96 --synthetic-first 200 --synthetic-only

Synthetic scenes: seeds 5000.. (``--synthetic-first`` on) with a drone and ground movers (cars) under
ego-motion, and seeds 6000.. without the drone (``render_target=False``, more cars): every lock there is false. With
``--tiny-light N``, seeds 7000.. are issue 16's tiny white drone (configs/tiny-light-sky.yaml: 3-6 px,
light airframe, clear sky, above the horizon), so the verifier learns what such a lock looks like.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from payload.config import config_with, load_config  # noqa: E402
from payload.detect.pipeline import Glad  # noqa: E402
from payload.detect.verify import N_FEATURES, PATCH_PX, target_patch  # noqa: E402
from payload.eval.cv import DETECTOR_FILES, fold_model_files, halmstad_clips  # noqa: E402
from payload.eval.folds import load_folds  # noqa: E402
from payload.eval.labels import load_labels  # noqa: E402
from payload.offline import UsageError, check_ego_motion_seed, recorded_name, with_ego_motion  # noqa: E402
from payload.synth.scene import Scene  # noqa: E402
from payload.types import Frame  # noqa: E402

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared", "data", "halmstad")
SYNTH_DRONE_SEED, SYNTH_EMPTY_SEED, SYNTH_LIGHT_SEED = 5000, 6000, 7000


def fold_of(folds, name: str) -> int:
    """A clip's fold (also as ``V_DRONE_013~ego7``, warped by --ego-motion); a synthetic scene's is its
    seed modulo the number of folds."""
    if name.startswith("SYN_"):
        return int(name.rsplit("_", 1)[1]) % folds.k
    return folds.fold_of(recorded_name(name))


def nearest(gt: np.ndarray, box) -> np.ndarray:
    """The labelled box whose centre is nearest to ``box`` (the first one without a box); NaN if none."""
    if gt is None or not len(gt):
        return np.full(4, np.nan, np.float32)
    if box is None:
        return np.asarray(gt[0], np.float32)
    c = (np.asarray(box[:2]) + np.asarray(box[2:])) / 2.0
    g = (gt[:, :2] + gt[:, 2:]) / 2.0
    return np.asarray(gt[int(np.argmin(np.hypot(*(g - c).T)))], np.float32)


def run(glad, frames, fps=30.0):
    """GLAD from a fresh start over ``frames`` ((index, image, drone boxes [K,4] or None)): the arrays
    of one clip."""
    glad.reset()
    import cv2

    rows, index, lock, confirmed, box, gt, patch_rel, patch_nat = [], [], [], [], [], [], [], []
    n_frames = n_gt = 0
    lock_id = -1
    for i, image, drones in frames:
        n_frames += 1
        n_gt += int(drones is not None and len(drones) > 0)
        t_ns = int(i * 1e9 / fps)
        glad.process(Frame(image=image, index=i, t_capture_ns=t_ns, t_wall_ns=t_ns))
        # one target at a time (detector.targets.max 1): its track, while it lasts
        track = glad.tracks[0] if glad.tracks else None
        if track is None or track.last_row is None:
            continue
        if len(track.verifier.rows) == 1:
            lock_id += 1
        rows.append(track.last_row[:N_FEATURES])  # the look features are made from the patches below
        index.append(i)
        lock.append(lock_id)
        confirmed.append(track.lock.confirmed)
        b = track.last_box
        box.append(np.full(4, np.nan, np.float32) if b is None else b)
        gt.append(nearest(drones, b))
        # the target's pixels where its row measured it, to study its look over time
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        measured = track.verifier.features.box
        patch_rel.append(target_patch(grey, measured))
        patch_nat.append(target_patch(grey, measured, native=True))
    return dict(rows=np.asarray(rows, np.float32).reshape(-1, N_FEATURES), frame=np.asarray(index, np.int32),
                lock=np.asarray(lock, np.int32), confirmed=np.asarray(confirmed, bool),
                box=np.asarray(box, np.float32).reshape(-1, 4), gt=np.asarray(gt, np.float32).reshape(-1, 4),
                frames=np.int32(n_frames), gt_frames=np.int32(n_gt),
                patch_rel=np.asarray(patch_rel, np.uint8).reshape(-1, PATCH_PX, PATCH_PX),
                patch_nat=np.asarray(patch_nat, np.uint8).reshape(-1, PATCH_PX, PATCH_PX))


def halmstad_frames(clip):
    """(index, image, drone boxes) of a clip, warped by its camera path where it has one (--ego-motion)."""
    import cv2

    labels = load_labels(clip.labels, classes=("DRONE",))
    warp = clip.ego_motion
    if warp is not None:
        labels = warp.labels(labels)
    cap = cv2.VideoCapture(clip.video)
    i = 0
    while True:
        ok, image = cap.read()
        if not ok:
            break
        yield i, (image if warp is None else warp.image(i, image)), labels.get(i)
        i += 1
    cap.release()


def scene_frames(scene):
    for sf in scene:
        yield sf.index, sf.image, (None if sf.target_xyxy is None or not scene.render_target
                                   else np.asarray(sf.target_xyxy, np.float32)[None])


def synthetic_scene(seed: int, frames: int, with_drone: bool) -> Scene:
    """A SYN_DRONE (4-40 px drone, 3 cars) or SYN_EMPTY (no drone, 8 cars) scene; bench/drone_free.py
    counts false targets on the drone-free kind."""
    return Scene(seed=seed, frames=frames, target_px=(4.0, 40.0), cars=3 if with_drone else 8, render_target=with_drone)


#: bench/drone_free.py's scenes (its default --first-seed and --scenes come from here): never mined, so that its
#: false-target count stays a figure on scenes the verifier never saw
DRONE_FREE_BENCH_SEEDS = range(6100, 6108)


def check_synthetic_range(first: int, count: int) -> None:
    """Refuse (one line) a scene range that is negative or would mine bench/drone_free.py's scenes."""
    if first < 0 or count < 0:
        raise SystemExit("--synthetic-first %d --synthetic %d: expected both >= 0" % (first, count))
    empty = range(SYNTH_EMPTY_SEED + first, SYNTH_EMPTY_SEED + first + count)
    if max(empty.start, DRONE_FREE_BENCH_SEEDS.start) < min(empty.stop, DRONE_FREE_BENCH_SEEDS.stop):
        raise SystemExit("--synthetic-first %d --synthetic %d: drone-free seeds %d-%d would include bench/drone_free.py's "
                         "%d-%d, which must stay unseen; expected a range off them (e.g. --synthetic-first 200)" % (
                             first, count, empty.start, empty.stop - 1, DRONE_FREE_BENCH_SEEDS.start,
                             DRONE_FREE_BENCH_SEEDS.stop - 1))


def jobs(args, folds=None):
    """(name, frames) of the clips and scenes of ``args.shard``; with ``args.folds``, of those folds only."""
    out = []
    if not args.synthetic_only:
        clips = halmstad_clips(args.data)
        if args.ego_motion is not None:
            clips = with_ego_motion(clips, args.ego_motion)  # one camera path per clip, as eval and cv warp them
        for clip in clips:
            out.append((clip.name, lambda clip=clip: halmstad_frames(clip)))
    for k in range(args.synthetic_first, args.synthetic_first + args.synthetic):
        for seed, with_drone in ((SYNTH_DRONE_SEED + k, True), (SYNTH_EMPTY_SEED + k, False)):
            def frames(seed=seed, with_drone=with_drone):
                return scene_frames(synthetic_scene(seed, args.scene_frames, with_drone))
            out.append(("SYN_%s_%d" % ("DRONE" if with_drone else "EMPTY", seed), frames))
    for k in range(args.tiny_light):
        def frames(seed=SYNTH_LIGHT_SEED + k):
            return scene_frames(Scene(seed=seed, frames=args.scene_frames, target_px=(3.0, 6.0), drone_look="light",
                                      sky="clear", target_in_sky=True))
        out.append(("SYN_LIGHT_DRONE_%d" % (SYNTH_LIGHT_SEED + k), frames))
    # shuffled (a fixed order): a run stopped part-way still covers every kind and every fold evenly
    order = np.random.default_rng(0).permutation(len(out))
    out = [out[n] for n in order]
    out = [j for n, j in enumerate(out) if n % args.shards == args.shard]
    if args.folds is not None:
        out = [j for j in out if fold_of(folds, j[0]) in args.folds]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--data", default=DATA)
    ap.add_argument("--config", default=None)
    ap.add_argument("--shard", type=int, default=0)
    ap.add_argument("--shards", type=int, default=1)
    ap.add_argument("--synthetic", type=int, default=0, help="synthetic scene pairs (drone / empty)")
    ap.add_argument("--synthetic-first", type=int, default=0,
                    help="the first pair's seed offset: more scenes later without re-mining (keep off 6100-6107, "
                         "bench/drone_free.py's scenes never mined)")
    ap.add_argument("--tiny-light", type=int, default=0, help="tiny white drone scenes (3-6 px, clear sky)")
    ap.add_argument("--synthetic-only", action="store_true")
    ap.add_argument("--scene-frames", type=int, default=150)
    ap.add_argument("--fold-models", default=None, metavar="DIR",
                    help="run each clip with the networks of its fold: DIR/fold{k}/glad_*.onnx")
    ap.add_argument("--ego-motion", type=int, default=None, metavar="SEED",
                    help="the Halmstad clips warped as if the camera moved (glad-payload cv --ego-motion SEED's camera "
                         "paths; the synthetic scenes have their own)")
    ap.add_argument("--folds", type=int, nargs="+", default=None, metavar="K",
                    help="only the clips and scenes of these folds (e.g. while the other folds' networks still train)")
    args = ap.parse_args()
    check_synthetic_range(args.synthetic_first, args.synthetic)
    if args.ego_motion is not None:  # refused before any clip is read or mined
        try:
            check_ego_motion_seed(args.ego_motion)
        except UsageError as e:
            raise SystemExit(str(e)) from None
    os.makedirs(args.out, exist_ok=True)
    import cv2

    cv2.setNumThreads(1)  # one core per shard: shards side by side must not fight over threads
    cfg = load_config(args.config)
    folds = load_folds()

    def make_glad(fold):
        det = cfg
        if args.fold_models:
            which = fold if fold >= 0 else "all"
            det = config_with(cfg, **fold_model_files(args.fold_models, [which], DETECTOR_FILES)[which])
        # the verifier off: every lock is followed and reported as today, its rows recorded all the
        # same; one target at a time: a lock's rows are one track's
        return Glad(det.detector.model_copy(update={
            "threads": 1, "verifier": det.detector.verifier.model_copy(update={"enabled": False}),
            "targets": det.detector.targets.model_copy(update={"max": 1})}))

    glads = {}
    todo = jobs(args, folds)
    for n, (name, frames) in enumerate(todo):
        path = os.path.join(args.out, name + ".npz")
        if os.path.exists(path):
            continue
        t = time.time()
        fold = fold_of(folds, name) if args.fold_models else -1
        if fold not in glads:
            glads[fold] = make_glad(fold)
        arrays = run(glads[fold], frames())
        tmp = path + ".tmp.npz"
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
        print("%d/%d %s frames %d locked %d locks %d (%.0f s)" % (
            n + 1, len(todo), name, arrays["frames"], len(arrays["rows"]), len(set(arrays["lock"].tolist())),
            time.time() - t), flush=True)


if __name__ == "__main__":
    main()
