"""The agent: acting (epsilon-greedy, recurrent state per flight) and the double-Q update.

Double Q-learning (van Hasselt et al. 2016). The online net picks the next action, the
target net (a copy refreshed every ``target_update`` updates) values it::

    a*  = argmax_a Q_online(o_{t+1}, a)
    y_t = r_t + gamma * (1 - terminal_t) * Q_target(o_{t+1}, a*)
    L   = mean over unmasked (t, b) of Huber(Q_online(o_t, a_t) - y_t)

On a window of L steps both nets run over the L + 1 frames from a zero state, so
Q(o_{t+1}) has seen the same history as Q(o_t) plus one frame (``double_q_targets``).

Acting. A recurrent agent keeps (h, c) for every parallel flight; the state advances
on every step, whichever action is then taken (greedy or random), and is zeroed for a
flight whose episode has just started (``reset_state``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import autograd as ag
from ..config import at_least, between, positive, setting, validate
from ..autograd import Tensor, no_grad
from ..autograd.losses import huber_loss
from ..autograd.optim import Adam, clip_grad_norm
from ..nets.qnet import QNet, QNetConfig
from .replay import SequenceBatch


def double_q_targets(q_online_next: np.ndarray, q_target_next: np.ndarray,
                     rewards: np.ndarray, terminals: np.ndarray, gamma: float) -> np.ndarray:
    """y = r + gamma (1 - terminal) Q_target(o', argmax_a Q_online(o', a)).

    q_*_next (..., A); rewards, terminals (...). Returns float32 (...).
    """
    q_online_next = np.asarray(q_online_next)
    q_target_next = np.asarray(q_target_next)
    if q_online_next.shape != q_target_next.shape:
        raise ValueError(f"double_q_targets: q_online_next {q_online_next.shape} and "
                         f"q_target_next {q_target_next.shape} must match")
    best = np.argmax(q_online_next, axis=-1)
    value = np.take_along_axis(q_target_next, best[..., None], axis=-1)[..., 0]
    y = np.asarray(rewards) + gamma * (1.0 - np.asarray(terminals)) * value
    return y.astype(np.float32)


@dataclass
class AgentConfig:
    gamma: float = setting(0.99, "discount factor", source="paper", check=between(0, 1))
    lr: float = setting(3e-4, "Adam step size", source="paper", check=positive)
    target_update: int = setting(300, "updates between target-net refreshes",
                                 source="paper", cli="more", check=at_least(1))
    huber_delta: float = setting(1.0, "Huber loss: quadratic within +-delta (the paper "
                                      "does not give its loss)", check=positive)
    grad_clip: float = setting(10.0, "clip the gradient's global norm to this",
                               check=positive)
    reward_scale: float = setting(0.1, "rewards x this (the same policy; Q-values ~ 10, "
                                       "not ~ 100)", check=positive)

    def __post_init__(self):
        validate(self)


class Agent:
    """Online and target QNet, Adam, and the update. ``td_target``: the TD target, a
    function like ``double_q_targets`` (the default)."""

    def __init__(self, qnet_config: QNetConfig, config: AgentConfig | None = None, rng=None,
                 td_target=None):
        self.config = config or AgentConfig()
        self.td_target = td_target or double_q_targets
        self.online = QNet(qnet_config, rng=rng)
        self.target = QNet(qnet_config, rng=0)
        self.target.copy_from(self.online)
        self.optimizer = Adam(self.online.parameters(), lr=self.config.lr)
        self.updates = 0

    @property
    def qnet_config(self) -> QNetConfig:
        return self.online.config

    # -- acting -------------------------------------------------------------------
    def initial_state(self, batch: int):
        return self.online.initial_state(batch)

    @staticmethod
    def reset_state(state, done: np.ndarray):
        """Zero (h, c) rows of the flights in ``done`` (bool (B,)); returns new state."""
        if state is None:
            return None
        done = np.asarray(done, bool)
        if not done.any():
            return state
        h, c = (s.data.copy() for s in state)
        h[done] = 0.0
        c[done] = 0.0
        return Tensor(h), Tensor(c)

    def q_values(self, obs: np.ndarray, state=None):
        """Greedy forward for a batch of flights: obs (B, C, H, W) -> (Q (B, A) array, state)."""
        with no_grad():
            q, state = self.online.step(np.asarray(obs, dtype=np.float32), state)
        return q.data, state

    def act(self, obs: np.ndarray, state, epsilon: float, rng: np.random.Generator):
        """Epsilon-greedy actions (B,), Q-values (B, A) and the advanced state.

        The network always runs (so the recurrent state sees every frame); a flight
        then takes a uniformly random action with probability ``epsilon``.
        """
        q, state = self.q_values(obs, state)
        actions = np.argmax(q, axis=1)
        if epsilon > 0:
            explore = rng.random(len(actions)) < epsilon
            actions = np.where(explore, rng.integers(q.shape[1], size=len(actions)), actions)
        return actions.astype(np.int64), q, state

    # -- learning -----------------------------------------------------------------
    def loss(self, batch: SequenceBatch):
        """Masked Huber loss of the double-Q targets over a window batch."""
        cfg = self.config
        L, B = batch.actions.shape
        q_all, _ = self.online(batch.obs)                       # (L+1, B, A), with graph
        with no_grad():
            q_tgt, _ = self.target(batch.obs)
        y = self.td_target(q_all.data[1:], q_tgt.data[1:], batch.rewards * cfg.reward_scale,
                           batch.terminals, cfg.gamma)
        y = np.asarray(y, dtype=np.float32)
        t_idx, b_idx = np.meshgrid(np.arange(L), np.arange(B), indexing="ij")
        q_sa = q_all[t_idx, b_idx, batch.actions]                # (L, B)
        mask = batch.mask
        per = huber_loss(q_sa, y, delta=cfg.huber_delta, reduction="none")
        loss = ag.sum(per * mask) * (1.0 / max(1.0, float(mask.sum())))
        info = {"q_mean": float((q_sa.data * mask).sum() / max(1.0, mask.sum())),
                "target_mean": float((y * mask).sum() / max(1.0, mask.sum()))}
        return loss, info

    def update(self, batch: SequenceBatch) -> dict:
        """One gradient step; refreshes the target net every ``target_update`` updates."""
        loss, info = self.loss(batch)
        self.optimizer.zero_grad()
        loss.backward()
        info["grad_norm"] = clip_grad_norm(self.online.parameters(), self.config.grad_clip)
        self.optimizer.step()
        self.updates += 1
        if self.updates % self.config.target_update == 0:
            self.target.copy_from(self.online)
        info["loss"] = float(loss.data)
        return info

    # -- saving -------------------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        state = {f"online.{k}": v for k, v in self.online.state_dict().items()}
        state.update({f"target.{k}": v for k, v in self.target.state_dict().items()})
        state.update({f"optim.{k}": v for k, v in self.optimizer.state_dict().items()})
        state["updates"] = np.asarray(self.updates)
        return state

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        def part(prefix):
            return {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
        self.online.load_state_dict(part("online."))
        self.target.load_state_dict(part("target."))
        self.optimizer.load_state_dict(part("optim."))
        self.updates = int(state["updates"])


class FrameStacker:
    """The last ``stack`` frames of every flight, as the (B, stack, H, W) observation.

    At an episode's start the first frame fills the whole stack.
    """

    def __init__(self, n: int, stack: int, frame_shape):
        self.stack = int(stack)
        self.buf = np.zeros((n, self.stack) + tuple(frame_shape), dtype=np.float32)

    def reset(self, idx, frames: np.ndarray) -> None:
        idx = np.atleast_1d(idx)
        self.buf[idx] = np.asarray(frames, dtype=np.float32)[:, None]

    def push(self, frames: np.ndarray, idx=None) -> np.ndarray:
        if idx is None:
            idx = np.arange(len(self.buf))
        self.buf[idx, :-1] = self.buf[idx, 1:]
        self.buf[idx, -1] = frames
        return self.buf

    @property
    def obs(self) -> np.ndarray:
        return self.buf
