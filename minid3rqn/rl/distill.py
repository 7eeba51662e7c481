"""Distillation from a privileged teacher: our addition, built on the paper's loop.

Why. A D3RQN trained long on ground-truth depth flies far better than the same net on
the DispNet's predicted depth (docs/results.md), and an ensemble of such nets better
still. Fine-tuning on predicted depth by Q-learning must rediscover, from rewards
alone, how to read the DispNet's errors. A teacher that sees the true depth can instead
*tell* the student, at every frame, how good each action is: "learning by cheating"
(Chen et al. 2019) and DAgger (Ross et al. 2011), with a Q-net as both teacher and
student (policy distillation, Rusu et al. 2016).

What. ``distil`` runs ``rl.train.train`` with its own steps 1 and 4:

    1. act: the teacher (a Q-net file or an ensemble, 'A.npz+B.npz+...') reads the GT
       depth of every flight (``DroneEnv.gt_depth``), carrying its own recurrent
       state through the flight; its Q-values Q_T(o_t, .) are stored in the replay
       beside the student's frame o_t (``LabelledReplay``). The flights fly the
       teacher's greedy action with probability beta, else the student's: beta falls
       linearly from ``teacher_mix`` to 0 over ``teacher_mix_steps`` transitions, so
       the student then learns in the states its own mistakes lead to (DAgger). No
       epsilon: the teacher's actions are the exploration.
    4. learn: on windows of L steps from a zero state, the student's Q-values of every
       action regress onto the teacher's,

           L_Q = mean over unmasked (t, b) and actions a of Huber(Q_S(o_t, a) - Q_T(o_t, a)),

       plus ``distil_kl`` times a KL term on the action preferences at temperature T
       (Hinton et al. 2015),

           L_KL = mean over unmasked (t, b) of sum_a p_T(a) [log p_T(a) - log p_S(a)],
           p_T = softmax(Q_T(o_t, .) / T),  p_S = softmax(Q_S(o_t, .) / T).

       The Huber loss spends its effort on Q-values, while in most states the teacher's
       best actions differ by a few hundredths, below the student's error; the KL term
       looks only at differences between actions. With ``mirror_augment`` each sampled
       window is seen in a left-right mirror with probability 1/2 (``rl.mirror``).

The student is a D3RQN like any other: ``evaluate`` and ``fly`` read its file unchanged.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..autograd.losses import huber_loss
from ..autograd.optim import clip_grad_norm
from ..config import (ConfigError, as_dict, at_least, between, flat_settings, positive,
                      setting, validate)
from .agent import AgentConfig
from .mirror import mirror_permutation, mirror_q, mirror_windows
from .replay import EpisodeReplay, SequenceBatch
from .train import Run, TrainConfig, start_run, train


def student() -> TrainConfig:
    """Our recipe's student (reproduce --recipe distil): the wide torso (conv channels
    8, 16, 16) and 256 LSTM units, Adam at 1e-4, on predicted depth; no epsilon."""
    return TrainConfig(steps=40_000, learning_starts=2_000, replay_capacity=60_000,
                       updates_per_step=4.0, hidden=256, conv_channels=[8, 16, 16],
                       depth="pred", eps_start=0.0, eps_end=0.0, agent=AgentConfig(lr=1e-4))


# The distil command's options; the other settings are given with --set NAME=VALUE.
DISTIL_OPTIONS = ("teachers", "init_model", "steps", "seed")


@dataclass
class DistilConfig:
    teachers: str = setting("", "the teacher: Q-net .npz files joined by '+', flown on GT "
                                "depth", source="run")
    teacher_mix: float = setting(0.5, "probability of flying the teacher's action at the "
                                      "start", check=between(0, 1))
    teacher_mix_steps: int = setting(20_000, "transitions over which it falls to 0",
                                     check=at_least(1))
    distil_kl: float = setting(1.0, "weight of the KL term (0: the Huber loss only)",
                               check=at_least(0))
    distil_temperature: float = setting(0.1, "temperature of the KL term, in Q-value units",
                                        check=positive)
    mirror_augment: bool = setting(True, "learn from each window mirrored with probability "
                                         "1/2")
    init_widen: bool = setting(False, "the init_model's LSTM is narrower than hidden: grow "
                                      "it (the same Q-values at the start)")
    train: TrainConfig = setting(default_factory=student)

    def __post_init__(self):
        validate(self)
        if self.init_widen and not self.train.init_model:
            raise ConfigError("init_widen", True, "false without --init-model (it grows "
                              "the --init-model's LSTM)")


@dataclass
class LabelledBatch(SequenceBatch):
    """Windows with the teacher's Q-values of each step's frame: labels (L, B, A)."""
    labels: np.ndarray | None = None


class LabelledReplay(EpisodeReplay):
    """``EpisodeReplay`` that also stores, for every frame, the teacher's Q-values of it.

    ``label_latest(q)`` labels the newest frame of every stream (o_t, before the action
    taken from it is added); ``sample`` returns them as ``batch.labels`` (L, B, A),
    aligned with ``batch.obs[:L]``, zero where the mask is.
    """

    def __init__(self, capacity: int, n_streams: int, frame_shape, n_actions: int, seed=None):
        super().__init__(capacity, n_streams, frame_shape, seed=seed)
        self.labels = np.zeros((self.n_streams, self.cap, int(n_actions)), dtype=np.float32)

    def label_latest(self, q: np.ndarray) -> None:
        q = np.asarray(q, dtype=np.float32)
        if q.shape != (self.n_streams, self.labels.shape[2]):
            raise ValueError(f"LabelledReplay.label_latest: q must be (n_streams, n_actions) = "
                             f"{(self.n_streams, self.labels.shape[2])}; got {q.shape}")
        if (self.open_start < 0).any():
            raise RuntimeError("LabelledReplay.label_latest: every stream needs an open "
                               "episode (start_episodes first)")
        self.labels[np.arange(self.n_streams), (self.count - 1) % self.cap] = q

    def _gather(self, streams, starts, L, stack) -> LabelledBatch:
        batch = super()._gather(streams, starts, L, stack)
        slot = (starts[:, None] + np.arange(L)[None, :]) % self.cap       # (B, L)
        labels = self.labels[streams[:, None], slot].transpose(1, 0, 2)   # (L, B, A)
        return LabelledBatch(**vars(batch), labels=labels * batch.mask[:, :, None])

    def state_dict(self) -> dict[str, np.ndarray]:
        return {**super().state_dict(), "labels": self.labels}


def load_teacher(spec: str, frame_shape, n_actions: int):
    """'A.npz' or 'A.npz+B.npz+...' -> a QNetPolicy or an EnsemblePolicy, checked to read
    frames of ``frame_shape`` and to score ``n_actions`` actions (ValueError otherwise)."""
    from .models import ensemble_members
    from .policies import EnsemblePolicy, QNetPolicy
    parts = ensemble_members(spec)
    if not spec or any(not p for p in parts):
        raise ValueError(f"teachers: expected Q-net .npz files joined by '+'; got {spec!r}")
    members = []
    for p in parts:
        if not Path(p).is_file():
            raise ValueError(f"teachers: {p!r} is not a file (expected a Q-net .npz from "
                             f"train-agent)")
        pol = QNetPolicy.load(p, name=Path(p).parent.name or Path(p).stem)
        cfg = pol.qnet.config
        got = ((cfg.height, cfg.width_px), cfg.n_actions)
        if got != (tuple(frame_shape), int(n_actions)):
            raise ValueError(f"teachers: {p!r} reads {got[0]} frames and scores {got[1]} "
                             f"actions; the student needs {tuple(frame_shape)} and {n_actions}")
        members.append(pol)
    return members[0] if len(members) == 1 else EnsemblePolicy(members, name="teacher")


def kl_term(q, labels: np.ndarray, mask: np.ndarray, temperature: float):
    """L_KL of the module docstring: q (L, B, A) the student's Q-values (a Tensor),
    labels (L, B, A) the teacher's, mask (L, B) the real (not padded) steps."""
    t = float(temperature)
    log_p_t = ag.log_softmax(ag.Tensor(labels.astype(q.dtype) / t), axis=-1).data
    w = np.exp(log_p_t) * mask[:, :, None].astype(q.dtype)   # p_T, 0 on padded steps
    log_p_s = ag.log_softmax(q * (1.0 / t), axis=-1)
    kl = ag.sum((log_p_s * -1.0 + log_p_t) * w)
    return kl * (1.0 / max(1.0, float(mask.sum())))


class Distillation:
    """Steps 1 and 4 of ``rl.train.train`` for a student of ``teacher`` (module
    docstring). ``aug_seed``: the mirror augmentation's generator."""

    def __init__(self, cfg: DistilConfig, teacher, actions, aug_seed):
        self.cfg, self.teacher = cfg, teacher
        self.mirror_of = mirror_permutation(actions) if cfg.mirror_augment else None
        self.aug_rng = np.random.default_rng(aug_seed)
        self.resumed = False

    def state_dict(self) -> dict[str, np.ndarray]:
        """The teacher's memory of the flights and the augmentation's generator."""
        state = {f"teacher.{k}": v for k, v in self.teacher.state_dict().items()}
        state["aug_rng"] = np.asarray(json.dumps(self.aug_rng.bit_generator.state))
        return state

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        self.teacher.load_state_dict({k[len("teacher."):]: v for k, v in state.items()
                                      if k.startswith("teacher.")})
        self.aug_rng.bit_generator.state = json.loads(str(state["aug_rng"]))
        self.resumed = True

    def mix_at(self, step: int) -> float:
        """beta: linear from ``teacher_mix`` to 0 over ``teacher_mix_steps`` transitions."""
        return self.cfg.teacher_mix * (1.0 - min(1.0, step / self.cfg.teacher_mix_steps))

    def act(self, run: Run) -> np.ndarray:
        started = run.env.steps == 0                     # flights that have just begun
        teacher_a = self.teacher.act(run.env.gt_depth(), started=started)
        run.replay.label_latest(self.teacher.last_q)     # Q_T(o_t, .)
        q, run.state = run.agent.q_values(run.stacker.obs, run.state)
        student_a = np.argmax(q, axis=1)
        beta = self.mix_at(run.steps)
        run.note("teacher_mix", beta)
        run.note("agree", np.mean(student_a == teacher_a))
        fly_teacher = run.rng.random(len(student_a)) < beta
        return np.where(fly_teacher, teacher_a, student_a).astype(np.int64)

    def learn(self, run: Run, batch: LabelledBatch) -> dict:
        """One Adam step on L_Q + distil_kl * L_KL (no target net: the teacher is one)."""
        labels = batch.labels
        if self.mirror_of is not None:
            which = self.aug_rng.random(batch.actions.shape[1]) < 0.5
            batch = mirror_windows(batch, which, self.mirror_of)
            labels = mirror_q(labels, which, self.mirror_of)
        agent = run.agent
        q = agent.online(batch.obs)[0][:labels.shape[0]]          # (L, B, A), with graph
        per = huber_loss(q, labels, delta=agent.config.huber_delta, reduction="none")
        mask = np.broadcast_to(batch.mask[:, :, None], labels.shape).astype(np.float32)
        loss = ag.sum(per * mask) * (1.0 / max(1.0, float(mask.sum())))
        if self.cfg.distil_kl > 0:
            kl = kl_term(q, labels, batch.mask, self.cfg.distil_temperature)
            run.note("kl", kl.data)
            loss = loss + kl * self.cfg.distil_kl
        agent.optimizer.zero_grad()
        loss.backward()
        clip_grad_norm(agent.online.parameters(), agent.config.grad_clip)
        agent.optimizer.step()
        agent.updates += 1
        return {"loss": float(loss.data),
                "q_mean": float((q.data * mask).sum() / max(1.0, mask.sum()))}


def _widen(agent, path) -> None:
    """Load a Q-net with a narrower LSTM into ``agent``, grown (``widen_recurrent_state``)."""
    from ..io import load_npz
    from ..nets.widen import widen_recurrent_state
    old, _ = load_npz(path)
    agent.online.load_state_dict(widen_recurrent_state(old, agent.online.state_dict()))


def distil(cfg: DistilConfig, out_dir, depth_estimator=None, *, progress: bool = True,
           resume: bool = False, settings: dict | None = None) -> Run:
    """Train ``cfg.train``'s student by distillation (module docstring) with
    ``rl.train.train``; returns the run. ``depth_estimator``: the student's DispNet
    (``cfg.train.depth="pred"``); a resumed run must share every setting of ``cfg``
    with its checkpoint, and ``settings`` (``rl.train.Run``)."""
    from ..world import ACTIONS, Camera
    t = cfg.train
    if not cfg.teachers:
        raise ValueError("distil: cfg.teachers is empty; give the teacher's Q-net file(s), "
                         "'A.npz' or 'A.npz+B.npz+...'")
    actions = np.asarray(ACTIONS if t.actions is None else t.actions, dtype=np.float64)
    cam = Camera(hfov_deg=t.hfov_deg)
    teacher = load_teacher(cfg.teachers, (cam.height, cam.width), len(actions))
    # the fifth stream of the run's seed (rl.train draws from the first four)
    steps = Distillation(cfg, teacher, actions, np.random.SeedSequence(t.seed).spawn(5)[4])

    def replay(capacity, n_streams, frame_shape, seed):
        return LabelledReplay(capacity, n_streams, frame_shape, len(actions), seed=seed)
    run = start_run(t, out_dir, depth_estimator, resume, replay=replay,
                    extra={"distillation": steps},
                    load_init=_widen if cfg.init_widen else None,
                    settings={**flat_settings(as_dict(cfg)), **(settings or {})})
    if not steps.resumed:                 # a resumed teacher has its memory back
        teacher.reset(run.env)
    return train(t, out_dir, progress=progress, run=run, act=steps.act, learn=steps.learn)
