"""training/cv_train.py: which clips a fold trains on, and stages that skip, rerun and fail loudly."""

import os
import sys
from types import SimpleNamespace

import pytest

pytest.importorskip("torch")  # training/ needs the training environment

from payload.eval.folds import Folds  # noqa: E402
from training.cv_train import Log, hard_sets, run_stage, select  # noqa: E402
from training.mine_tracks import check_synthetic_range, fold_of, jobs  # noqa: E402
from training.train_verifier import choose, choose_within, lockcheck, replay  # noqa: E402

NAMES = ["V_DRONE_001", "V_DRONE_031", "IR_DRONE_001", "IR_DRONE_041", "V_BIRD_001", "V_AIRPLANE_031",
         "IR_BIRD_001", "IR_HELICOPTER_021"]


def test_a_fold_trains_on_no_clip_it_holds_out():
    folds = Folds({"k": 2, "block_size": 10, "kinds": {
        kind: [[1, 20], [21, 999]] for kind in ("V_DRONE", "IR_DRONE", "V_BIRD", "V_AIRPLANE", "IR_BIRD", "IR_HELICOPTER")}})
    outside = folds.training(NAMES, 0)
    assert select(outside, "V", False) == ["V_DRONE_031"]
    assert select(outside, "IR", False) == ["IR_DRONE_041"]
    assert select(outside, "V", True) == ["V_AIRPLANE_031"]
    assert select(outside, "IR", True) == ["IR_HELICOPTER_021"]
    held = set(folds.split(NAMES)[0])
    assert held == {"V_DRONE_001", "IR_DRONE_001", "V_BIRD_001", "IR_BIRD_001"}
    assert not held & set(outside)
    assert select(NAMES, "V", False, limit=1) == ["V_DRONE_001"]


def test_a_fold_is_mined_and_taught_only_by_what_never_saw_it():
    folds = Folds({"k": 3, "block_size": 10, "kinds": {"IR_BIRD": [[1, 10], [11, 20], [21, 999]]}})
    assert [fold_of(folds, n) for n in ("IR_BIRD_005", "IR_BIRD_015", "IR_BIRD_025")] == [0, 1, 2]
    # synthetic scenes: the seed decides, the same for every kind of scene
    assert [fold_of(folds, n) for n in ("SYN_DRONE_5000", "SYN_EMPTY_6001", "SYN_LIGHT_DRONE_7005")] == [2, 1, 0]
    assert fold_of(folds, "IR_BIRD_015~ego7") == 1  # a clip warped by --ego-motion stays in its fold
    objects = ["irobj0", "irobj1", "irobj2"]
    assert hard_sets(objects, "1") == ["irobj0", "irobj2"]
    assert hard_sets(objects, "0") == ["irobj1", "irobj2"]
    assert hard_sets(objects, "all") == objects


def test_more_scenes_are_mined_beside_the_first_without_touching_the_drone_free_bench():
    def names(first, count):
        args = SimpleNamespace(synthetic_only=True, synthetic=count, synthetic_first=first, tiny_light=0, shard=0,
                               shards=1, scene_frames=150, folds=None)
        return sorted(name for name, _ in jobs(args))

    assert names(0, 2) == ["SYN_DRONE_5000", "SYN_DRONE_5001", "SYN_EMPTY_6000", "SYN_EMPTY_6001"]
    assert names(200, 2) == ["SYN_DRONE_5200", "SYN_DRONE_5201", "SYN_EMPTY_6200", "SYN_EMPTY_6201"]
    check_synthetic_range(0, 96)
    check_synthetic_range(200, 96)
    check_synthetic_range(108, 10)
    for first, count in ((0, 101), (96, 96), (107, 1), (-1, 5), (0, -3)):
        with pytest.raises(SystemExit) as e:
            check_synthetic_range(first, count)
        assert "--synthetic-first %d --synthetic %d" % (first, count) in str(e.value)
        assert "\n" not in str(e.value)


def test_mining_some_folds_takes_only_their_scenes_and_the_rest_later_completes_the_shard():
    folds = Folds({"k": 3, "block_size": 10, "kinds": {"V_DRONE": [[1, 10], [11, 20], [21, 999]]}})

    def names(only, shard=0):
        args = SimpleNamespace(synthetic_only=True, synthetic=6, synthetic_first=0, tiny_light=3, shard=shard,
                               shards=2, scene_frames=150, folds=only)
        return [name for name, _ in jobs(args, folds)]

    first, rest = names([0, 1]), names([2])
    assert first and rest
    assert all(fold_of(folds, n) in (0, 1) for n in first) and all(fold_of(folds, n) == 2 for n in rest)
    # together they are the shard, in its order: mining the last fold later leaves nothing out
    whole = names(None)
    assert sorted(first + rest) == sorted(whole) and len(whole) == len(set(whole))
    assert not set(whole) & set(names(None, shard=1))


def test_the_verifier_rule_may_cost_no_drone_group_more_than_the_limit():
    def fold(vis_cf, thermal_cf, false_pct):
        return {"visible drones": {"cF": vis_cf}, "thermal drones": {"cF": thermal_cf},
                "visible negatives": {"target%": false_pct}}

    rules = {"lockcheck": [fold(0.99, 0.99, 20.0)],
             "gentle": [fold(0.96, 0.95, 4.0)],
             # its mean loss (0.03) is within 0.05, but thermal drones lose 0.06: refused
             "strict": [fold(0.99, 0.93, 1.0)]}
    assert choose(rules, 0.05)["rule"] == "gentle"
    assert choose(rules, 0.07)["rule"] == "strict"


def test_within_the_false_target_bar_the_rule_finding_most_drones_is_chosen():
    def fold(vis_f, thermal_f, vis_false, thermal_false, empty=0.5):
        return {"visible drones": {"F": vis_f}, "thermal drones": {"F": thermal_f},
                "visible negatives": {"target%": vis_false}, "thermal negatives": {"target%": thermal_false},
                "synthetic empty": {"target%": empty}}

    bar = {"visible negatives": 3.0, "thermal negatives": 3.0, "synthetic empty": 2.0}
    rules = {"lockcheck": [fold(0.85, 0.90, 50.0, 30.0)],
             "loose": [fold(0.75, 0.86, 3.5, 1.0)],  # visible over the bar
             "strict": [fold(0.66, 0.82, 2.0, 0.5)],
             "middle": [fold(0.70, 0.84, 2.9, 2.9)],
             # within on the real negatives, over on the drone-free synthetic scenes
             "blind": [fold(0.74, 0.85, 2.0, 2.0, empty=2.5)]}
    assert choose_within(rules, bar)["rule"] == "middle"
    # per fold means: one fold over the bar does not refuse a rule whose mean is within it
    rules["split"] = [fold(0.72, 0.85, 4.0, 1.0), fold(0.72, 0.85, 1.8, 1.0)]
    assert choose_within(rules, bar)["rule"] == "split"
    with pytest.raises(SystemExit, match="no rule"):
        choose_within({"lockcheck": rules["lockcheck"]}, bar)


def test_a_stricter_lockcheck_replayed_on_loosely_mined_locks_confirms_and_drops_as_glad_would():
    import numpy as np

    from payload.detect.verify import FEATURES, N_FEATURES

    measured, p = FEATURES.index("measured"), FEATURES.index("drone_p")
    # lock 0: a doubted start, confirmed at its 4th hit, then a coasting frame (no hit: no verdict);
    # lock 1: confirmed at once, then its hits fall until the hold drops it
    hit = [1, 1, 1, 1, 0, 1, 1, 1, 1, 1]
    prob = [0.9, 0.6, 0.9, 0.9, 0.0, 0.9, 0.9, 0.9, 0.05, 0.05]
    rows = np.zeros((10, N_FEATURES), np.float32)
    rows[:, measured], rows[:, p] = hit, prob
    clip = {"rows": rows, "lock": np.array([0] * 6 + [1] * 4), "confirmed": np.ones(10, bool),
            "box": np.tile(np.float32([[10, 10, 20, 20]]), (10, 1))}
    clip["box"][7] = np.nan  # no box this frame: never reported
    want = [False, False, False, True, True, True, False, True, True, False]
    assert lockcheck(clip, 3, 0.5, 2, 0.8).tolist() == want
    # the replay reports what that check passes (not what was mined) where there is a box
    confirmed = lockcheck(clip, 3, 0.5, 2, 0.8)
    got = replay(clip, None, 0, 0, 0, use_verifier=False, confirmed=confirmed)
    assert got.tolist() == [w and i != 7 for i, w in enumerate(want)]
    assert replay(clip, None, 0, 0, 0, use_verifier=False).sum() == 9  # as mined


def test_train_verifier_refuses_a_malformed_lockcheck_naming_it(tmp_path):
    import subprocess

    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, os.path.join(repo, "training", "train_verifier.py"), "--tracks", str(tmp_path),
                           "--out", str(tmp_path / "out"), "--lockcheck", "10:0.15:2:1.5"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "10:0.15:2:1.5" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()


def _write(path, text):
    return [sys.executable, "-c", "open(%r, 'w').write(%r)" % (str(path), text)]


def _write_if_absent(path, text):
    """A command that fails when ``path`` is still there (a stage that would resume from it)."""
    return [sys.executable, "-c", "import os, sys\nif os.path.exists(%r): sys.exit(1)\nopen(%r, 'w').write(%r)"
            % (str(path), str(path), text)]


def test_stage_runs_once_then_skips_and_reruns_when_its_command_or_input_changes(tmp_path):
    log = Log(str(tmp_path / "log.txt"))
    out, marker, ckpt = tmp_path / "out.txt", tmp_path / ".done", tmp_path / "ckpt"
    ckpt.write_text("1")
    os.utime(str(ckpt), (1000, 1000))
    run_stage(log, "s", str(marker), _write(out, "a"), [str(out)], inputs=[str(ckpt)])
    assert out.read_text() == "a"
    run_stage(log, "s", str(marker), _write(out, "a"), [str(out)], inputs=[str(ckpt)])
    assert "s: done before, skipped" in (tmp_path / "log.txt").read_text()
    run_stage(log, "s", str(marker), _write(out, "b"), [str(out)], inputs=[str(ckpt)])  # another command
    assert out.read_text() == "b"
    # the checkpoint is newer than the output: the output is removed (a training stage must not
    # resume from a checkpoint of the old input) and the stage runs again
    out.write_text("stale")
    os.utime(str(out), (500, 500))
    run_stage(log, "s", str(marker), _write_if_absent(out, "fresh"), [str(out)], inputs=[str(ckpt)])
    assert out.read_text() == "fresh"
    assert "is older than its input, removed" in (tmp_path / "log.txt").read_text()


def test_a_failed_stage_stops_the_driver_and_leaves_no_marker(tmp_path):
    log = Log(str(tmp_path / "log.txt"))
    with pytest.raises(SystemExit):
        run_stage(log, "bad", str(tmp_path / ".done"), [sys.executable, "-c", "raise SystemExit(3)"], [])
    with pytest.raises(SystemExit):
        run_stage(log, "silent", str(tmp_path / ".done"), [sys.executable, "-c", "pass"], [str(tmp_path / "none")])
    assert not (tmp_path / ".done").exists()
    text = (tmp_path / "log.txt").read_text()
    assert "bad: FAILED with exit status 3" in text and "silent: FAILED: no " in text


def test_the_shipped_verifier_is_its_members_averaged_and_loads_as_one(tmp_path):
    import numpy as np
    import torch

    from payload.detect.onnx_model import OnnxModel
    from payload.detect.verify import N_FEATURES, LockVerifier
    from training.train_verifier import WINDOW, build_net, ensemble, export

    torch.manual_seed(0)
    members = [build_net(np.zeros(N_FEATURES, np.float32), np.ones(N_FEATURES, np.float32)).eval() for _ in range(3)]
    net = ensemble(members)
    x = torch.rand(5, WINDOW, N_FEATURES)
    x[:, :, 0] = 1.0
    with torch.no_grad():
        each = torch.stack([m(x) for m in members])
        assert each.std(0).max() > 1e-4  # the members differ, so the mean is a real test
        assert torch.allclose(net(x), each.mean(0), atol=1e-6)
    path = str(tmp_path / "verifier.onnx")
    export(net, path)
    verifier = LockVerifier(OnnxModel(path, expected_inputs={"tracks": (None, None, N_FEATURES)}), min_frames=1,
                            threshold=0.5, release_threshold=0.3)
    for row in x[0].numpy():
        verifier.add(row)
    assert abs(verifier.probability - float(each.mean(0)[0, 0])) < 1e-4


def test_a_views_network_never_sees_the_evidence_it_was_trained_without(tmp_path):
    """Each view's networks (train_verifier VIEWS) are trained with some columns zeroed; the shipped
    ensemble must zero them at run time too, or a network would meet values it never saw."""
    import numpy as np
    import torch

    from payload.detect.onnx_model import OnnxModel
    from payload.detect.verify import LOOK_FEATURES, N_FEATURES, LockVerifier
    from training.train_verifier import VIEWS, WINDOW, build_net, ensemble, export, masked, view_keep

    n_in = N_FEATURES + len(LOOK_FEATURES)
    torch.manual_seed(0)
    nets = {view: masked(build_net(np.zeros(n_in, np.float32), np.ones(n_in, np.float32)).eval(), view_keep(view, n_in))
            for view in ("all", "look", "motion")}
    x = torch.rand(4, WINDOW, n_in)
    x[:, :, 0] = 1.0
    for view, net in nets.items():
        keep = torch.from_numpy(view_keep(view, n_in))
        assert int((keep == 0).sum()) == len(VIEWS[view])
        other = x.clone()
        other[:, :, keep == 0] = torch.rand(int((keep == 0).sum()))  # only what the view is without differs
        with torch.no_grad():
            assert torch.allclose(net(x), net(other), atol=1e-7), view
            changed = x.clone()
            changed[:, :, keep == 1] += 1.0
            assert not torch.allclose(net(x), net(changed)), view  # and it does see the rest
    net = ensemble(list(nets.values()))
    path = str(tmp_path / "views.onnx")
    export(net, path, WINDOW, n_in)
    verifier = LockVerifier(OnnxModel(path, expected_inputs={"tracks": (None, None, None)}), min_frames=1,
                            threshold=0.5, release_threshold=0.3)
    for row in x[0].numpy():
        verifier.add(row)
    with torch.no_grad():
        want = float(torch.stack([m(x[:1]) for m in nets.values()]).mean())
    assert abs(verifier.probability - want) < 1e-5


def test_a_verifier_exported_for_a_longer_window_is_run_on_that_window(tmp_path):
    import numpy as np
    import torch

    from payload.detect.onnx_model import OnnxModel
    from payload.detect.verify import N_FEATURES, LockVerifier
    from training.train_verifier import WINDOW, build_net, export

    window = WINDOW + 16  # not the default, so the export must carry it
    torch.manual_seed(0)
    net = build_net(np.zeros(N_FEATURES, np.float32), np.ones(N_FEATURES, np.float32)).eval()
    path = str(tmp_path / "verifier_long.onnx")
    export(net, path, window)
    verifier = LockVerifier(OnnxModel(path, expected_inputs={"tracks": (None, None, N_FEATURES)}), min_frames=1,
                            threshold=0.5, release_threshold=0.3)
    assert verifier.window == window
    rows = torch.rand(window + 8, N_FEATURES)
    rows[:, 0] = 1.0
    for row in rows.numpy():
        verifier.add(row)
    with torch.no_grad():
        want = float(net(rows[-window:][None])[0, 0])  # the last ``window`` rows, the oldest 8 gone
    assert abs(verifier.probability - want) < 1e-4


@pytest.mark.parametrize("flag, value, expected", [("--members", "0", "--members 0: expected at least 1 network"),
                                                   ("--window", "3", "--window 3: expected at least 4"),
                                                   ("--views", "look", "--views look: the rows have no look_log_area")])
def test_train_verifier_refuses_a_bad_argument_in_one_line(tmp_path, flag, value, expected):
    import subprocess

    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, os.path.join(repo, "training", "train_verifier.py"), "--tracks", str(tmp_path),
                           "--out", str(tmp_path / "out"), flag, value], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.strip().startswith(expected) and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()  # refused before anything is written


def _fake_tracks(root, names, n=40, seed=0):
    """Lock tracks as training/mine_tracks.py writes them: two locks a clip, the first on the drone
    (in a drone clip), rows of N_FEATURES measurements."""
    import numpy as np

    from payload.detect.verify import N_FEATURES

    rng = np.random.default_rng(seed)
    root.mkdir()
    for name in names:
        drone = "_DRONE_" in name
        rows = rng.normal(size=(n, N_FEATURES)).astype(np.float32)
        rows[:, 0] = 1.0  # present
        rows[:, 1] += 2.0 if drone else -2.0  # something to learn
        box = np.tile(np.array([[100, 100, 110, 110]], np.float32), (n, 1))
        gt = box.copy() if drone else np.full((n, 4), np.nan, np.float32)
        np.savez(str(root / (name + ".npz")), rows=rows, lock=np.repeat([1, 2], n // 2), box=box, gt=gt,
                 confirmed=np.ones(n, bool), frames=n, gt_frames=n if drone else 0)


@pytest.mark.parametrize("views", [[], ["--views", "all", "size", "motion"]])
def test_each_folds_verifier_is_exported_as_scored(tmp_path, views):
    """--export-folds writes the very networks whose held-out probabilities the cross-validation
    scored, so that glad-payload cv --fold-models runs a verifier that never saw the fold; with
    --views too, each view's networks fed their view of the rows inside the one file."""
    import numpy as np

    from payload.detect.onnx_model import OnnxModel
    from payload.detect.verify import N_FEATURES, LockVerifier
    from training.train_verifier import main as train_verifier

    names = ["V_DRONE_001", "V_DRONE_040", "V_DRONE_080", "V_BIRD_001", "V_BIRD_020", "V_BIRD_040"]
    _fake_tracks(tmp_path / "tracks", names)
    out, models = tmp_path / "run", tmp_path / "models"
    train_verifier(["--tracks", str(tmp_path / "tracks"), "--out", str(out), "--steps", "30", "--members", "2",
                    "--min-frames", "4", "--thresholds", "0.5", "--export-folds", str(models)] + views)
    oof = np.load(str(out / "oof_prob.npz"))
    assert sorted(os.listdir(str(models))) == ["fold0", "fold1", "fold2"]

    def first_lock_probability(fold, rows):
        """Fold ``fold``'s exported verifier after the clip's first lock (its first 20 rows), whole."""
        model = OnnxModel(str(models / ("fold%d" % fold) / "glad_verifier.onnx"),
                          expected_inputs={"tracks": (None, None, N_FEATURES)})
        verifier = LockVerifier(model, min_frames=1, threshold=0.5, release_threshold=0.3)
        for row in rows[:20]:
            verifier.add(row)
        return verifier.probability

    for fold, name in enumerate(["V_DRONE_001", "V_DRONE_040", "V_DRONE_080"]):
        with np.load(str(tmp_path / "tracks" / (name + ".npz"))) as z:
            rows = z["rows"]
        # frame 19 of the clip is the first lock's last: the held-out probability of that window
        assert abs(first_lock_probability(fold, rows) - float(oof[name][19])) < 1e-4, (fold, name)
    # the three folds' networks differ (each trained without its own fold)
    probs = [first_lock_probability(fold, rows) for fold in range(3)]
    assert max(probs) - min(probs) > 1e-4


def test_an_excursion_strays_inside_a_drone_window_and_comes_back():
    """--excursions: a drone window gets one or two rows of a not-drone window inside it (never its
    first present row nor its current one), the lock jumping 3-10 box sizes there and back; not-drone
    windows and the rest of the rows stay as they were."""
    import numpy as np

    from payload.detect.verify import FEATURES, N_FEATURES
    from training.train_verifier import excursions

    rng = np.random.default_rng(0)
    n, T = 64, 32
    xb = np.zeros((n, T, N_FEATURES), np.float32)
    present = rng.integers(4, T + 1, size=n)
    for i in range(n):
        xb[i, T - present[i]:] = rng.normal(0.0, 0.3, size=(present[i], N_FEATURES))
        xb[i, T - present[i]:, 0] = 1.0
        xb[i, T - present[i]:, FEATURES.index("log2_w")] = 3.0
        xb[i, T - present[i]:, FEATURES.index("log2_h")] = 3.0
    yb = (np.arange(n) % 2).astype(np.float32)
    out = excursions(xb, yb, rng, 1.0)
    dx, dy = FEATURES.index("rel_dx"), FEATURES.index("rel_dy")
    assert np.array_equal(out[yb == 0], xb[yb == 0])
    motion = [FEATURES.index(f) for f in ("rel_dx", "rel_dy", "log_rel_px")]
    # the current row is the drone's (at most it is the row that comes back)
    assert np.array_equal(np.delete(out[:, -1], motion, axis=1), np.delete(xb[:, -1], motion, axis=1))
    strayed = 0
    for i in np.nonzero(yb == 1)[0]:
        changed = np.nonzero((out[i] != xb[i]).any(1))[0]
        if not len(changed):
            continue
        strayed += 1
        first = T - present[i]
        assert changed.min() > first and changed[-2] < T - 1, (i, changed)
        assert 2 <= len(changed) <= 3  # one or two stray rows and the row that comes back
        jump_in = np.hypot(out[i, changed[0], dx], out[i, changed[0], dy])
        back = out[i, changed[-1], [dx, dy]]
        assert 3.0 <= jump_in <= 10.0
        assert np.allclose(back, -out[i, changed[0], [dx, dy]])
        # the stray rows are a not-drone window's rows (apart from the jump)
        stray = np.delete(out[i, changed[:-1]], motion, axis=1)
        pool = np.delete(xb[yb == 0].reshape(-1, N_FEATURES), motion, axis=1)
        assert all((np.abs(pool - r).max(1) < 1e-6).any() for r in stray)
    assert strayed >= 0.8 * (yb == 1).sum()
    assert np.array_equal(excursions(xb, yb, rng, 0.0), xb)


def test_a_view_trained_with_excursions_never_sees_the_jump_in_its_zeroed_columns(monkeypatch):
    """The excursions write the motion columns; a view trained without them (``motion``) must still
    see zeros there in every batch, or it would learn from values its file never feeds it."""
    import numpy as np

    import training.train_verifier as tv
    from payload.detect.verify import FEATURES, N_FEATURES

    seen = []
    build = tv.build_net

    def recording_net(mean, std):
        net = build(mean, std)
        net.register_forward_pre_hook(lambda module, inputs: seen.append(inputs[0].detach().numpy().copy()))
        return net

    monkeypatch.setattr(tv, "build_net", recording_net)
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 0.3, size=(64, tv.WINDOW, N_FEATURES)).astype(np.float32)
    x[:, :, 0] = 1.0
    y = (np.arange(64) % 2).astype(np.float32)
    w = np.ones(64, np.float32)
    motion = [FEATURES.index(f) for f in tv.VIEWS["motion"]]
    for view in ("all", "motion"):
        keep = tv.view_keep(view, N_FEATURES)
        seen.clear()
        tv.train(x * keep, y, w, steps=4, seed=0, log_every=0, excursion=1.0,
                 columns=None if keep.all() else keep)
        jumps = np.abs(np.concatenate(seen)[:, :, motion[:2]]).max()
        if view == "all":
            assert jumps >= 3.0  # the excursions happened
        else:
            assert jumps == 0.0, view


def test_a_second_mining_is_learned_and_the_first_is_scored(tmp_path):
    """--tracks A B: the networks learn the locks of both minings (the same clips as other detectors
    locked them), the cross-validation scores A's. B here says the opposite of A, so learning it
    must pull A's held-out drone probabilities down; an empty mining is refused in one line."""
    import subprocess

    import numpy as np

    from training.train_verifier import main as train_verifier

    names = ["V_DRONE_001", "V_DRONE_040", "V_DRONE_080", "V_BIRD_001", "V_BIRD_020", "V_BIRD_040"]
    _fake_tracks(tmp_path / "a", names)
    _fake_tracks(tmp_path / "b", names, seed=1)
    for name in names:  # B: the signal reversed
        path = str(tmp_path / "b" / (name + ".npz"))
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        d["rows"][:, 1] = -d["rows"][:, 1]
        np.savez(path, **d)

    def drone_oof(*minings):
        out = tmp_path / ("run%d" % len(minings))
        train_verifier(["--tracks"] + [str(tmp_path / m) for m in minings] + ["--out", str(out), "--steps", "60",
                       "--members", "1", "--min-frames", "4", "--thresholds", "0.5"])
        oof = np.load(str(out / "oof_prob.npz"))
        assert sorted(oof.files) == sorted(names)
        return float(np.mean([oof[n].mean() for n in names if "_DRONE_" in n]))

    alone, both = drone_oof("a"), drone_oof("a", "b")
    assert alone > 0.8 and both < alone - 0.2, (alone, both)
    # --score B: the networks learn A alone and judge B's locks, which say the opposite
    out = tmp_path / "scored"
    train_verifier(["--tracks", str(tmp_path / "a"), "--score", str(tmp_path / "b"), "--out", str(out), "--steps", "60",
                    "--members", "1", "--min-frames", "4", "--thresholds", "0.5"])
    oof = np.load(str(out / "oof_prob.npz"))
    assert sorted(oof.files) == sorted(names)
    assert np.mean([oof[n].mean() for n in names if "_DRONE_" in n]) < alone - 0.2
    (tmp_path / "empty").mkdir()
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, os.path.join(repo, "training", "train_verifier.py"), "--tracks",
                           str(tmp_path / "a"), str(tmp_path / "empty"), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(tmp_path / "empty") in lines[0] and "no mined locks" in lines[0], proc.stderr
    proc = subprocess.run([sys.executable, os.path.join(repo, "training", "train_verifier.py"), "--tracks",
                           str(tmp_path / "a"), "--score", str(tmp_path / "empty"), "--out", str(tmp_path / "run")],
                          capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode != 0 and len(lines) == 1 and "--score %s" % (tmp_path / "empty") in lines[0], proc.stderr


def test_a_classifier_from_another_run_replaces_the_classifier_stage(tmp_path, monkeypatch, capsys):
    import training.cv_train as cv_train

    stages = []
    monkeypatch.setattr(cv_train, "run_stage", lambda log, name, *a, **k: stages.append(name))
    monkeypatch.setattr(cv_train, "clip_frames", lambda root: dict.fromkeys(NAMES, 10))
    given = tmp_path / "clsB" / "fold1" / "glad_classifier.onnx"
    given.parent.mkdir(parents=True)
    given.write_bytes(b"fold 1's classifier")
    tag = str(tmp_path / "run")
    argv = ["--tag", tag, "--folds-only", "1", "--log", str(tmp_path / "log.txt")]
    assert cv_train.main(argv + ["--classifier-from", str(tmp_path / "clsB")]) == 0
    assert (tmp_path / "run" / "models" / "fold1" / "glad_classifier.onnx").read_bytes() == b"fold 1's classifier"
    assert "fold 1 global detector" in stages and not any("classifier" in s for s in stages)
    assert "fold 1 export glad_classifier.onnx" not in stages
    stages.clear()
    assert cv_train.main(argv) == 0  # without it the shortened classifier is trained and exported
    assert "fold 1 classifier" in stages and "fold 1 export glad_classifier.onnx" in stages
    # a fold the other run lacks: one line naming the file, refused before anything trains
    stages.clear()
    assert cv_train.main(argv[:2] + ["--folds-only", "1", "0", "--classifier-from", str(tmp_path / "clsB")]) == 2
    said = capsys.readouterr().out.strip().splitlines()[-1]
    assert said.endswith("--classifier-from %s: no %s" % (tmp_path / "clsB", tmp_path / "clsB" / "fold0" / "glad_classifier.onnx"))
    assert stages == []


def test_a_folds_classifier_learns_nothing_of_the_folds_clips_in_either_step(tmp_path, monkeypatch):
    import training.cv_train as cv_train

    commands = {}
    monkeypatch.setattr(cv_train, "run_stage", lambda log, name, marker, argv, *a, **k: commands.setdefault(name, argv))
    monkeypatch.setattr(cv_train, "clip_frames", lambda root: dict.fromkeys(NAMES, 10))
    folds = cv_train.load_folds(None)
    thermal_negatives = [n for n in NAMES if n.startswith("IR_") and "DRONE" not in n]
    assert len({folds.fold_of(n) for n in thermal_negatives}) == 2  # the test needs two folds' objects
    held = folds.fold_of(thermal_negatives[0])
    assert cv_train.main(["--tag", str(tmp_path / "run"), "--folds-only", str(held), "--log", str(tmp_path / "log")]) == 0

    # each fold's objects are built from that fold's thermal negatives clips and nothing else
    objects = {}
    for name, argv in commands.items():
        if name.startswith("thermal objects of fold "):
            fold = int(name.split()[4])
            clips = argv[argv.index("--clips") + 1:]
            assert clips == [n for n in thermal_negatives if folds.fold_of(n) == fold]
            objects[fold] = argv[argv.index("--name") + 1]
    assert sorted(objects) == list(range(folds.k))

    first = commands["fold %d classifier" % held]
    assert "--init" not in first  # the first step starts from nothing that saw a clip
    second = commands["fold %d classifier, second step" % held]
    init = second[second.index("--init") + 1]
    assert init == commands["fold %d export the classifier's first step" % held][-1]
    hard = second[second.index("--hard") + 1:second.index("--hard-frac")]
    assert sorted(os.path.basename(p) for p in hard) == sorted(
        "%s_cls.npz" % objects[j] for j in range(folds.k) if j != held)
    # both steps read the fold's own patch cache, whose clips are all outside the fold
    cache = commands["fold %d cache" % held]
    assert first[first.index("--cache") + 1] == second[second.index("--cache") + 1] == cache[cache.index("--cache") + 1]
    assert not set(cache[cache.index("--clips") + 1:]) & set(folds.split(NAMES)[held])
    # the exported classifier is the second step's
    export = commands["fold %d export glad_classifier.onnx" % held]
    tuned = os.path.join(cv_train.HERE, "runs", second[second.index("--name") + 1], "last.pt")
    assert os.path.normpath(export[-2]) == os.path.normpath(tuned)


def test_a_clip_mined_under_camera_motion_has_its_frames_and_labels_warped_alike(tmp_path):
    # --ego-motion: the locks of a clip as a moving camera would film it; the drone's label must
    # move with its pixels, or the verifier learns drones as clutter
    import cv2
    import numpy as np

    from payload.offline import ClipSpec, with_ego_motion
    from training.mine_tracks import halmstad_frames

    video, labels = tmp_path / "V_DRONE_001.mp4", tmp_path / "V_DRONE_001.csv"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (320, 240))
    rows = []
    for i in range(20):
        img = np.full((240, 320, 3), 200, np.uint8)
        x, y = 100 + 3 * i, 90
        cv2.rectangle(img, (x, y), (x + 15, y + 11), (20, 20, 20), -1)
        writer.write(img)
        rows.append("%d,DRONE,%d,%d,16,12" % (i, x, y))
    writer.release()
    labels.write_text("frame,class,x,y,w,h\n" + "\n".join(rows) + "\n")
    clip = ClipSpec("V_DRONE_001", str(video), str(labels))
    plain = list(halmstad_frames(clip))
    warped = list(halmstad_frames(with_ego_motion([clip], 3)[0]))
    assert len(warped) == len(plain) == 20
    moved = 0
    for (i, raw, raw_box), (j, image, box) in zip(plain, warped):
        assert i == j and image.shape == raw.shape
        dark = np.argwhere(image.min(axis=2) < 80)  # the drone's pixels where the camera put them
        cy, cx = dark.mean(axis=0)
        x1, y1, x2, y2 = box[0]
        assert x1 - 2 <= cx <= x2 + 2 and y1 - 2 <= cy <= y2 + 2, (i, (cx, cy), box[0])
        moved += np.hypot(*((box[0, :2] + box[0, 2:]) / 2 - (raw_box[0, :2] + raw_box[0, 2:]) / 2)) > 2
    assert moved >= 10  # the camera did move the drone


def test_mine_tracks_refuses_a_negative_camera_motion_seed_in_one_line(tmp_path):
    import subprocess
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, os.path.join(repo, "training", "mine_tracks.py"), "--out", str(tmp_path / "out"),
                           "--ego-motion", "-1", "--synthetic", "0"], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert proc.stderr.strip() == "--ego-motion -1: expected a seed >= 0"
    assert not (tmp_path / "out").exists()  # refused before anything is written
