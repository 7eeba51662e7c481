"""Distillation from a privileged teacher (rl/distill.py): labels, mixing, loss, resume, errors."""
import argparse
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.rl import commands
from minid3rqn.rl.agent import AgentConfig
from minid3rqn.rl.distill import Distiller, LabelledReplay, load_teacher
from minid3rqn.rl.flights import Flights, FlightsConfig
from minid3rqn.rl.train import TrainConfig, Trainer, train

pytestmark = pytest.mark.rl

ROOT = Path(__file__).resolve().parent.parent
TEACHER = str(ROOT / "minid3rqn" / "models" / "d3rqn_basic.npz")


def small_config(**kw) -> TrainConfig:
    base = dict(total_steps=96, learning_starts=32, n_envs=4, log_every=32, checkpoint_every=48,
                hidden=16, replay_capacity=1000, teachers=TEACHER, teacher_mix=0.5,
                teacher_mix_steps=64, flights=FlightsConfig(n_worlds=2))
    base.update(kw)
    return TrainConfig(**base)


def run_and_resume(cls, cfg, folder, until):
    """Run ``cls(cfg)`` to ``until``, checkpoint, resume a twin from the checkpoint, run
    both to the end and assert the same weights; return the first run."""
    a = cls(cfg, folder, progress=False)
    a.run(until=until)
    a.save_checkpoint()
    b = cls.resume(folder, progress=False)
    a.run()
    b.run()
    assert a.agent.updates > 0 and a.steps == cfg.total_steps
    for p, q in zip(a.agent.online.parameters(), b.agent.online.parameters()):
        np.testing.assert_array_equal(p.data, q.data)
    return a


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


def test_gt_frames_are_the_gt_observation_in_pred_mode():
    cfg = FlightsConfig(n_worlds=2)
    gt = Flights("basic", 3, seed=4, config=cfg, depth="gt")
    pred = Flights("basic", 3, seed=4, config=cfg, depth="pred", depth_estimator=_Flat())
    pred.reset()
    np.testing.assert_array_equal(pred.gt_frames(), gt.reset())
    a = np.array([1, 2, 0])
    gt.step(a)
    res = pred.step(a)
    assert np.allclose(res.frames, 0.5)                     # the student sees the estimator
    np.testing.assert_array_equal(pred.gt_frames(), gt.frames)


def test_full_teacher_mix_flies_the_teachers_actions(tmp_path):
    d = Distiller(small_config(teacher_mix=1.0, teacher_mix_steps=10 ** 9), tmp_path,
                  progress=False)
    d._start()
    d._started = True
    for _ in range(6):
        actions = d.choose_actions()
        np.testing.assert_array_equal(actions, np.argmax(d.teacher.last_q, axis=1))
        res = d.flights.step(actions)
        done = res.terminated | res.truncated
        d.replay.add_step(actions, res.rewards, res.terminated, res.truncated, res.final_frames)
        if done.any():
            d.replay.start_episodes(np.flatnonzero(done), res.frames[done])
            d.episodes_ended(done)
        d.stacker.push(res.frames)


def test_teacher_mix_decays_linearly_to_zero(tmp_path):
    d = Distiller(small_config(teacher_mix=0.8, teacher_mix_steps=100), tmp_path, progress=False)
    assert d.teacher_mix_at(0) == pytest.approx(0.8)
    assert d.teacher_mix_at(50) == pytest.approx(0.4)
    assert d.teacher_mix_at(100) == 0.0 and d.teacher_mix_at(10 ** 6) == 0.0


def test_distillation_lowers_the_loss_on_a_fixed_batch(tmp_path):
    """The update moves the student's Q-values toward the teacher's labels."""
    cfg = small_config(total_steps=64, learning_starts=10 ** 6, agent=AgentConfig(lr=1e-2))
    d = Distiller(cfg, tmp_path, progress=False)
    d.run()
    batch = d.replay.sample(8, seq_len=5)
    target = float((batch.labels * batch.mask[:, :, None]).sum() / (5 * batch.mask.sum()))
    losses, q_means = [], []
    for _ in range(25):
        info = d.learn(batch)
        losses.append(info["loss"])
        q_means.append(info["q_mean"])
    assert losses[-1] < losses[0]
    assert np.all(np.diff(losses) < 0)
    assert abs(q_means[-1] - target) < abs(q_means[0] - target)


def test_distillation_smoke_and_exact_resume(tmp_path):
    a = run_and_resume(Distiller, small_config(), tmp_path / "a", until=48)
    assert {"teacher_mix", "agree"} <= set(a.curve[-1])
    assert a.curve[-1]["teacher_mix"] == 0.0


def test_train_picks_the_distiller_and_plain_trainer_refuses_teachers(tmp_path):
    tr = train(small_config(total_steps=32, learning_starts=16), tmp_path, progress=False)
    assert isinstance(tr, Distiller)
    with pytest.raises(ValueError, match="Distiller"):
        Trainer(small_config(), tmp_path / "t", progress=False)


def test_bad_teachers_get_clear_errors(tmp_path):
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
    with pytest.raises(ValueError, match="teacher_mix"):
        Distiller(small_config(teacher_mix=1.5), tmp_path, progress=False)
    with pytest.raises(ValueError, match="teachers"):
        Distiller(small_config(teachers=""), tmp_path, progress=False)
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    args = p.parse_args(["--smoke", "--quiet", "--teachers", "random", "--out",
                         str(tmp_path / "cli")])
    with pytest.raises(SystemExit, match="--teachers.*not a file"):
        commands.run_train_agent(args)


def test_mirror_augmentation_is_seeded_resumable_and_leaves_other_runs_alone(tmp_path):
    """--mirror-augment: the run resumes exactly and repeats from its seed; it learns
    from mirrored windows (a different student from the same seed without it), and its
    random stream does not move the runs without it (they fly the same flights)."""
    a = run_and_resume(Distiller, small_config(mirror_augment=True), tmp_path / "a", until=48)
    assert a.mirror_of is not None
    assert Distiller.resume(tmp_path / "a", progress=False).cfg.mirror_augment
    plain = Distiller(small_config(), tmp_path / "p", progress=False)
    plain.run()
    assert plain.mirror_of is None
    assert any(not np.array_equal(p.data, q.data)
               for p, q in zip(a.agent.online.parameters(), plain.agent.online.parameters()))
    # the augmentation draws from a stream of its own: built from one seed, the two
    # runs start with the same weights and the same action and replay streams
    fresh = [Distiller(small_config(mirror_augment=m), tmp_path / f"f{m}", progress=False)
             for m in (False, True)]
    for p, q in zip(*(f.agent.online.parameters() for f in fresh)):
        np.testing.assert_array_equal(p.data, q.data)
    assert fresh[0].rng.bit_generator.state == fresh[1].rng.bit_generator.state
    assert fresh[0].replay.rng.bit_generator.state == fresh[1].replay.rng.bit_generator.state
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    args = p.parse_args(["--smoke", "--mirror-augment", "--out", str(tmp_path / "cli")])
    got = commands.config_from_args(args)
    assert got.mirror_augment and not got.teacher_mirror
    args = p.parse_args(["--smoke", "--teacher-mirror", "--out", str(tmp_path / "cli")])
    got = commands.config_from_args(args)
    assert got.teacher_mirror and not got.mirror_augment


def test_q_learning_with_mirror_augmentation_resumes_exactly(tmp_path):
    cfg = TrainConfig(total_steps=96, learning_starts=32, n_envs=4, log_every=32,
                      checkpoint_every=48, hidden=16, replay_capacity=1000,
                      mirror_augment=True, flights=FlightsConfig(n_worlds=2))
    run_and_resume(Trainer, cfg, tmp_path / "a", until=48)


def test_a_mirrored_teacher_is_the_nets_and_their_mirror_images(tmp_path):
    """--teacher-mirror: the teacher ensemble holds each net and its mirrored twin, so its
    Q-values on a mirrored view are its Q-values on the view, mirrored (exactly
    symmetric); the run resumes exactly with the twins' memories."""
    from minid3rqn.rl.policies import EnsemblePolicy, mirror_permutation
    from minid3rqn.world import ACTIONS
    shape, n = (32, 104), 5
    t = load_teacher(TEACHER, shape, n, mirror=True)
    assert isinstance(t, EnsemblePolicy) and len(t.members) == 2
    assert [m.mirror for m in t.members] == [False, True]
    assert len(load_teacher(TEACHER + "+" + TEACHER, shape, n, mirror=True).members) == 4
    perm = mirror_permutation(ACTIONS)
    frames = np.random.default_rng(0).random((3, 2, *shape)).astype(np.float32)
    a, b = (load_teacher(TEACHER, shape, n, mirror=True) for _ in range(2))
    a.reset(2)
    b.reset(2)
    for k in range(3):
        a.act({"frames": frames[k]}, started=np.full(2, k == 0))
        b.act({"frames": np.ascontiguousarray(frames[k][..., ::-1])},
              started=np.full(2, k == 0))
        np.testing.assert_allclose(b.last_q, a.last_q[:, perm], rtol=1e-5, atol=1e-6)
    run_and_resume(Distiller, small_config(teacher_mirror=True), tmp_path / "a", until=48)


def test_mirror_augmentation_needs_a_symmetric_action_table(tmp_path, monkeypatch):
    """A classroom action table without mirror images gets a clear error naming the flag."""
    import minid3rqn.rl.flights as flights_module
    monkeypatch.setattr(flights_module, "ACTIONS",
                        np.array([[2.0, 0.0], [2.0, 0.3], [2.0, 0.6]]))
    cfg = TrainConfig(total_steps=32, learning_starts=16, n_envs=2, hidden=16,
                      replay_capacity=200, mirror_augment=True,
                      flights=FlightsConfig(n_worlds=1))
    with pytest.raises(ValueError, match=r"--mirror-augment.*symmetric action table"):
        Trainer(cfg, tmp_path, progress=False)


def test_a_teacher_on_predicted_depth_reads_the_students_frames(tmp_path):
    """--teacher-depth pred: the labels are the teacher's Q-values of the student's own
    frame (here a stand-in DispNet's flat 5 m), not of the GT frame; the default reads
    GT. A teacher on predicted depth needs a student on it: clear errors otherwise."""
    def first_labels(teacher_depth):
        d = Distiller(small_config(depth="pred", teacher_depth=teacher_depth),
                      tmp_path / teacher_depth, depth_estimator=_Flat(), progress=False)
        d._start()
        d.choose_actions()
        return d, d.teacher.last_q.copy()

    d, got = first_labels("pred")
    assert np.allclose(d.stacker.obs[:, -1], 0.5)
    twin = load_teacher(TEACHER, d.frame_shape, d.flights.n_actions)
    twin.reset(d.cfg.n_envs)
    twin.act({"frames": d.stacker.obs[:, -1]}, started=np.ones(d.cfg.n_envs, bool))
    np.testing.assert_array_equal(got, twin.last_q)
    d_gt, got_gt = first_labels("gt")
    twin.reset(d.cfg.n_envs)
    twin.act({"frames": d_gt.flights.gt_frames()}, started=np.ones(d.cfg.n_envs, bool))
    np.testing.assert_array_equal(got_gt, twin.last_q)
    assert not np.allclose(got, got_gt)
    with pytest.raises(ValueError, match="teacher_depth is 'gt' or 'pred'"):
        Distiller(small_config(teacher_depth="GT"), tmp_path / "bad", progress=False)
    with pytest.raises(ValueError, match="teacher_depth='pred'.*depth='pred'.*'gt'"):
        Distiller(small_config(teacher_depth="pred"), tmp_path / "bad", progress=False)
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    args = p.parse_args(["--smoke", "--teachers", TEACHER, "--teacher-depth", "pred",
                         "--out", str(tmp_path / "cli")])
    with pytest.raises(SystemExit, match="--teacher-depth pred.*--depth pred; got.*--depth gt"):
        commands.config_from_args(args)
    args = p.parse_args(["--smoke", "--depth", "pred", "--teachers", TEACHER,
                         "--teacher-depth", "pred", "--out", str(tmp_path / "cli")])
    assert commands.config_from_args(args).teacher_depth == "pred"


def test_the_kl_term_sees_only_action_preferences_and_is_gradient_checked(tmp_path):
    """L_KL is 0 when the student prefers actions as the teacher does, whatever the Q-values'
    level; positive otherwise; padded steps count for nothing; its gradient is checked
    against central differences (float64)."""
    from minid3rqn import autograd as ag
    d = Distiller(small_config(distil_kl=1.0, distil_temperature=0.5), tmp_path, progress=False)
    rng = np.random.default_rng(0)
    labels = rng.normal(14.0, 1.0, (5, 3, 5))
    mask = np.ones((5, 3))
    mask[3:, 2] = 0.0                                   # an episode that ended early
    same = d.kl_term(ag.Tensor(labels - 3.0), labels, mask)
    assert abs(float(same.data)) < 1e-12
    q = rng.normal(14.0, 1.0, (5, 3, 5))
    assert float(d.kl_term(ag.Tensor(q), labels, mask).data) > 0
    q_pad = q.copy()
    q_pad[3:, 2] += rng.normal(0, 5.0, (2, 5))          # change only the padded steps
    assert float(d.kl_term(ag.Tensor(q_pad), labels, mask).data) == pytest.approx(
        float(d.kl_term(ag.Tensor(q), labels, mask).data))
    ag.gradcheck(lambda t: d.kl_term(t, labels, mask), [q])


def test_distillation_with_the_kl_term_lowers_it_on_a_fixed_batch(tmp_path):
    cfg = small_config(total_steps=64, learning_starts=10 ** 6, agent=AgentConfig(lr=1e-2),
                       distil_kl=1.0, distil_temperature=0.1)
    d = Distiller(cfg, tmp_path, progress=False)
    d.run()
    batch = d.replay.sample(8, seq_len=5)
    kls = [d.learn(batch)["kl"] for _ in range(25)]
    assert np.isfinite(kls).all() and kls[-1] < kls[0]


def test_distillation_with_the_kl_term_resumes_exactly(tmp_path):
    """The KL settings travel in the checkpoint: a resumed run ends on the same weights."""
    a = run_and_resume(Distiller, small_config(distil_kl=1.0, distil_temperature=0.1),
                       tmp_path / "a", until=48)
    assert a.cfg.distil_kl == 1.0
    assert np.isfinite(a.curve[-1]["kl"]) and a.curve[-1]["kl"] >= 0


def test_bad_kl_settings_get_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="distil_kl"):
        Distiller(small_config(distil_kl=-1.0), tmp_path, progress=False)
    with pytest.raises(ValueError, match="distil_temperature"):
        Distiller(small_config(distil_kl=1.0, distil_temperature=0.0), tmp_path, progress=False)
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    for argv, match in [(["--distil-kl", "1"], "needs --teachers"),
                        (["--teachers", TEACHER, "--distil-kl", "nan"], "weight >= 0"),
                        (["--teachers", TEACHER, "--distil-temperature", "-1"], "temperature > 0")]:
        args = p.parse_args(["--smoke", "--quiet", "--out", str(tmp_path / "cli"), *argv])
        with pytest.raises(SystemExit, match=match):
            commands.run_train_agent(args)


def test_window_length_and_batch_size_are_settable_and_checked(tmp_path, monkeypatch):
    """``--seq-len`` and ``--batch-size`` reach the replay's sampler; bad values are named."""
    d = Distiller(small_config(seq_len=9, batch_size=3, total_steps=64), tmp_path, progress=False)
    seen = []
    sample = d.replay.sample
    monkeypatch.setattr(d.replay, "sample",
                        lambda *a, **k: seen.append(a) or sample(*a, **k))
    d.run()
    assert d.agent.updates > 0 and seen and all(a[:2] == (3, 9) for a in seen)
    for name, flag in (("seq_len", "--seq-len"), ("batch_size", "--batch-size")):
        for bad in (0, -1, 2.5, True):
            with pytest.raises(ValueError, match=f"{name}.*{flag}.*got"):
                Distiller(small_config(**{name: bad}), tmp_path / "bad", progress=False)
    p = argparse.ArgumentParser()
    commands.add_arguments_train_agent(p)
    for flag in ("--seq-len", "--batch-size"):
        args = p.parse_args(["--smoke", flag, "0", "--out", str(tmp_path / "cli")])
        with pytest.raises(SystemExit, match=f"{flag}.*0"):
            commands.config_from_args(args)
    args = p.parse_args(["--smoke", "--seq-len", "10", "--batch-size", "16"])
    cfg = commands.config_from_args(args)
    assert (cfg.seq_len, cfg.batch_size) == (10, 16)
