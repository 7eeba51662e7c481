"""Distillation from a privileged teacher: our addition, not the paper's method.

Why. A D3RQN trained long on ground-truth depth flies far better than the same net on
the DispNet's predicted depth (docs/results.md: 0.95 against 0.87 in ``basic``), and
an ensemble of five such nets better still (0.97). Fine-tuning on predicted depth by
Q-learning (the shipped recipe) must rediscover, from rewards alone, how to read the
DispNet's errors. A teacher that sees the true depth can instead *tell* the student,
at every frame, how good each action is. This is the idea behind "learning by
cheating" (Chen et al. 2019) and DAgger (Ross et al. 2011), with a Q-net as both
teacher and student (policy distillation, Rusu et al. 2016).

What. Flights are flown exactly as in Q-learning (``rl.train``), with two changes:

    1. the teacher (one Q-net file or an ensemble, 'A.npz+B.npz+...') reads the GT depth
       frame of every flight at every step (``Flights.gt_frames``), carrying its own
       recurrent state through the flight, and its Q-values Q_T(o_t, .) are stored in
       the replay beside the student's predicted-depth frame o_t (``LabelledReplay``);
    2. the flights fly the teacher's greedy action with probability beta (the "mix"),
       else the student's: beta falls linearly from ``teacher_mix`` to 0 over
       ``teacher_mix_steps`` transitions. At first the data follows the teacher's
       flights; later the student's own, so it learns what to do in the states *its*
       mistakes lead to (DAgger). There is no epsilon-greedy exploration (the
       ``eps_*`` settings are unused): the teacher's actions are the exploration.

A variant (``teacher_depth="pred"``, ours): the teacher reads the student's own
predicted-depth frame instead of the GT one. The teacher is then not privileged: it is
a set of nets that already fly on predicted depth (say, several students and their
mirror images), and the student learns to fly as their ensemble does in one pass.

A second variant (``base_teachers``, ours): in a mixed pool (``FlightsConfig.scene_mix`` <
1, some worlds built with ``scene``, the rest the scenario as it is) each kind of world
can have its own teacher, as in multi-task policy distillation (Rusu et al. 2016), where
every task's expert labels that task's data: ``teachers`` label the flights in the
changed worlds, ``base_teachers`` those in the scenario's own. Both fly every flight and
carry their recurrent state through it (simple, at twice a teacher's cost); each
flight keeps the labels and actions of its own world's teacher
(``Flights.in_changed_world``).

The update replaces the double-Q loss: on a window of L = 5 steps from a zero state
(as in Q-learning, ``rl.agent``), the student's Q-values of every action regress onto
the teacher's:

    L = mean over unmasked (t, b) and actions a of Huber(Q_S(o_t, a) - Q_T(o_t, a))

A second term, optional (``distil_kl`` > 0, ours): the Huber loss spends most of its
effort on Q-values, and in most states of ``basic`` the teacher's best and second-best
actions differ by a few hundredths (median 0.04 on Q-values near 14), far below the
student's typical error; the greedy action, the only thing a flight uses, is then
barely constrained. The KL divergence between the teacher's and the student's action
preferences at temperature T (Hinton et al. 2015; Rusu et al. 2016),

    L_KL = mean over unmasked (t, b) of sum_a p_T(a) [log p_T(a) - log p_S(a)],
    p_T = softmax(Q_T(o_t, .) / T),  p_S = softmax(Q_S(o_t, .) / T),

looks only at differences between actions, and weighs them by how much they differ
compared with T: near-ties stay soft, clear preferences become near-certain targets.
The loss is then L + distil_kl * L_KL.

Rewards are still stored (the learning curve reports them) but not learned from. The
student is a D3RQN like any other: ``evaluate`` and ``fly`` read its file unchanged.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..autograd.losses import huber_loss
from ..autograd.optim import clip_grad_norm
from .replay import EpisodeReplay
from .train import TrainConfig, Trainer


class LabelledReplay(EpisodeReplay):
    """``EpisodeReplay`` that also stores, for every frame, the teacher's Q-values of it.

    ``label_latest(q)`` labels the newest frame of every stream (o_t, before the action
    taken from it is added); ``sample`` returns them as ``batch.labels`` (L, B, A),
    aligned with ``batch.obs[:L]``.
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

    def _gather(self, streams, starts, L, stack):
        batch = super()._gather(streams, starts, L, stack)
        slot = (starts[:, None] + np.arange(L)[None, :]) % self.cap       # (B, L)
        labels = self.labels[streams[:, None], slot].transpose(1, 0, 2)   # (L, B, A)
        batch.labels = labels * batch.mask[:, :, None]
        return batch

    def state_dict(self) -> dict[str, np.ndarray]:
        return {**super().state_dict(), "labels": self.labels}


def load_teacher(spec: str, frame_shape, n_actions: int, mirror: bool = False):
    """'A.npz' or 'A.npz+B.npz+...' -> a QNetPolicy or an EnsemblePolicy, checked to
    read frames of ``frame_shape`` and to score ``n_actions`` actions.

    ``mirror``: every net also flies the mirrored view (``QNetPolicy.mirrored``), and the
    teacher is the ensemble of all of them, twice as many members (``evaluate --mirror``
    for a teacher; our addition)."""
    from .policies import EnsemblePolicy, QNetPolicy
    parts = str(spec).split("+")
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
    if mirror:
        members += [m.mirrored() for m in members]
    return members[0] if len(members) == 1 else EnsemblePolicy(members, name="teacher")


class Distiller(Trainer):
    """``Trainer`` whose student learns the teacher's Q-values; see the module docstring."""

    learns_from_teacher = True

    def __init__(self, cfg: TrainConfig, out_dir, depth_estimator=None, progress: bool = True):
        if not cfg.teachers:
            raise ValueError("Distiller: cfg.teachers is empty; give the teacher's Q-net "
                             "file(s), 'A.npz' or 'A.npz+B.npz+...'")
        if not 0.0 <= cfg.teacher_mix <= 1.0:
            raise ValueError(f"Distiller: teacher_mix is a probability in [0, 1]; got "
                             f"{cfg.teacher_mix}")
        if cfg.teacher_mix_steps < 1:
            raise ValueError(f"Distiller: teacher_mix_steps must be >= 1; got "
                             f"{cfg.teacher_mix_steps}")
        if cfg.teacher_depth not in ("gt", "pred"):
            raise ValueError(f"Distiller: teacher_depth is 'gt' or 'pred'; got "
                             f"{cfg.teacher_depth!r}")
        if not (np.isfinite(cfg.distil_kl) and cfg.distil_kl >= 0):
            raise ValueError(f"Distiller: distil_kl (--distil-kl) is a weight >= 0; got "
                             f"{cfg.distil_kl!r}")
        if not (np.isfinite(cfg.distil_temperature) and cfg.distil_temperature > 0):
            raise ValueError(f"Distiller: distil_temperature (--distil-temperature) is a "
                             f"temperature > 0 in Q-value units; got {cfg.distil_temperature!r}")
        if cfg.teacher_depth == "pred" and cfg.depth != "pred":
            raise ValueError("Distiller: teacher_depth='pred' gives the teacher the student's "
                             f"predicted-depth frames, so it needs depth='pred'; got "
                             f"depth={cfg.depth!r}")
        if cfg.base_teachers and not (cfg.flights.scene and cfg.flights.scene_mix < 1.0):
            raise ValueError(f"Distiller: base_teachers (--base-teachers) teach in the "
                             f"scenario's own worlds of a mixed pool, so they need "
                             f"flights.scene set and flights.scene_mix < 1; got scene="
                             f"{cfg.flights.scene!r}, scene_mix={cfg.flights.scene_mix!r}")
        super().__init__(cfg, out_dir, depth_estimator, progress)
        self.teacher = load_teacher(cfg.teachers, self.frame_shape, self.flights.n_actions,
                                    mirror=cfg.teacher_mirror)
        self.teacher.reset(cfg.n_envs)
        self.base_teacher = None                     # the second teacher of a mixed pool
        if cfg.base_teachers:
            self.base_teacher = load_teacher(cfg.base_teachers, self.frame_shape,
                                             self.flights.n_actions, mirror=cfg.teacher_mirror)
            self.base_teacher.reset(cfg.n_envs)
        self.teacher_started = np.ones(cfg.n_envs, bool)
        self._window["agree"] = []

    def make_replay(self, seed) -> LabelledReplay:
        return LabelledReplay(self.cfg.replay_capacity, self.cfg.n_envs, self.frame_shape,
                              self.flights.n_actions, seed=seed)

    def teacher_mix_at(self, step: int) -> float:
        """beta: linear from ``teacher_mix`` to 0 over ``teacher_mix_steps`` transitions."""
        frac = min(1.0, step / self.cfg.teacher_mix_steps)
        return self.cfg.teacher_mix * (1.0 - frac)

    # -- the loop (rl.train.Trainer.vector_step calls these) -------------------------
    def choose_actions(self) -> np.ndarray:
        if self.cfg.teacher_depth == "gt":
            seen = self.flights.gt_frames()
        else:                                                  # the student's current frame
            seen = self.stacker.obs[:, -1]
        teacher_a = self.teacher.act({"frames": seen}, started=self.teacher_started)
        teacher_q = self.teacher.last_q
        if self.base_teacher is not None:                      # each world its own teacher
            base_a = self.base_teacher.act({"frames": seen}, started=self.teacher_started)
            base = ~self.flights.in_changed_world()
            teacher_a = np.where(base, base_a, teacher_a)
            teacher_q = np.where(base[:, None], self.base_teacher.last_q, teacher_q)
        self.teacher_started[:] = False
        self.replay.label_latest(teacher_q)                    # Q_T(o_t, .)
        q, self.state = self.agent.q_values(self.stacker.obs, self.state)
        student_a = np.argmax(q, axis=1)
        self._window["agree"].append(float(np.mean(student_a == teacher_a)))
        fly_teacher = self.rng.random(len(student_a)) < self.teacher_mix_at(self.steps)
        return np.where(fly_teacher, teacher_a, student_a).astype(np.int64)

    def episodes_ended(self, done: np.ndarray) -> None:
        super().episodes_ended(done)
        self.teacher_started |= np.asarray(done, bool)

    def learn(self, batch) -> dict:
        """One step of the distillation loss (module docstring) with Adam."""
        L = batch.labels.shape[0]
        q_all, _ = self.agent.online(batch.obs)                  # (L+1, B, A), with graph
        q = q_all[:L]
        per = huber_loss(q, batch.labels, delta=self.agent.config.huber_delta, reduction="none")
        mask = np.broadcast_to(batch.mask[:, :, None], batch.labels.shape).astype(np.float32)
        loss = ag.sum(per * mask) * (1.0 / max(1.0, float(mask.sum())))
        info = {}
        if self.cfg.distil_kl > 0:
            kl = self.kl_term(q, batch.labels, batch.mask)
            info["kl"] = float(kl.data)
            self._window.setdefault("kl", []).append(info["kl"])
            loss = loss + kl * self.cfg.distil_kl
        opt = self.agent.optimizer
        opt.zero_grad()
        loss.backward()
        grad_norm = clip_grad_norm(self.agent.online.parameters(), self.agent.config.grad_clip)
        opt.step()
        self.agent.updates += 1
        q_mean = float((q.data * mask).sum() / max(1.0, mask.sum()))
        return {"loss": float(loss.data), "q_mean": q_mean, "grad_norm": grad_norm, **info}

    def kl_term(self, q, labels: np.ndarray, mask: np.ndarray):
        """L_KL of the module docstring: q (L, B, A) the student's Q-values (a Tensor),
        labels (L, B, A) the teacher's, mask (L, B) the real (not padded) steps."""
        t = float(self.cfg.distil_temperature)
        log_p_t = ag.log_softmax(ag.Tensor(labels.astype(q.dtype) / t), axis=-1).data
        w = np.exp(log_p_t) * mask[:, :, None].astype(q.dtype)   # p_T, 0 on padded steps
        log_p_s = ag.log_softmax(q * (1.0 / t), axis=-1)
        kl = ag.sum((log_p_s * -1.0 + log_p_t) * w)
        return kl * (1.0 / max(1.0, float(mask.sum())))

    # -- the learning curve and the checkpoint --------------------------------------
    def extra_row(self) -> dict:
        agree = self._window.get("agree", [])
        row = {"epsilon": 0.0, "teacher_mix": round(self.teacher_mix_at(self.steps), 4),
               "agree": float(np.mean(agree)) if agree else float("nan")}
        if self.cfg.distil_kl > 0:                       # L_KL alone (loss has L + W L_KL)
            kl = self._window.get("kl", [])
            row["kl"] = float(np.mean(kl)) if kl else float("nan")
        return row

    def extra_state(self) -> dict[str, np.ndarray]:
        state = {f"teacher.{k}": v for k, v in self.teacher.state_dict().items()}
        if self.base_teacher is not None:
            state.update({f"base_teacher.{k}": v
                          for k, v in self.base_teacher.state_dict().items()})
        state["teacher_started"] = self.teacher_started.copy()
        return state

    def load_extra_state(self, arrays: dict[str, np.ndarray]) -> None:
        for prefix, teacher in (("teacher.", self.teacher), ("base_teacher.", self.base_teacher)):
            if teacher is not None:
                teacher.load_state_dict({k[len(prefix):]: v for k, v in arrays.items()
                                         if k.startswith(prefix)})
        self.teacher_started[...] = arrays["teacher_started"]


__all__ = ["Distiller", "LabelledReplay", "load_teacher"]
