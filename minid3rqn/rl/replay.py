"""Episodic replay: one stream of frames per parallel flight, sampled as short windows.

Storage. Flight ``e`` of a vectorized env writes into its own ring ``stream e``. Each
slot holds one depth frame (quantized to uint8 in [0, 1] x 255) and, if an action was
taken from it, that transition's action, reward and terminal flag::

    slot:        j        j+1      ...    j+T-1      j+T
    frame:       o_0      o_1             o_{T-1}    o_T     (o_T: the last frame seen)
    transition:  a_0 r_0  a_1 r_1         a_{T-1}..  none    (has_next = False)

so the frame after transition ``j`` is always in slot ``j + 1``, and an episode's
final frame sits in a slot of its own that carries no transition. Every slot knows
the absolute index of its episode's first slot (``ep_start``), which is all that is
needed to keep windows inside one episode.

Sampling (``sample``). A transition ``t`` is drawn uniformly from all stored ones; the
window of length L that contains it is ``s .. s+L-1`` with ``s = max(ep_start, t-L+1)``
(pulled left if it would run past the episode's end), so windows never cross
episodes. Episodes shorter than L give windows whose tail is masked out. Each step's
observation is the ``stack`` most recent frames of the episode (the first frame
repeated before the episode's start), so one sampler serves all variants:

    recurrent:       L = 5, stack = 1   (the paper's input sequence of 5 depth maps)
    non-recurrent:   L = 1, stack = 1   (last frame only) or stack = 5 (window as channels)

Truncation (the 50-step time limit) is *not* terminal: the final frame is stored and
the target bootstraps from it; only a collision sets ``terminal``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SequenceBatch:
    """A batch of windows. T = L + 1 frames for L transitions.

    obs (L+1, B, stack, H, W) float32; actions (L, B) int64; rewards (L, B) float32;
    terminals (L, B) float32 (1 = collision, no bootstrap); mask (L, B) float32
    (0 past the episode's end).
    """
    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminals: np.ndarray
    mask: np.ndarray


class EpisodeReplay:
    """Replay for ``n_streams`` parallel flights, ``capacity`` frames in total."""

    def __init__(self, capacity: int, n_streams: int, frame_shape: tuple[int, int],
                 seed=None):
        if n_streams < 1 or capacity < 4 * n_streams:
            raise ValueError(f"EpisodeReplay: need n_streams >= 1 and capacity >= 4 * n_streams; "
                             f"got capacity={capacity}, n_streams={n_streams}")
        self.n_streams = int(n_streams)
        self.cap = int(capacity) // self.n_streams          # slots per stream
        self.frame_shape = tuple(frame_shape)
        S, C = self.n_streams, self.cap
        self.frames = np.zeros((S, C) + self.frame_shape, dtype=np.uint8)
        self.actions = np.zeros((S, C), dtype=np.int64)
        self.rewards = np.zeros((S, C), dtype=np.float32)
        self.terminals = np.zeros((S, C), dtype=np.bool_)
        self.has_next = np.zeros((S, C), dtype=np.bool_)
        self.ep_start = np.zeros((S, C), dtype=np.int64)     # absolute index of episode start
        self.count = np.zeros(S, dtype=np.int64)               # absolute slots written
        self.open_start = np.full(S, -1, dtype=np.int64)       # current episode start, -1: none
        self.rng = np.random.default_rng(seed)

    # -- writing --------------------------------------------------------------------
    @staticmethod
    def quantize(frames: np.ndarray) -> np.ndarray:
        return np.clip(np.rint(np.asarray(frames, dtype=np.float32) * 255.0), 0, 255).astype(np.uint8)

    def _write_frames(self, streams: np.ndarray, frames: np.ndarray) -> None:
        """Append one frame to each of the (distinct) ``streams``, in a fresh slot."""
        j = self.count[streams] % self.cap
        self.frames[streams, j] = frames
        self.has_next[streams, j] = False
        self.terminals[streams, j] = False
        self.ep_start[streams, j] = self.open_start[streams]
        self.count[streams] += 1

    def start_episodes(self, streams, frames: np.ndarray) -> None:
        """First frame o_0 (values in [0, 1]) of a new episode in each given stream."""
        streams = np.atleast_1d(np.asarray(streams, dtype=np.int64))
        if len(np.unique(streams)) != len(streams):
            raise ValueError(f"EpisodeReplay.start_episodes: streams must be distinct; got "
                             f"{streams.tolist()}")
        self.open_start[streams] = self.count[streams]
        self._write_frames(streams, self.quantize(frames))

    def add_step(self, actions, rewards, terminals, truncated, next_frames) -> None:
        """One vector step for every stream: a_t, r_t, collision flag, time-limit flag and
        o_{t+1} (the frame after the action; for a finished episode, its final frame).

        A finished stream (terminal or truncated) needs ``start_episodes`` before its
        next ``add_step``.
        """
        closed = np.flatnonzero(self.open_start < 0)
        if closed.size:
            raise RuntimeError(f"EpisodeReplay.add_step: stream {int(closed[0])} has no open "
                               f"episode; call start_episodes first")
        streams = np.arange(self.n_streams)
        j = (self.count - 1) % self.cap                   # the slot holding o_t
        self.actions[streams, j] = actions
        self.rewards[streams, j] = rewards
        self.terminals[streams, j] = np.asarray(terminals, bool)
        self.has_next[streams, j] = True
        self._write_frames(streams, self.quantize(next_frames))   # o_{t+1}
        done = np.asarray(terminals, bool) | np.asarray(truncated, bool)
        self.open_start[done] = -1

    # -- reading --------------------------------------------------------------------
    def __len__(self) -> int:
        """Number of stored transitions (slots with a next frame)."""
        return int(self.has_next.sum())

    def sample(self, batch_size: int, seq_len: int = 5, stack: int = 1) -> SequenceBatch:
        """``batch_size`` windows of ``seq_len`` transitions, ``stack`` frames per step."""
        L, B = int(seq_len), int(batch_size)
        if len(self) == 0:
            raise RuntimeError("EpisodeReplay.sample: the buffer holds no transition yet")
        streams = np.empty(B, dtype=np.int64)
        starts = np.empty(B, dtype=np.int64)
        n = 0
        while n < B:                      # rejection sampling of a stored transition
            s = int(self.rng.integers(self.n_streams))
            lo = max(0, int(self.count[s]) - self.cap)
            hi = int(self.count[s])
            if hi - lo < 2:
                continue
            t = int(self.rng.integers(lo, hi))
            j = t % self.cap
            if not self.has_next[s, j]:
                continue
            ep0 = max(int(self.ep_start[s, j]), lo)
            # pull the window left so that it ends inside the episode if possible
            end = t
            while end + 1 < hi and end - t < L - 1 and self.has_next[s, (end + 1) % self.cap] \
                    and self.ep_start[s, (end + 1) % self.cap] == self.ep_start[s, j]:
                end += 1
            start = max(ep0, min(t, end - L + 1))
            streams[n], starts[n] = s, start
            n += 1
        return self._gather(streams, starts, L, stack)

    def _gather(self, streams: np.ndarray, starts: np.ndarray, L: int,
                stack: int) -> SequenceBatch:
        H, W = self.frame_shape
        offs = np.arange(L)
        idx = starts[:, None] + offs[None, :]                       # (B, L) transitions
        slot = idx % self.cap
        sb = streams[:, None]
        ep = self.ep_start[sb, starts[:, None] % self.cap]           # (B, 1) episode id
        ok = (self.has_next[sb, slot] & (self.ep_start[sb, slot] == ep)
              & (idx < self.count[streams][:, None]))
        ok = np.logical_and.accumulate(ok, axis=1)                  # stop at the first gap
        # frames: steps 0..L, each with `stack` frames back, clamped to the episode
        last_ok = starts + ok.sum(axis=1)                            # index of last frame
        steps = starts[:, None] + np.arange(L + 1)[None, :]          # (B, L+1)
        steps = np.minimum(steps, last_ok[:, None])
        back = steps[:, :, None] - np.arange(stack - 1, -1, -1)[None, None, :]
        lo = np.maximum(ep[:, :, None], (self.count[streams] - self.cap)[:, None, None])
        back = np.maximum(back, lo)                                  # (B, L+1, stack)
        frames = self.frames[streams[:, None, None], back % self.cap]  # (B, L+1, stack, H, W)
        obs = frames.transpose(1, 0, 2, 3, 4).astype(np.float32) * (1.0 / 255.0)
        actions = self.actions[sb, slot].T.copy()
        rewards = self.rewards[sb, slot].T.astype(np.float32)
        terminals = self.terminals[sb, slot].T.astype(np.float32)
        mask = ok.T.astype(np.float32)
        actions[mask == 0] = 0
        rewards[mask == 0] = 0
        terminals[mask == 0] = 0
        return SequenceBatch(obs, actions, rewards, terminals, mask)

    # -- saving (for exact resume) ----------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        return {"frames": self.frames, "actions": self.actions, "rewards": self.rewards,
                "terminals": self.terminals, "has_next": self.has_next,
                "ep_start": self.ep_start, "count": self.count,
                "open_start": self.open_start}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        for key, value in state.items():
            own = getattr(self, key)
            if own.shape != value.shape:
                raise ValueError(f"EpisodeReplay.load_state_dict: {key} has shape "
                                 f"{value.shape}; this buffer expects {own.shape}")
            own[...] = value
