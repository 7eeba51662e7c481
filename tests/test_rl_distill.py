"""Distillation from a privileged teacher (rl/distill.py): labels, mixing, loss, resume,
errors; and growing a net's LSTM with the same Q-values (``init_widen``; nets/qnet.py)."""
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.cli import main
from minid3rqn.config import ConfigError
from minid3rqn.rl.agent import AgentConfig
from minid3rqn.rl.distill import (DistilConfig, Distillation, LabelledReplay, distil, kl_term,
                                  load_teacher)
from minid3rqn.rl.observe import encode_depth
from minid3rqn.world import DroneEnv
from minid3rqn.rl.train import TrainConfig, start_run
from minid3rqn.world import ACTIONS

pytestmark = pytest.mark.rl

ROOT = Path(__file__).resolve().parent.parent
TEACHER = str(ROOT / "minid3rqn" / "models" / "d3rqn_basic.npz")
STUDENT = dict(steps=96, learning_starts=32, n_envs=4, log_every=32, checkpoint_every=48,
               hidden=16, replay_capacity=1000, n_worlds=2, depth="gt", conv_channels=None)


def small_config(train=None, **kw) -> DistilConfig:
    base = dict(teachers=TEACHER, teacher_mix=0.5, teacher_mix_steps=64, distil_kl=0.0,
                mirror_augment=False)
    return DistilConfig(**{**base, **kw}, train=replace(TrainConfig(), **{**STUDENT,
                                                                         **(train or {})}))


def weights(run) -> list:
    return [p.data for p in run.agent.online.parameters()]


def run_and_resume(cfg, folder, until):
    """Distil ``cfg`` to ``until`` transitions, then resume it to the end from its
    checkpoint; assert the same weights as a run made in one go; return that run."""
    distil(replace(cfg, train=replace(cfg.train, steps=until)), folder / "cut",
           progress=False)
    b = distil(cfg, folder / "cut", progress=False, resume=True)
    a = distil(cfg, folder / "whole", progress=False)
    assert a.agent.updates > 0 and a.steps == cfg.train.steps
    for p, q in zip(weights(a), weights(b)):
        np.testing.assert_array_equal(p, q)
    return a


def distillation(cfg: DistilConfig, folder, depth_estimator=None):
    """A distillation's run, started, and its steps (what ``distil`` hands the loop)."""
    from minid3rqn.rl import distill
    teacher = load_teacher(cfg.teachers, (32, 104), 5)
    steps = Distillation(cfg, teacher, ACTIONS, 7)
    run = start_run(cfg.train, folder, depth_estimator,
                    replay=lambda c, n, s, seed: distill.LabelledReplay(c, n, s, 5, seed=seed))
    teacher.reset(run.env)
    return run, steps


def test_labelled_replay_labels_stay_with_their_frames():
    """Frame k carries label k, through episode ends and ring wrap-around."""
    rng = np.random.default_rng(0)
    rep = LabelledReplay(capacity=48, n_streams=2, frame_shape=(2, 3), n_actions=5, seed=1)
    k = 1

    def frame_and_label():
        nonlocal k
        f = np.full((2, 2, 3), 0.0, np.float32)
        f[0], f[1] = k / 255.0, (k + 1) / 255.0
        q = np.stack([np.full(5, k, np.float32), np.full(5, k + 1, np.float32)])
        k = (k + 2) % 250 + 1
        return f, q

    f, q = frame_and_label()
    rep.start_episodes([0, 1], f)
    for t in range(80):
        rep.label_latest(q)
        f, q = frame_and_label()
        done = rng.random(2) < 0.15
        rep.add_step(np.zeros(2, np.int64), np.zeros(2), done, np.zeros(2, bool), f)
        if done.any():
            idx = np.flatnonzero(done)
            f2, q2 = frame_and_label()
            f[idx], q[idx] = f2[idx], q2[idx]
            rep.start_episodes(idx, f2[idx])
    batch = rep.sample(64, seq_len=5)
    frame_id = np.rint(batch.obs[:5, :, 0, 0, 0] * 255.0)          # (L, B)
    ok = batch.mask > 0
    assert ok.sum() > 100
    np.testing.assert_array_equal(batch.labels[..., 0][ok], frame_id[ok])
    assert np.all(batch.labels[~ok] == 0)
    with pytest.raises(ValueError, match="n_streams, n_actions"):
        rep.label_latest(np.zeros((3, 5)))


class _Flat:
    """A stand-in depth estimator: 5 m everywhere."""

    def predict(self, rgb):
        return np.full(rgb.shape[:3], 5.0, np.float32)


def test_gt_depth_is_the_gt_observation_in_pred_mode():
    gt = DroneEnv("basic", 3, seed=4, n_worlds=2, observation="depth")
    pred = DroneEnv("basic", 3, seed=4, n_worlds=2, observation="pred", depth_model=_Flat())
    pred.reset()
    np.testing.assert_array_equal(pred.gt_depth(), gt.reset()[0])
    a = np.array([1, 2, 0])
    seen = gt.step(a)[0]
    obs = pred.step(a)[0]
    assert np.allclose(obs, 5.0)                            # the student sees the estimator
    np.testing.assert_array_equal(pred.gt_depth(), seen)


def test_full_teacher_mix_flies_the_teachers_actions(tmp_path):
    run, steps = distillation(small_config(teacher_mix=1.0, teacher_mix_steps=10 ** 9),
                              tmp_path)
    for _ in range(6):
        actions = steps.act(run)
        np.testing.assert_array_equal(actions, np.argmax(steps.teacher.last_q, axis=1))
        obs, rewards, terminated, truncated, info = run.env.step(actions)
        done = terminated | truncated
        frames = encode_depth(obs)
        run.replay.add_step(actions, rewards, terminated, truncated,
                            encode_depth(info["final_obs"]))
        if done.any():
            run.replay.start_episodes(np.flatnonzero(done), frames[done])
            run.state = run.agent.reset_state(run.state, done)
        run.stacker.push(frames)


def test_teacher_mix_decays_linearly_to_zero(tmp_path):
    _, steps = distillation(small_config(teacher_mix=0.8, teacher_mix_steps=100), tmp_path)
    assert steps.mix_at(0) == pytest.approx(0.8)
    assert steps.mix_at(50) == pytest.approx(0.4)
    assert steps.mix_at(100) == 0.0 and steps.mix_at(10 ** 6) == 0.0


def _filled(cfg, folder):
    """A distillation run whose replay holds 64 transitions, not yet learned from."""
    run = distil(replace(cfg, train=replace(cfg.train, steps=64, learning_starts=10 ** 6)),
                 folder, progress=False)
    _, steps = distillation(cfg, folder / "twin")
    return run, steps


def test_distillation_lowers_the_loss_on_a_fixed_batch(tmp_path):
    """The update moves the student's Q-values toward the teacher's labels."""
    cfg = small_config(train={"agent": AgentConfig(lr=1e-2)})
    run, steps = _filled(cfg, tmp_path)
    batch = run.replay.sample(8, seq_len=5)
    target = float((batch.labels * batch.mask[:, :, None]).sum() / (5 * batch.mask.sum()))
    losses, q_means = [], []
    for _ in range(25):
        info = steps.learn(run, batch)
        losses.append(info["loss"])
        q_means.append(info["q_mean"])
    assert losses[-1] < losses[0]
    assert np.all(np.diff(losses) < 0)
    assert abs(q_means[-1] - target) < abs(q_means[0] - target)


def test_distillation_smoke_and_exact_resume(tmp_path):
    a = run_and_resume(small_config(), tmp_path, until=48)
    assert {"teacher_mix", "agree"} <= set(a.curve[-1])


def test_bad_teachers_and_settings_get_clear_errors(tmp_path, capsys):
    shape, n = (32, 104), 5
    with pytest.raises(ValueError, match="not a file"):
        load_teacher(str(tmp_path / "missing.npz"), shape, n)
    with pytest.raises(ValueError, match="joined by"):
        load_teacher(TEACHER + "+", shape, n)
    with pytest.raises(ValueError, match="not a file"):
        load_teacher("random", shape, n)
    with pytest.raises(ValueError, match="actions"):
        load_teacher(TEACHER, shape, 7)
    assert load_teacher(TEACHER + "+" + TEACHER, shape, n).name == "teacher"
    for bad, name in (({"teacher_mix": 1.5}, "teacher_mix"),
                      ({"teacher_mix_steps": 0}, "teacher_mix_steps"),
                      ({"distil_kl": -1.0}, "distil_kl"),
                      ({"distil_kl": float("nan")}, "distil_kl"),
                      ({"distil_temperature": 0.0}, "distil_temperature")):
        with pytest.raises(ConfigError, match=name):
            small_config(**bad)
    with pytest.raises(ValueError, match="teachers is empty"):
        distil(small_config(teachers=""), tmp_path, progress=False)
    for argv, says in ((["--teachers", "random"], "--teachers: 'random' is not a file"),
                       (["--teachers", TEACHER, "--set", "distil_kl=-1"],
                        "--set distil_kl: expected a number >= 0"),
                       (["--teachers", TEACHER, "--set", "distil_temperature=-1"],
                        "--set distil_temperature: expected a number > 0"),
                       (["--teachers", TEACHER, "--set", "init_widen=true"],
                        "init_widen.*--init-model")):
        assert main(["distil", "--smoke", "--out", str(tmp_path / "cli"), *argv]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and re.search(says, err), err


def test_mirror_augmentation_is_seeded_resumable_and_leaves_other_runs_alone(tmp_path):
    """mirror_augment: the run resumes exactly and repeats from its seed; it learns from
    mirrored windows (a different student from the same seed without it); its generator
    is a stream of its own, so until the first update both runs fly the same flights."""
    a = run_and_resume(small_config(mirror_augment=True), tmp_path / "a", until=48)
    plain = distil(small_config(), tmp_path / "p", progress=False)
    assert any(not np.array_equal(p, q) for p, q in zip(weights(a), weights(plain)))
    assert a.curve[0]["agree"] == plain.curve[0]["agree"]         # before learning starts


def test_mirror_augmentation_needs_a_symmetric_action_table(tmp_path):
    """A classroom action table without mirror images gets a clear error."""
    table = [[2.0, 0.0], [2.0, 0.3], [2.0, 0.6]]
    teacher = str(tmp_path / "three.npz")
    from minid3rqn.nets.qnet import QNet, QNetConfig
    QNet(QNetConfig(n_actions=3, width=8), rng=0).save(
        teacher, {"kind": "qnet", "qnet_config": QNetConfig(n_actions=3, width=8).to_dict(),
                  "train_config": {"actions": table}})
    cfg = small_config(teachers=teacher, mirror_augment=True, train={"actions": table})
    with pytest.raises(ValueError, match="no mirror image"):
        distil(cfg, tmp_path / "run", progress=False)


def test_the_kl_term_sees_only_action_preferences_and_is_gradient_checked():
    """L_KL is 0 when the student prefers actions as the teacher does, whatever the Q-values'
    level; positive otherwise; padded steps count for nothing; its gradient is checked
    against central differences (float64)."""
    from minid3rqn import autograd as ag
    rng = np.random.default_rng(0)
    labels = rng.normal(14.0, 1.0, (5, 3, 5))
    mask = np.ones((5, 3))
    mask[3:, 2] = 0.0                                   # an episode that ended early
    same = kl_term(ag.Tensor(labels - 3.0), labels, mask, 0.5)
    assert abs(float(same.data)) < 1e-12
    q = rng.normal(14.0, 1.0, (5, 3, 5))
    assert float(kl_term(ag.Tensor(q), labels, mask, 0.5).data) > 0
    q_pad = q.copy()
    q_pad[3:, 2] += rng.normal(0, 5.0, (2, 5))          # change only the padded steps
    assert float(kl_term(ag.Tensor(q_pad), labels, mask, 0.5).data) == pytest.approx(
        float(kl_term(ag.Tensor(q), labels, mask, 0.5).data))
    ag.gradcheck(lambda t: kl_term(t, labels, mask, 0.5), [q])


def test_distillation_with_the_kl_term_lowers_it_on_a_fixed_batch(tmp_path):
    cfg = small_config(distil_kl=1.0, distil_temperature=0.1,
                       train={"agent": AgentConfig(lr=1e-2)})
    run, steps = _filled(cfg, tmp_path)
    batch = run.replay.sample(8, seq_len=5)
    kls = []
    for _ in range(25):
        steps.learn(run, batch)
        kls.append(run.notes["kl"][-1])
    assert np.isfinite(kls).all() and kls[-1] < kls[0]


def test_distillation_with_the_kl_term_resumes_exactly(tmp_path):
    a = run_and_resume(small_config(distil_kl=1.0, distil_temperature=0.1), tmp_path,
                       until=48)
    assert np.isfinite(a.curve[-1]["kl"]) and a.curve[-1]["kl"] >= 0


def test_window_length_and_batch_size_reach_the_sampler(tmp_path, monkeypatch):
    """``--seq-len`` and ``--batch-size`` reach the replay's sampler."""
    from minid3rqn.rl import distill
    seen = []
    sample = distill.LabelledReplay.sample
    monkeypatch.setattr(distill.LabelledReplay, "sample",
                        lambda self, *a, **k: seen.append(a) or sample(self, *a, **k))
    run = distil(small_config(train={"seq_len": 9, "batch_size": 3, "steps": 64}), tmp_path,
                 progress=False)
    assert run.agent.updates > 0 and seen and all(a[:2] == (3, 9) for a in seen)


def test_the_distil_command_records_the_command_that_makes_it(tmp_path):
    out = tmp_path / "cli"
    assert main(["distil", "--smoke", "--teachers", TEACHER, "--out", str(out)]) == 0
    from minid3rqn.io import load_npz
    meta = load_npz(out / "model.npz")[1]
    assert meta["command"].startswith(f"python -m minid3rqn distil --teachers {TEACHER} ")
    assert meta["train_config"]["hidden"] == 16 and meta["train_config"]["depth"] == "pred"


# -- growing the LSTM (stage 1 of our recipe) ------------------------------------------------
def _qnet(width, variant="d3rqn", seed=0, convs=None):
    from minid3rqn.nets.qnet import QNet, QNetConfig
    extra = {"convs": convs} if convs else {}
    return QNet(QNetConfig.for_variant(variant, height=32, width_px=104, n_actions=5,
                                       width=width, **extra), rng=seed)


@pytest.mark.parametrize("variant", ["d3rqn", "ddrqn"])
def test_a_widened_net_starts_with_the_same_q_values_and_can_learn(variant):
    from minid3rqn import autograd as ag
    from minid3rqn.nets.widen import widen_recurrent_state
    narrow, wide = _qnet(8, variant, seed=1), _qnet(13, variant, seed=2)
    wide.load_state_dict(widen_recurrent_state(narrow.state_dict(), wide.state_dict()))
    obs = np.random.default_rng(3).random((6, 2, 1, 32, 104)).astype(np.float32)
    q0, _ = narrow(obs)
    q1, (h, _) = wide(obs)
    np.testing.assert_allclose(q1.data, q0.data, rtol=1e-5, atol=1e-6)
    assert np.abs(h.data[:, 8:]).max() > 0          # the new units run ...
    ag.sum(q1 * q1).backward()                      # ... and their path to the heads opens
    head = wide.advantage if variant == "d3rqn" else wide.q_head
    assert np.abs(head.weight.grad[:, 8:]).max() > 0


def test_widening_refuses_what_it_cannot_do(tmp_path):
    from minid3rqn.nets.widen import widen_recurrent_state
    wide = _qnet(16)
    with pytest.raises(ValueError, match="at least as wide.*16.*got 8"):
        widen_recurrent_state(wide.state_dict(), _qnet(8).state_dict())
    with pytest.raises(ValueError, match="only a recurrent"):
        widen_recurrent_state(_qnet(8, "d3qn").state_dict(), _qnet(16, "d3qn").state_dict())
    other = _qnet(16, convs=[[4, 4, 2], [8, 4, 2], [6, 3, 1]])
    with pytest.raises(ValueError, match="only the LSTM may be wider|LSTM's input"):
        widen_recurrent_state(_qnet(8).state_dict(), other.state_dict())


def test_distilling_from_a_widened_net(tmp_path):
    """A run from a widened init_model starts from its Q-values and resumes exactly."""
    narrow = tmp_path / "narrow.npz"
    _qnet(8).save(narrow, {"kind": "qnet"})
    cfg = small_config(init_widen=True, train={"init_model": str(narrow)})
    from minid3rqn.rl.distill import _widen
    run = start_run(cfg.train, tmp_path / "first", load_init=_widen)
    obs = np.random.default_rng(0).random((3, 2, 1, 32, 104)).astype(np.float32)
    np.testing.assert_allclose(run.agent.online(obs)[0].data, _qnet(8)(obs)[0].data,
                               rtol=1e-5, atol=1e-6)
    run_and_resume(cfg, tmp_path, until=48)
    wide = tmp_path / "wide.npz"
    _qnet(32).save(wide, {"kind": "qnet"})          # wider than the student's 16 units
    with pytest.raises(ValueError, match="at least as wide"):
        distil(small_config(init_widen=True, train={"init_model": str(wide)}),
               tmp_path / "bad", progress=False)


def test_a_run_without_a_bar_prints_one_line_per_checkpoint(tmp_path, capsys):
    """With no progress bar (reproduce's parallel runs, a log file) a run still says how far
    it is: its folder, steps of the total and the success so far, at each checkpoint."""
    distil(small_config(), tmp_path / "quiet_run", progress=False)
    lines = [l for l in capsys.readouterr().out.splitlines() if l.startswith("quiet_run: ")]
    assert [l.split()[1] for l in lines] == ["48/96", "96/96"]
    assert all("success" in l and l.endswith(" s") for l in lines)
