"""Training flights that pay the student's reward, or see the student's corruption of
the depth (see ``adapters.classroom_flights``)."""
from __future__ import annotations

import json

import numpy as np

from ..rl.flights import Flights
from .adapters import call_reward


class ClassroomFlights(Flights):
    """``Flights`` whose reward is ``reward_fn(d_nearest, collided[, yaw_rate])``, and
    whose observed depth is ``depth_fn(depth, rng)``.

    The library's flights pay the paper's reward (Eq. 4); with ``reward_fn`` this
    subclass recomputes the rewards of the flights that moved, from the same clearance
    and collision flags, with the student's function (which may also see the yaw rate
    of the action flown).

    With ``depth_fn`` (exercise 8), every depth map the flights observe (metres, float32
    (m, H, W): the m flights that just moved or restarted) is replaced by
    ``depth_fn(depth, self.depth_rng)`` before it is encoded into the Q-net's frames,
    so the policy sees, and the replay stores, the corrupted depth. Collisions,
    clearances and rewards still come from the world. ``depth_rng`` is a generator of
    its own, seeded from ``seed`` but apart from the one that draws worlds and start
    poses: with the same seed, flights with and without the corruption fly in the same
    worlds from the same poses. What ``depth_fn`` returns must be positive finite
    depths of the input's shape (else ``ValueError``; ``check depth-errors`` says why
    before any training starts). None for either: the library's.
    """

    def __init__(self, scenario, n, seed=0, *args, reward_fn=None, depth_fn=None, **kwargs):
        super().__init__(scenario, n, seed, *args, **kwargs)
        self.reward_fn = reward_fn
        self.depth_fn = depth_fn
        self.depth_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])

    def step(self, actions, active=None):
        res = super().step(actions, active)
        if self.reward_fn is None:
            return res
        act = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        idx = np.flatnonzero(act)
        if len(idx):
            yaw = self.actions[np.asarray(actions, dtype=np.int64)[idx], 1]
            r = call_reward(self.reward_fn, res.d_nearest[idx].astype(np.float64),
                            res.terminated[idx].copy(), yaw)
            res.rewards[idx] = np.broadcast_to(np.asarray(r, dtype=np.float64), idx.shape)
        return res

    # -- exercise 8: the depth the Q-net sees --------------------------------------
    def observe(self, idx=None):
        depth, frames, rgb = super().observe(idx)
        if self.depth_fn is None:
            return depth, frames, rgb
        depth = self.corrupt(depth)
        return depth, self.encode(depth), rgb

    def corrupt(self, depth: np.ndarray) -> np.ndarray:
        """``depth_fn(depth, depth_rng)`` as float32, after checking that it is usable."""
        out = self.depth_fn(depth, self.depth_rng)
        arr = None if out is None else np.asarray(out)
        problem = None
        if arr is None:
            problem = "None"
        elif arr.shape != depth.shape:
            problem = f"an array of shape {arr.shape}"
        elif arr.dtype.kind != "f":
            problem = f"an array of dtype {arr.dtype}"
        elif not np.all(np.isfinite(arr)):
            problem = f"{int(np.sum(~np.isfinite(arr)))} non-finite values (nan or inf)"
        elif np.any(arr <= 0):
            problem = f"{int(np.sum(arr <= 0))} depths <= 0 (lowest {float(arr.min()):g} m)"
        if problem is not None:
            raise ValueError(f"ClassroomFlights: depth_fn(depth, rng) must return positive "
                             f"finite float depths (metres) of the input's shape "
                             f"{depth.shape}; got {problem} (python -m minid3rqn check "
                             f"depth-errors finds why)")
        return arr.astype(np.float32)

    # -- saving (exact resume): the corruption's generator too ----------------------
    def meta_state(self) -> dict:
        meta = super().meta_state()
        if self.depth_fn is not None:
            meta["depth_rng"] = json.dumps(self.depth_rng.bit_generator.state)
        return meta

    def load_state_dict(self, arrays: dict, meta: dict) -> None:
        super().load_state_dict(arrays, meta)
        if "depth_rng" in meta:
            self.depth_rng.bit_generator.state = json.loads(meta["depth_rng"])
