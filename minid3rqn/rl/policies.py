"""Policies for batched flights: Straight, Random, Reactive, Oracle, and a trained QNet.

A policy sees a batch of flights. ``reset(n)`` starts n flights; ``act(obs)`` returns
one action index per flight, where ``obs`` is a dict with

    "frames"  (n, H, W) float32 depth frames in [0, 1] (the Q-nets' input, 1 = far)
    "depth"   (n, H, W) depth in metres (GT, or the DispNet's prediction scaled)
    "flights" the Flights object, for the privileged oracle only
    "active"  (n,) bool: flights still flying (the others' actions are ignored)

and ``started`` (bool (n,)) on ``act`` marks flights whose episode has just begun
(the recurrent policy zeroes their state).
"""
from __future__ import annotations

import math

import numpy as np

from ..nets.qnet import QNet, QNetConfig
from .agent import Agent, FrameStacker



def _trained(meta: dict | None) -> dict:
    return (meta or {}).get("train_config") or {}


def trained_actions(meta: dict | None) -> np.ndarray:
    """The action table (A, 2) a Q-net was trained with (the paper's Table 3 if the
    file records none)."""
    from ..world import ACTIONS
    actions = _trained(meta).get("actions")
    return ACTIONS.copy() if actions is None else np.asarray(actions, dtype=np.float64)


def trained_camera(meta: dict | None):
    """The camera a Q-net was trained with (90 degrees wide if the file records none)."""
    from ..world import Camera
    return Camera(hfov_deg=float(_trained(meta).get("hfov_deg", 90.0)))

class Policy:
    name = "policy"

    def reset(self, n: int) -> None:
        self.n = n

    def reseed(self, seed) -> None:
        """Restart the policy's random generator, if it has one, from ``seed``."""
        if hasattr(self, "rng"):
            self.rng = np.random.default_rng(seed)

    def act(self, obs: dict) -> np.ndarray:
        raise NotImplementedError


class StraightPolicy(Policy):
    """Always action 0: fly straight ahead (the paper's "Straight")."""
    name = "Straight"

    def __init__(self, straight_action: int = 0):
        self.a = straight_action

    def act(self, obs):
        return np.full(len(obs["frames"]), self.a, dtype=np.int64)


class RandomPolicy(Policy):
    """A uniformly random action every step (the paper's "Random")."""
    name = "Random"

    def __init__(self, n_actions: int, seed=None):
        self.n_actions = n_actions
        self.rng = np.random.default_rng(seed)

    def act(self, obs):
        return self.rng.integers(self.n_actions, size=len(obs["frames"])).astype(np.int64)


class ReactivePolicy(Policy):
    """Steer toward the deepest direction of the depth map (no learning, no memory).

    Per image column, the obstacle distance is the median depth of the ``rows`` rows
    around the horizon, the middle row (the optical axis is level, so floor and ceiling
    are far from those rows).
    The profile is smoothed over ``smooth`` columns (a corridor as wide as the drone
    must be free, not one pixel). If the centre of the image is free beyond
    ``clear_ahead`` metres the drone flies straight; otherwise it turns toward the
    column of greatest depth, with the yaw rate in the action table nearest to
    ``angle / turn_time`` (the rate that would face that direction in ``turn_time`` s).

    The defaults were tuned *up* on ``basic`` (GT depth, 150 flights per setting, test
    worlds of seed 777, not the seed of the reported tables) over smooth in {15..101},
    turn_time in {0.4..1.6}, clear_ahead in {4, 6, 8, 10, 100}: from 0.00 (smooth 15,
    clear_ahead 4) to 0.72 (smooth 91: a window as wide as most of the image, i.e.
    "turn toward the widest free sector").
    """
    name = "Reactive"

    def __init__(self, actions: np.ndarray, hfov_deg: float = 90.0, rows: int = 4,
                 smooth: int = 91, clear_ahead: float = 10.0, turn_time: float = 0.6):
        self.actions = np.asarray(actions, dtype=np.float64)
        self.hfov = math.radians(hfov_deg)
        self.rows, self.smooth = rows, smooth
        self.clear_ahead, self.turn_time = clear_ahead, turn_time

    def profile(self, depth: np.ndarray) -> np.ndarray:
        """(n, H, W) depth -> (n, W) smoothed per-column obstacle distance."""
        n, H, W = depth.shape
        mid = H // 2
        band = depth[:, max(0, mid - self.rows // 2): mid + (self.rows + 1) // 2]
        col = np.median(band, axis=1)
        k = max(1, min(self.smooth, W))
        pad = np.pad(col, ((0, 0), (k // 2, k - 1 - k // 2)), mode="edge")
        # a corridor is only as free as its nearest point: sliding minimum
        win = np.lib.stride_tricks.sliding_window_view(pad, k, axis=1)
        return win.min(axis=2)

    def act(self, obs):
        depth = np.asarray(obs["depth"], dtype=np.float64)
        n, H, W = depth.shape
        prof = self.profile(depth)
        centre = prof[:, W // 2]
        best = np.argmax(prof, axis=1)
        fx = (W / 2) / math.tan(self.hfov / 2)
        angle = -np.arctan((best - (W - 1) / 2) / fx)       # left of centre -> positive
        want = angle / self.turn_time
        want = np.where(centre >= self.clear_ahead, 0.0, want)
        rates = self.actions[:, 1]
        speeds_ok = self.actions[:, 0] > 0
        cost = np.abs(want[:, None] - rates[None, :]) + np.where(speeds_ok, 0, 1e9)[None, :]
        return np.argmin(cost, axis=1).astype(np.int64)


class OraclePolicy(Policy):
    """The world's privileged planner (``world.policies.Oracle``: it reads the map, not
    the camera), flying our ``Flights`` through the attributes it expects."""
    name = "Oracle"

    def reset(self, n):
        from ..world.policies import Oracle
        self.n = n
        self.oracle = Oracle()

    def act(self, obs):
        return np.asarray(self.oracle(obs["flights"]), dtype=np.int64)


class QNetPolicy(Policy):
    """Greedy on a trained QNet; the recurrent state is carried through each flight and
    zeroed when a flight starts (``started``)."""

    def __init__(self, qnet: QNet, name: str | None = None):
        self.qnet = qnet
        self.name = name or "QNet"
        self.last_q = None

    @classmethod
    def load(cls, path, name: str | None = None) -> "QNetPolicy":
        """A Q-net file; its metadata (how it was trained) is kept as ``meta``."""
        from ..io import load_npz
        from ..io import reason
        from ..nets.module import check_finite
        arrays, meta = load_npz(path)
        meta = meta if isinstance(meta, dict) else {}
        if "qnet_config" not in meta:
            what = "a depth model" if "disp" in " ".join(arrays) or meta.get("config") \
                else "no Q-net"
            raise ValueError(f"{str(path)!r} is {what}, not a Q-net file (expected a model "
                             f"written by train-agent or distil)")
        check_finite(arrays, path)
        try:                      # the net, and the action table and camera it flies with
            net = QNet(QNetConfig(**meta["qnet_config"]), rng=0)
            net.load_state_dict(arrays)
            actions, _ = trained_actions(meta), trained_camera(meta)
            if actions.shape != (net.config.n_actions, 2) or not np.isfinite(actions).all():
                raise ValueError(f"its action table {actions.tolist()} is not "
                                 f"{net.config.n_actions} rows of (speed, yaw rate)")
            if not isinstance(meta.get("steps", 0), int):
                raise ValueError(f"its step count {meta['steps']!r} is not a number")
        except (AttributeError, KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{str(path)!r} is not a readable Q-net file: {reason(e)}") \
                from None
        pol = cls(net, name)
        pol.meta = meta
        return pol

    def reset(self, n):
        self.n = n
        cfg = self.qnet.config
        self.stacker = FrameStacker(n, cfg.in_channels, (cfg.height, cfg.width_px))
        self.state = self.qnet.initial_state(n)
        self.fresh = np.ones(n, bool)

    def state_dict(self) -> dict[str, np.ndarray]:
        """The flights' memory (frame stack, recurrent state), to resume a run exactly."""
        state = {"stack": self.stacker.buf, "fresh": self.fresh}
        if self.state is not None:
            state["h"], state["c"] = self.state[0].data, self.state[1].data
        return {k: np.array(v) for k, v in state.items()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        from ..autograd import Tensor
        self.stacker.buf[...] = state["stack"]
        self.fresh[...] = state["fresh"]
        if "h" in state:
            self.state = (Tensor(np.array(state["h"])), Tensor(np.array(state["c"])))

    def act(self, obs, started=None):
        from ..autograd import no_grad
        frames = np.asarray(obs["frames"], dtype=np.float32)
        started = self.fresh if started is None else (np.asarray(started, bool) | self.fresh)
        if started.any():
            self.stacker.reset(np.flatnonzero(started), frames[started])
            self.state = Agent.reset_state(self.state, started)
        live = np.flatnonzero(~started)
        if len(live):
            self.stacker.push(frames[live], live)
        self.fresh[:] = False
        with no_grad():
            q, self.state = self.qnet.step(self.stacker.obs, self.state)
        self.last_q = q.data
        return np.argmax(self.last_q, axis=1).astype(np.int64)


class EnsemblePolicy(Policy):
    """Greedy on the mean of several Q-nets' Q-values (each with its own recurrent
    state): our addition, not the paper's method.

    Nets trained from different seeds make different mistakes away from their training
    world (docs/results.md, Table 6); averaging their Q-values before the argmax votes
    the idiosyncrasies down. Every member sees the same frames; ``last_q`` is the mean.
    """

    def __init__(self, members: list, name: str | None = None):
        members = list(members)
        if len(members) < 2:
            raise ValueError(f"EnsemblePolicy: members must hold at least 2 Q-net policies; "
                             f"got {len(members)}")
        for i, m in enumerate(members):
            if not hasattr(m, "qnet"):
                raise TypeError(f"EnsemblePolicy: members[{i}] must be a Q-net policy; "
                                f"got {type(m).__name__}")
        shapes = {(m.qnet.config.height, m.qnet.config.width_px, m.qnet.config.n_actions)
                  for m in members}
        if len(shapes) > 1:
            raise ValueError(f"EnsemblePolicy: members must share (height, width, actions); "
                             f"got {sorted(shapes)}")
        self.members = members
        names = sorted({m.name for m in members})
        self.name = name or f"{'+'.join(names)}-ens{len(members)}"
        self.last_q = None

    def reset(self, n):
        self.n = n
        for m in self.members:
            m.reset(n)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {f"{i}.{k}": v for i, m in enumerate(self.members)
                for k, v in m.state_dict().items()}

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        for i, m in enumerate(self.members):
            m.load_state_dict({k[len(f"{i}."):]: v for k, v in state.items()
                               if k.startswith(f"{i}.")})

    def act(self, obs, started=None):
        for m in self.members:
            m.act(obs, started)
        self.last_q = np.mean([m.last_q for m in self.members], axis=0)
        return np.argmax(self.last_q, axis=1).astype(np.int64)
