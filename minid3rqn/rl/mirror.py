"""The mirror image (ours, not the paper's method): a world seen in a left-right mirror
is as likely as the world itself, and is flown by mirrored actions.

Mirroring a frame flips it along its width (the camera is symmetric, cx = (W - 1) / 2);
mirroring an action (speed v, yaw rate w) gives (v, -w), the action at index
``mirror_of[a]`` of the same table (``mirror_permutation``). Two uses:

    MirroredPolicy(net)     at test time: the net flies the mirrored view, a second
                            opinion for free; joined with the net itself in an
                            ``EnsemblePolicy`` it is a two-member ensemble of one net
                            (``evaluate --mirror``; docs/d3rqn.md section 10)
    mirror_windows(batch)   in training: replay windows seen in the mirror, and
    mirror_q(q)             a teacher's Q-values of them (``rl.distill``'s augmentation)
"""
from __future__ import annotations

import numpy as np

from .policies import Policy, QNetPolicy, trained_actions
from .replay import SequenceBatch


def mirror_permutation(actions) -> np.ndarray:
    """For each action (speed, yaw rate), the index of its mirror image: the same speed,
    the opposite yaw rate. ValueError if the action table is not symmetric."""
    actions = np.asarray(actions, dtype=np.float64)
    mirrored = actions * np.array([1.0, -1.0])
    match = np.all(np.isclose(actions[None, :, :], mirrored[:, None, :]), axis=2)  # (i, j)
    if not match.any(axis=1).all():
        missing = actions[~match.any(axis=1)].tolist()
        raise ValueError(f"mirror_permutation: the action table has no mirror image for "
                         f"{missing}; it needs, for every (speed, yaw rate), (speed, -yaw rate)")
    return np.argmax(match, axis=1)


class MirroredPolicy(Policy):
    """A Q-net flying the mirrored view: it reads every frame flipped, and its Q-value of
    action a is reported as that of a's mirror image. The net is shared with ``policy``
    (the same weights); the memory (frame stack, recurrent state) is its own."""

    def __init__(self, policy: QNetPolicy, actions=None):
        self.meta = getattr(policy, "meta", None)
        self.inner = QNetPolicy(policy.qnet, policy.name + "-mirrored")
        self.qnet, self.name = policy.qnet, self.inner.name
        self.mirror_of = mirror_permutation(trained_actions(self.meta) if actions is None
                                            else actions)
        if len(self.mirror_of) != policy.qnet.config.n_actions:
            raise ValueError(f"MirroredPolicy: the action table has {len(self.mirror_of)} "
                             f"actions; the net scores {policy.qnet.config.n_actions}")
        self.last_q = None

    def reset(self, env) -> None:
        self.n = env.n_envs
        self.inner.reset(env)

    def act(self, obs, started=None):
        self.inner.act(np.ascontiguousarray(np.asarray(obs)[..., ::-1]), started)
        self.last_q = self.inner.last_q[:, self.mirror_of]
        return np.argmax(self.last_q, axis=1).astype(np.int64)


def mirror_windows(batch: SequenceBatch, which: np.ndarray,
                   mirror_of: np.ndarray) -> SequenceBatch:
    """A copy of ``batch`` in which the windows ``which`` (bool (B,)) are seen in the
    mirror: frames flipped along the width, each action a replaced by ``mirror_of[a]``;
    rewards, terminals and the mask stay (the reward reads distances, not directions)."""
    which = np.asarray(which, dtype=bool)
    B = batch.actions.shape[1]
    if which.shape != (B,):
        raise ValueError(f"mirror_windows: which must be a bool mask of the {B} windows; "
                         f"got shape {which.shape}")
    mirror_of = np.asarray(mirror_of, dtype=np.int64)
    obs = batch.obs.copy()
    obs[:, which] = obs[:, which][..., ::-1]
    actions = np.where(which[None, :], mirror_of[batch.actions], batch.actions)
    return SequenceBatch(obs, actions, batch.rewards, batch.terminals, batch.mask)


def mirror_q(q: np.ndarray, which: np.ndarray, mirror_of: np.ndarray) -> np.ndarray:
    """Q-values (L, B, A) of the windows ``which`` (bool (B,)) seen in the mirror: the
    value of action a is that of its mirror image ``mirror_of[a]``."""
    return np.where(np.asarray(which, bool)[None, :, None], q[..., mirror_of], q)
