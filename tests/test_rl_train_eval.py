"""Smoke runs: training, resume, evaluation, baselines, the CLI hooks and the shipped model."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.cli import main
from minid3rqn.io import load_npz
from minid3rqn.nets.qnet import QNetConfig
from minid3rqn.rl import models
from minid3rqn.rl.evaluate import evaluate_policy, wilson_interval
from minid3rqn.rl.policies import (OraclePolicy, QNetPolicy, RandomPolicy, ReactivePolicy,
                                   StraightPolicy)
from minid3rqn.rl.train import TrainConfig, start_run, train
from minid3rqn.world import ACTIONS, Camera, DroneEnv, render_depth_batch

pytestmark = pytest.mark.rl

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "minid3rqn" / "models" / "d3rqn_basic.npz"
SHIPPED_DEPTH = ROOT / "minid3rqn" / "models" / "depth_basic.npz"
SMALL = dict(steps=192, learning_starts=64, n_envs=8, log_every=64, checkpoint_every=96,
             hidden=16, replay_capacity=2000, eps_decay_steps=200, n_worlds=3)


def weights(run) -> list:
    return [p.data for p in run.agent.online.parameters()]


def test_wilson_interval():
    lo, hi = wilson_interval(0, 2000)
    assert lo == 0.0 and 0.0015 < hi < 0.0025
    lo, hi = wilson_interval(50, 100)
    assert lo == pytest.approx(0.404, abs=1e-3) and hi == pytest.approx(0.596, abs=1e-3)
    lo, hi = wilson_interval(2000, 2000)
    assert hi == 1.0 and lo > 0.997


def test_training_env_step_contract():
    env = DroneEnv("basic", 4, seed=0, n_worlds=2, autoreset=True)
    depth, _ = env.reset()
    assert depth.shape == (4, 32, 104) and depth.min() > 0
    for _ in range(30):
        _, rewards, terminated, truncated, _ = env.step(np.zeros(4, dtype=np.int64))
        assert not (terminated & truncated).any()
        # a collision pays -1; otherwise the clearance (>= 0.5 m)
        assert np.all(rewards[terminated] == -1.0)
        assert np.all(rewards[~terminated] >= 0.5)
    with pytest.raises(ValueError, match="actions"):
        env.step(np.full(4, 7))


def test_training_smoke_and_exact_resume(tmp_path):
    """A run cut off at 96 transitions and resumed from its checkpoint is the run made in
    one go, weight for weight; and the same seed gives the same run."""
    cfg = TrainConfig(**SMALL)
    half = train(TrainConfig(**{**SMALL, "steps": 96}), tmp_path / "a", progress=False)
    assert half.steps == 96 and (tmp_path / "a" / "checkpoint.npz").exists()
    b = train(cfg, tmp_path / "a", progress=False, resume=True)
    a = train(cfg, tmp_path / "c", progress=False)
    assert a.agent.updates > 0 and a.steps == 192 and b.agent.updates == a.agent.updates
    for p, q in zip(weights(a), weights(b)):
        np.testing.assert_array_equal(p, q)
    assert (tmp_path / "a" / "curve.csv").exists() and (tmp_path / "a" / "curve.png").exists()
    assert a.curve == [{**row, "seconds": r["seconds"]} for row, r in zip(b.curve, a.curve)]
    with pytest.raises(ValueError, match=r"other settings: hidden 16 \(now 8\)"):
        train(TrainConfig(**{**SMALL, "hidden": 8}), tmp_path / "a", progress=False,
              resume=True)


def test_training_config_is_checked_and_names_the_setting():
    from minid3rqn.config import ConfigError
    for bad, name in (({"steps": 0}, "steps"), ({"batch_size": 0}, "batch_size"),
                      ({"seq_len": 0}, "seq_len"), ({"variant": "dqn"}, "variant"),
                      ({"conv_channels": [6, 5]}, "conv_channels"),
                      ({"hfov_deg": 180}, "hfov_deg"), ({"actions": [[2, "x"]]}, "actions")):
        with pytest.raises(ConfigError, match=name):
            TrainConfig(**bad)
    assert TrainConfig().window() == 5 and TrainConfig(variant="d3qn").window() == 1
    assert TrainConfig(variant="d3qn", seq_len=3).window() == 3


def test_stacked_nonrecurrent_training_smoke(tmp_path):
    cfg = TrainConfig(variant="ddqn", stack=5, **{**SMALL, "checkpoint_every": 1000,
                                                  "n_worlds": 2})
    run = train(cfg, tmp_path, progress=False)
    pol = QNetPolicy(run.agent.online)
    res = evaluate_policy(pol, "basic", n_flights=8, chunk=8, max_steps=5, progress=False)
    assert 0 <= res.rate <= 1 and res.flights == 8


def test_a_students_actions_reward_and_camera_are_parameters(tmp_path):
    """The action table and the camera travel with the model file (a 7-action net flies
    with its 7 actions); the reward, the depth change and the TD target reach training."""
    table = np.concatenate([ACTIONS, [[1.0, 0.3], [1.0, -0.3]]]).tolist()
    seen = {"reward": 0, "depth": 0, "target": 0}

    def reward(d, collided, yaw_rate=0.0):
        seen["reward"] += 1
        return np.where(collided, -1.0, 1.0)

    def depth_fn(depth, rng):
        seen["depth"] += 1
        return depth

    def target(qo, qt, r, term, gamma):
        seen["target"] += 1
        return r + gamma * (1 - term) * qt.max(axis=-1)
    cfg = TrainConfig(actions=table, hfov_deg=60.0, **{**SMALL, "steps": 128})
    run = train(cfg, tmp_path, reward_fn=reward, depth_fn=depth_fn, td_target=target,
                progress=False)
    assert all(seen.values()), seen
    assert run.env.n_actions == 7 and run.env.camera.hfov_deg == 60.0
    meta = QNetPolicy.load(tmp_path / "model.npz").meta
    np.testing.assert_array_equal(models.trained_actions(meta), table)
    assert models.trained_camera(meta) == Camera(hfov_deg=60.0)
    pol = models.load_policy(str(tmp_path / "model.npz"))
    res = evaluate_policy(pol, "basic", n_flights=4, chunk=4, max_steps=3, progress=False)
    assert res.flights == 4
    shipped = models.load_policy(str(SHIPPED))
    with pytest.raises(ValueError, match="another action table or camera"):
        models.actions_and_camera(pol, shipped)
    np.testing.assert_array_equal(models.actions_and_camera(shipped)[0], ACTIONS)


def test_evaluation_smoke_baselines():
    for pol in [StraightPolicy(), RandomPolicy(5, seed=0), ReactivePolicy(ACTIONS)]:
        res = evaluate_policy(pol, "basic", n_flights=8, chunk=4, max_steps=50, progress=False)
        assert res.flights == 8 and res.ci_low <= res.rate <= res.ci_high
    straight = evaluate_policy(StraightPolicy(), "basic", n_flights=16, progress=False)
    assert straight.rate == 0.0          # no free straight line 40 m long in any world


def test_evaluation_is_the_same_in_parallel_and_in_any_chunk_order():
    """Each chunk has its own world seed and its own policy generator, so two worker
    processes give exactly the one-process result, and a random policy's flights do
    not depend on what it flew before."""
    results = {}
    for name, make in [("random", lambda: RandomPolicy(5, seed=0)),
                       ("reactive", lambda: ReactivePolicy(ACTIONS))]:
        one = evaluate_policy(make(), "basic", n_flights=12, chunk=4, max_steps=8,
                              progress=False)
        two = evaluate_policy(make(), "basic", n_flights=12, chunk=4, max_steps=8,
                              progress=False, workers=2)
        assert (one.successes, one.mean_steps) == (two.successes, two.mean_steps)
        results[name] = one
    used = RandomPolicy(5, seed=0)
    evaluate_policy(used, "basic", n_flights=4, chunk=4, max_steps=8, seed=99, progress=False)
    again = evaluate_policy(used, "basic", n_flights=12, chunk=4, max_steps=8, progress=False)
    assert again.mean_steps == results["random"].mean_steps


class _FlatEstimator:
    """A stand-in DispNet: 5 m everywhere."""

    def predict(self, rgb):
        return np.full(rgb.shape[:3], 5.0, np.float32)


class _GTInPredMode(DroneEnv):
    """A pred-mode env whose policy sees ground truth (what examples/07 builds on)."""

    def observe(self, idx):
        super().observe(idx)
        self.obs[idx] = render_depth_batch(self.batch_of(idx), self.poses[idx], self.camera)


def test_evaluation_flies_the_env_the_factory_makes():
    """``env_factory`` is what each chunk is flown in: a pred-mode subclass that
    shows ground truth flies exactly the GT evaluation (same worlds, same starts), in one
    process or two; the flat stand-in DispNet alone flies differently."""
    pol = ReactivePolicy(ACTIONS)
    kw = dict(n_flights=12, chunk=4, max_steps=20, progress=False)
    gt = evaluate_policy(pol, "basic", depth="gt", **kw)
    flat = evaluate_policy(pol, "basic", depth="pred", depth_estimator=_FlatEstimator(), **kw)
    for workers in (1, 2):
        mixed = evaluate_policy(pol, "basic", depth="pred", depth_estimator=_FlatEstimator(),
                                env_factory=_GTInPredMode, workers=workers, **kw)
        assert (mixed.successes, mixed.mean_steps) == (gt.successes, gt.mean_steps)
    assert flat.mean_steps != gt.mean_steps


def test_training_world_pool_is_set_and_checked(tmp_path):
    from minid3rqn.rl.train import training_worlds
    run = start_run(TrainConfig(n_worlds=5, n_envs=3, seed=4), tmp_path)
    assert len(run.env.worlds) == 5 and len(set(run.env.world_seeds.tolist())) == 5
    np.testing.assert_array_equal(training_worlds(4, 5), run.env.world_seeds)
    for bad in (0, -2, 2.5, True):
        with pytest.raises(ValueError, match="n_worlds"):
            DroneEnv("basic", 3, seed=0, n_worlds=bad)


def test_evaluation_rejects_bad_counts():
    for kwargs, word in [({"n_flights": 0}, "n_flights"), ({"chunk": 0}, "chunk"),
                         ({"workers": 0}, "workers")]:
        with pytest.raises(ValueError, match=word):
            evaluate_policy(StraightPolicy(), "basic", progress=False, **kwargs)


def test_oracle_flies_the_channel():
    res = evaluate_policy(OraclePolicy(), "channel", n_flights=4, max_steps=20, progress=False)
    assert res.rate >= 0.75


def test_cli_smoke(tmp_path, capsys):
    assert main(["train-agent", "--smoke", "--out", str(tmp_path / "run")]) == 0
    model = tmp_path / "run" / "model.npz"
    _, meta = load_npz(model)              # the machine that trained it (io.machine)
    assert set(meta["machine"]) == {"numpy", "blas_core", "python", "platform"}
    assert meta["command"].startswith("python -m minid3rqn train-agent --steps 128 ")
    assert meta["command"].endswith(f"--out {tmp_path / 'run'}")
    assert main(["evaluate", str(model), "random", "--flights", "4", "--steps", "10",
                 "--json", str(tmp_path / "r.jsonl")]) == 0
    assert len((tmp_path / "r.jsonl").read_text().splitlines()) == 2
    printed = capsys.readouterr().out.splitlines()         # each line names what flew
    assert printed[-2].endswith(f"  {model} (gt depth)") and printed[-1].startswith("Random")
    record = json.loads((tmp_path / "r.jsonl").read_text().splitlines()[0])
    assert record["command"] == f"python -m minid3rqn evaluate {model} --flights 4 --steps 10"
    if SHIPPED_DEPTH.exists():                        # predicted depth, flip-averaged
        assert main([str(x) for x in [
            "evaluate", model, "--flights", 2, "--steps", 3, "--depth", "pred", "--flip-tta",
            "--json", tmp_path / "f.jsonl"]]) == 0
        assert json.loads((tmp_path / "f.jsonl").read_text())["depth_flip"] is True
        # the flag reaches the estimator that flies
        from minid3rqn.depth.flip import FlipAveraged
        assert isinstance(models.depth_estimator_for("pred", str(SHIPPED_DEPTH), "basic",
                                                     True), FlipAveraged)
        assert not isinstance(models.depth_estimator_for("pred", str(SHIPPED_DEPTH), "basic"),
                              FlipAveraged)
    ens = models.load_policy(f"{model}+{model}")          # an ensemble spec
    assert ens.name.endswith("-ens2") and len(ens.members) == 2
    one = models.load_policy(str(model), mirror=True)     # a net and its mirror image
    assert one.name.endswith("-mirror") and [type(m).__name__ for m in one.members] == \
        ["QNetPolicy", "MirroredPolicy"]
    two = models.load_policy(f"{model}+{model}", mirror=True)
    assert two.name.endswith("-ens2-mirror") and len(two.members) == 4
    assert models.load_policy("reactive", mirror=True).name == "Reactive"
    assert main(["evaluate", str(model), "--mirror", "--flights", "2", "--steps", "3",
                 "--json", str(tmp_path / "m.jsonl")]) == 0
    assert json.loads((tmp_path / "m.jsonl").read_text())["mirror"] is True
    for bad, why in ((f"{model}+random", "'random' is a baseline"), (f"{model}+", "'' not found")):
        with pytest.raises(ValueError, match=why):
            models.load_policy(bad)
    capsys.readouterr()
    assert main(["evaluate", f"{model}+nope.npz"]) == 2
    assert "'nope.npz' not found" in capsys.readouterr().err
    # the paper's protocol: the Q-net flies its own training worlds
    from minid3rqn.rl.train import training_worlds
    assert main(["evaluate", str(model), "--worlds", "train", "--flights", "6", "--steps", "3",
                 "--json", str(tmp_path / "w.jsonl")]) == 0
    record = json.loads((tmp_path / "w.jsonl").read_text())
    trained = meta["train_config"]
    own = set(training_worlds(trained["seed"], trained["n_worlds"]).tolist())
    assert record["worlds_set"] == "train" and set(record["world_seeds"]) <= own
    for argv, why in ((["random"], "a baseline has none"),
                      ([str(model), "--scenario", "corners"], "trained in 'basic' worlds")):
        assert main(["evaluate", *argv, "--worlds", "train", "--flights", "2"]) == 2
        assert why in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["train-agent", "--steps", "0"], "--steps: expected a number >= 1; got 0"),
    (["train-agent", "--set", "conv_channels=6,5"], "--set conv_channels: expected three"),
    (["train-agent", "--set", "conv_channels=6,x,3"], "--set conv_channels: expected numbers"),
    (["train-agent", "--lr", "-1"], "--lr: expected a number > 0; got -1.0"),
    (["train-agent", "--depth", "pred", "--depth-model", "nope.npz"], "--depth-model: "),
    (["distil", "--teachers", "nope.npz"], "--teachers: 'nope.npz' is not a file"),
    (["evaluate", "straight", "--flights", "0"], "--flights: expected a number >= 1"),
    (["fly", "--model", "papr"], "'papr' not found.*expected a shipped name, paper or distil"),
    (["reproduce", "--workers", "0"], "--workers: expected a number >= 1; got 0"),
    (["reproduce", "--students", "2"], "--students 2: only for --recipe distil"),
])
def test_bad_inputs_are_one_line_naming_the_option(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err


def test_conv_channels_widen_the_torso(tmp_path):
    assert main(["train-agent", "--smoke", "--set", "conv_channels=6,5,3",
                 "--out", str(tmp_path / "run")]) == 0
    pol = QNetPolicy.load(tmp_path / "run" / "model.npz")
    default = QNetConfig().convs
    assert [c[0] for c in pol.qnet.config.convs] == [6, 5, 3]
    assert [c[1:] for c in pol.qnet.config.convs] == [c[1:] for c in default]
    assert "--set conv_channels=6,5,3" in pol.meta["command"]


@pytest.mark.parametrize("name", sorted(models.SHIPPED_QNETS))
def test_shipped_model_loads_and_beats_random(name):
    """Each shipped Q-net (fly --model NAME) loads with its command and seed recorded, a
    JSON of its evaluations beside it, and flies far better than Random."""
    path = models.SHIPPED_QNETS[name]
    assert path.is_file(), f"shipped Q-net {name!r} missing: {path}"
    assert models.recorded_result(path, "basic", "pred") is not None
    # every recorded evaluation gives both 95% intervals, the one by world no narrower
    for row in json.loads(path.with_suffix(".json").read_text())["evaluations"]:
        lo, hi = row["ci95"]
        wlo, whi = row["ci95_by_world"]
        assert wlo <= lo <= row["rate"] <= hi <= whi and row["worlds"] >= 2, row["command"]
    pol = QNetPolicy.load(path)
    assert "command" in pol.meta and "seed" in pol.meta
    q = evaluate_policy(pol, "basic", n_flights=32, chunk=32, seed=7, progress=False)
    r = evaluate_policy(RandomPolicy(5, seed=7), "basic", n_flights=32, chunk=32, seed=7,
                        progress=False)
    assert q.rate > r.rate + 0.2


@pytest.mark.parametrize("script", ["04_train_d3rqn.py", "05_evaluate.py"])
def test_examples_smoke(script, tmp_path):
    path = ROOT / "examples" / script
    if not path.exists():
        pytest.skip(f"{script} not written yet")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(   # this tree's package, not another
        filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    out_dir = ["--out", str(tmp_path)] if script.startswith("04") else []   # 05 writes nothing
    out = subprocess.run([sys.executable, str(path), "--smoke", *out_dir],
                         capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr[-2000:]


@pytest.mark.skipif(not SHIPPED.exists(), reason="no shipped Q-net yet")
def test_fly_main_job_smoke(tmp_path, capsys):
    """The README's first command, small: flies the shipped models, writes the GIF, prints
    the rate; the shipped nets by name; a missing member is named."""
    from minid3rqn.rl.fly import fly
    gif = tmp_path / "fly.gif"
    est = models.depth_estimator_for("pred") if SHIPPED_DEPTH.exists() else None
    out = fly(str(SHIPPED), est, "basic", 1, 2, gif, max_steps=4)
    assert gif.is_file() and gif.stat().st_size > 0
    assert out["flights"] == 2 and 0 <= out["success_rate"] <= 1
    assert 1 <= out["worlds"] <= 2                  # and by world when there are two
    assert (out["ci95_by_world"] is None) == (out["worlds"] < 2)
    # an ensemble flies too (the shipped net twice), and the net with its mirror image
    assert fly(f"{SHIPPED}+{SHIPPED}", None, "basic", 1, 2, gif, max_steps=2)["flights"] == 2
    assert fly(str(SHIPPED), None, "basic", 1, 2, gif, max_steps=2, mirror=True)["flights"] == 2
    for name in models.SHIPPED_QNETS:
        assert main(["fly", "--flights", "1", "--seed", "1", "--depth", "gt",
                     "--gif", str(gif), "--model", name]) == 0
    capsys.readouterr()
    assert main(["fly", "--model", f"{SHIPPED}+{tmp_path / 'nope.npz'}"]) == 2
    assert "nope.npz" in capsys.readouterr().err


@pytest.mark.skipif(not SHIPPED.exists(), reason="no shipped Q-net yet")
def test_fly_gif_has_a_depth_key_and_is_deterministic(tmp_path):
    """The GIF's depth panel stands on its colour key (metres): the key's left end is
    depth_to_rgb's colour at 0.5 m, its right end at the Q-net's 10 m; the same seed
    writes the same bytes."""
    from minid3rqn import viz
    from minid3rqn.rl.fly import fly
    key = viz.depth_key(300, 0.5, 10.0)
    assert key.shape == (24, 300, 3) and key.dtype == np.uint8
    np.testing.assert_array_equal(key[0, [0, -1]], viz.depth_to_rgb(np.array([0.5, 10.0]),
                                                                     0.5, 10.0))
    assert key[11:].min() < 100                       # the tick labels, in dark text
    np.testing.assert_array_equal(key, viz.depth_key(300, 0.5, 10.0))
    gifs = [fly(str(SHIPPED), None, "basic", 3, 1, tmp_path / f"{k}.gif", max_steps=3)["gif"]
            for k in range(2)]
    assert Path(gifs[0]).read_bytes() == Path(gifs[1]).read_bytes()


def test_a_raised_horizon_reaches_the_flights_frames():
    """A raised horizon (Camera.horizon_row) reaches the flights' frames."""
    env = DroneEnv("basic", 2, seed=0, n_worlds=2, camera=Camera(horizon_row=4))
    assert env.camera.cy == 4.0
    depth, _ = env.reset()
    floor = 1.0 / ((31 - 4) / 52)                 # the lowest row sees the floor 1.93 m ahead
    assert depth.shape == (2, 32, 104) and np.all(depth[:, -1] <= floor + 1e-4)


def test_evaluate_warns_about_a_snapshot_of_an_unfinished_run():
    """train-agent rewrites model.npz at every checkpoint; evaluating one from a run still
    in progress is easy to do by mistake, so evaluate says so (and its JSON records it)."""
    class Net:
        name = "D3RQN"

        def __init__(self, steps, total):
            self.meta = {"steps": steps, "train_config": {"steps": total}}
    assert models.unfinished_warning(Net(240000, 240000)) is None
    assert models.unfinished_warning(StraightPolicy()) is None
    msg = models.unfinished_warning(Net(160000, 240000))
    assert "snapshot at 160000 of its run's 240000" in msg


def test_recorded_result_picks_the_largest_matching_evaluation(tmp_path):
    model = tmp_path / "m.npz"
    rows = [{"scenario": "basic", "depth": "pred", "flights": 500, "seed": 1, "rate": 0.5,
             "ci95": [0.4, 0.6]},
            {"scenario": "basic", "depth": "pred", "flights": 2000, "seed": 1, "rate": 0.7,
             "ci95": [0.6, 0.8]},
            {"scenario": "basic", "depth": "gt", "flights": 4000, "seed": 1, "rate": 0.9,
             "ci95": [0.8, 1.0]},
            {"scenario": "basic", "depth": "pred", "flights": 4000, "seed": 1, "rate": 0.8,
             "ci95": [0.7, 0.9], "mirror": True},
            {"scenario": "basic", "depth": "pred", "flights": 2000, "seed": 1, "rate": 0.85,
             "ci95": [0.8, 0.9], "mirror": True, "flip_tta": True}]
    model.with_suffix(".json").write_text(json.dumps({"evaluations": rows}))
    # a plain flight is never shown a result flown with the mirror image or the flip
    assert models.recorded_result(model, "basic", "pred")["rate"] == 0.7
    assert models.recorded_result(model, "basic", "pred", mirror=True)["rate"] == 0.8
    assert models.recorded_result(model, "basic", "pred", mirror=True,
                                    flip_tta=True)["rate"] == 0.85
    assert models.recorded_result(model, "basic", "pred", flip_tta=True) is None
    assert models.recorded_result(model, "corners", "pred") is None
    assert models.recorded_result(tmp_path / "none.npz", "basic", "gt") is None


def test_recorded_text_gives_the_interval_by_world_when_the_row_has_it():
    row = {"rate": 0.7, "ci95": [0.68, 0.72], "flights": 2000, "seed": 1}
    old = models.recorded_text(row)
    assert "by flight" in old and "by world" not in old and "seed 1" in old
    new = models.recorded_text(dict(row, ci95_by_world=[0.65, 0.75], worlds=128))
    assert "[0.650, 0.750] by world (128 worlds)" in new and "[0.680, 0.720] by flight" in new
