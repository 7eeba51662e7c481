"""Policies: Straight, Random, Reactive, Oracle and the trained Q-nets, one protocol.

A policy flies the N flights of a ``world.DroneEnv``:

    policy.reset(env)              the flights start (a Q-net zeroes its memory)
    actions = policy.act(obs)      obs: the env's observation, (N, H, W) depth in metres
                                   (GT or the DispNet's); actions (N,) int64

``act(obs, started)`` with ``started`` (bool (N,)) marks flights whose episode has just
begun in an autoresetting env (a Q-net zeroes their memory). Only the oracle reads the
env beyond its observation: it is privileged (it reads the map).
"""
from __future__ import annotations

import math

import numpy as np

from ..nets.qnet import QNet, QNetConfig
from ..world.distance import clearance_field, sample_fields
from ..world.kinematics import fly_plans, loiter_actions, loiter_circles, plan_paths
from .agent import Agent, FrameStacker
from .observe import encode_depth


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
    """The protocol (module docstring)."""
    name = "policy"

    def reset(self, env) -> None:
        """The flights of ``env`` (a ``world.DroneEnv``) start."""
        self.n = env.n_envs

    def reseed(self, seed) -> None:
        """Restart the policy's random generator, if it has one, from ``seed``."""
        if hasattr(self, "rng"):
            self.rng = np.random.default_rng(seed)

    def act(self, obs, started=None) -> np.ndarray:
        raise NotImplementedError


class StraightPolicy(Policy):
    """Always the action of the smallest |yaw rate|: fly straight ahead (the paper's
    "Straight")."""
    name = "Straight"

    def reset(self, env):
        self.n = env.n_envs
        self.a = int(np.argmin(np.abs(env.actions[:, 1])))

    def act(self, obs, started=None):
        return np.full(self.n, self.a, dtype=np.int64)


class RandomPolicy(Policy):
    """A uniformly random action every step (the paper's "Random")."""
    name = "Random"

    def __init__(self, n_actions: int, seed=None):
        self.n_actions = n_actions
        self.rng = np.random.default_rng(seed)

    def act(self, obs, started=None):
        return self.rng.integers(self.n_actions, size=self.n).astype(np.int64)


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

    def act(self, obs, started=None):
        depth = np.asarray(obs, dtype=np.float64)
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
    """The look-ahead planner. Privileged: it reads the map of each flight's world from
    the env given to ``reset`` (``env.poses``, ``env.scenes``, ``env.actions``, ``env.dt``,
    ``env.safe_distance``, ``env.steps``), not the camera. Each step it scores candidate
    plans (action sequences) over a look-ahead horizon and flies the first action of the
    best.

    - Plans. Action a_1 is held for ``segments[0]`` steps, a_2 for ``segments[1]`` steps, and
      so on; a_1 is any action, the later ones are hard left, hard right or straight
      (5 x 3^3 = 135 plans for the default segments (1, 2, 4, 8): 15 steps = 12 m ahead).
    - Clearance. Along a plan, points every ``spacing`` metres read the map's
      ``ClearanceField`` (distance to the nearest obstacle, negative outside the flyable
      region) as c_m = clearance - safe_distance - margin.
    - Score. With L the number of leading points with c_m >= 0,

          score = L + 0.5 clip(min_{m < L} c_m, 0, cap) / cap + 0.4 clip(mean_m c_m, 0, cap) / cap
                  - turn_cost |omega_1|  (+ M + 1 if certified, M = points per plan)

      first survive as long as possible, then keep away from obstacles. A plan failing only
      near the end of the horizon is not condemned: later steps can still change it.
    - Memory (receding horizon). The rest of the chosen plan competes again at the next
      step, so a plan once found safe stays available.
    - Certification. The best few fully surviving plans are checked for a safe full
      turning circle at their end (hard left or right held for ever); a certified plan can
      be flown safely for ever, and its remembered rest continues with that circle.

    Each flight's remembered plan (its rest, the last action held one step longer) is
    cleared where ``env.steps`` is 0.

    Args:
        segments: steps each action of a plan is held (the first is the action taken).
        spacing: metres between clearance checks along a plan.
        margin: extra clearance (m) demanded beyond the safe distance (covers the field's
            interpolation error and the gaps between samples).
        cap: clearances above this count as "safe enough" (m).
        turn_cost: penalty per rad/s of the first action's yaw rate (prefers straight).
        resolution: grid step (m) of the clearance fields.
        certify: how many of the best surviving plans per flight get the loiter check.
    """

    name = "Oracle"

    def __init__(self, segments=(1, 2, 4, 8), spacing: float = 0.4, margin: float = 0.25,
                 cap: float = 1.5, turn_cost: float = 0.02, resolution: float = 0.25,
                 certify: int = 4):
        if not segments or any(int(s) < 1 for s in segments):
            raise ValueError(f"OraclePolicy: segments must be positive step counts; got "
                             f"{segments!r}")
        self.segments = tuple(int(s) for s in segments)
        self.spacing, self.margin, self.cap = float(spacing), float(margin), float(cap)
        self.turn_cost, self.resolution = float(turn_cost), float(resolution)
        self.certify = int(certify)
        self._plans_key = None
        self._held = None
        self._stack = None
        self._memory = None

    def plans(self, actions: np.ndarray, dt: float):
        """The candidate plans of ``kinematics.plan_paths`` for this table (cached):
        per_step (K, T) action ids and relative poses (K, M, 3)."""
        key = (actions.tobytes(), dt)
        if self._plans_key != key:
            self._plans = plan_paths(actions, dt, self.segments, self.spacing)
            self._plans_key = key
            self._memory = None
        return self._plans

    def _fields(self, scenes):
        """Stacked clearance fields of the flights' worlds, (N, Gx, Gy) and origins (N, 2);
        refreshed slot by slot when a flight's world changes."""
        held = self._held
        if held is None or len(held) != len(scenes):
            held = self._held = [None] * len(scenes)
            self._stack = None
        changed = [k for k, s in enumerate(scenes) if held[k] is not s]
        if changed:
            fields = {k: clearance_field(scenes[k], self.resolution) for k in changed}
            shape = np.max([f.values.shape for f in fields.values()], axis=0)
            if self._stack is None or np.any(shape > self._stack[0].shape[1:]):
                old = self._stack
                big = shape if old is None else np.maximum(shape, old[0].shape[1:])
                values = np.full((len(scenes),) + tuple(big), -1.0, np.float32)
                origins = np.zeros((len(scenes), 2))
                if old is not None:
                    values[:, :old[0].shape[1], :old[0].shape[2]] = old[0]
                    origins[:] = old[1]
                self._stack = (values, origins)
            values, origins = self._stack
            for k, f in fields.items():
                values[k] = -1.0
                values[k, :f.values.shape[0], :f.values.shape[1]] = f.values
                origins[k] = f.origin
                held[k] = scenes[k]
        return self._stack

    def _clearance(self, env, xy) -> np.ndarray:
        """Clearance margin c = field - safe_distance - margin at points xy (N, ..., 2)."""
        values, origins = self._fields(env.scenes)
        n = len(xy)
        c = sample_fields(values, origins, self.resolution, xy.reshape(n, -1, 2))
        return c.reshape(xy.shape[:-1]) - (env.safe_distance + self.margin)

    def _score(self, clear) -> tuple[np.ndarray, np.ndarray]:
        """Scores and survival lengths of paths with clearance margins clear (N, K, M)."""
        m = clear.shape[-1]
        viol = clear < 0
        safe_len = np.where(viol.any(-1), np.argmax(viol, -1), m)
        prefix_min = np.where(np.arange(m) < safe_len[..., None], clear, np.inf).min(-1)
        score = (safe_len + 0.5 / self.cap * np.clip(prefix_min, 0, self.cap)
                 + 0.4 / self.cap * np.clip(clear.mean(-1), 0, self.cap))
        return score, safe_len

    def reset(self, env):
        self.n, self.env = env.n_envs, env
        self._held = self._stack = self._memory = None

    def act(self, obs, started=None) -> np.ndarray:
        env = self.env
        actions, poses = env.actions, env.poses
        per_step, rel = self.plans(actions, env.dt)
        n, (k, t), m, n_a = len(poses), per_step.shape, rel.shape[1], len(actions)
        rows = np.arange(n)
        fresh = np.broadcast_to(np.asarray(env.steps) == 0, (n,))
        if self._memory is None or len(self._memory) != n:
            self._memory = np.full((n, t), -1, np.int64)
        self._memory[fresh] = -1
        has_memory = self._memory[:, 0] >= 0

        # Candidate paths in world coordinates: the K fixed plans, then the memorized one.
        c, s = np.cos(poses[:, 2, None, None]), np.sin(poses[:, 2, None, None])
        rx, ry, ryaw = rel[None, ..., 0], rel[None, ..., 1], rel[None, ..., 2]
        fixed = np.stack([poses[:, 0, None, None] + c * rx - s * ry,
                          poses[:, 1, None, None] + s * rx + c * ry,
                          poses[:, 2, None, None] + ryaw], -1)               # (N, K, M, 3)
        memory = np.where(has_memory[:, None], self._memory, per_step[0])
        remembered = fly_plans(poses, memory, actions, env.dt, self.spacing)[:, None]
        paths = np.concatenate([fixed, remembered], axis=1)                   # (N, K+1, M, 3)
        score, safe_len = self._score(self._clearance(env, paths[..., :2]))
        score[~has_memory, k] = -np.inf

        # Certify the best few surviving plans: can the drone circle forever at the end?
        top = np.argsort(np.where(safe_len == m, -score, np.inf), axis=1)[:, :self.certify]
        ends = paths[rows[:, None], top, -1]                                  # (N, C, 3)
        loops = self._clearance(env, loiter_circles(ends, actions, self.spacing)).min(-1)
        ok = (loops >= 0) & (safe_len[rows[:, None], top] == m)[..., None]    # (N, C, 2)
        certified = np.zeros((n, k + 1, 2), bool)
        certified[rows[:, None], top] = ok
        loops_all = np.full((n, k + 1, 2), -np.inf)
        loops_all[rows[:, None], top] = loops
        score = score + (m + 1.0) * certified.any(-1)

        first = np.concatenate([np.broadcast_to(per_step[:, 0], (n, k)), memory[:, :1]], 1)
        score = score - self.turn_cost * np.abs(actions[first, 1])

        # The best plan for each first action, then the best first action.
        masked = np.where(first[:, None, :] == np.arange(n_a)[None, :, None], score[:, None, :],
                          -np.inf)                                            # (N, A, K + 1)
        best_plan = np.argmax(masked, axis=-1)
        per_action = masked[rows[:, None], np.arange(n_a)[None, :], best_plan]
        choice = np.argmax(per_action, axis=1)

        # Remember the rest of the chosen plan and what follows it: the loiter turn if the
        # plan is certified (so the memory stays certified), else its last action again.
        plan = best_plan[rows, choice]
        chosen = np.where((plan == k)[:, None], memory, per_step[np.minimum(plan, k - 1)])
        loiter = loiter_actions(actions)[np.argmax(loops_all[rows, plan], axis=-1)]
        nxt = np.where(certified[rows, plan].any(-1), loiter, chosen[:, -1])
        self._memory = np.concatenate([chosen[:, 1:], nxt[:, None]], axis=1)
        return choice.astype(np.int64)


class QNetPolicy(Policy):
    """Greedy on a trained QNet. It reads depth in metres as the Q-net's input
    (``rl.observe``: encoded, then stacked); the frame stack and the recurrent state are
    carried through each flight and restarted when a flight starts (``started``)."""

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
            if "steps" in meta and any(k.startswith("agent.") for k in arrays):
                what = "a training checkpoint (its run's Q-net is model.npz beside it)"
            elif "iteration" in meta or "dispnet" in meta:
                what = "a depth model" if "dispnet" in meta else "a depth training checkpoint"
            else:
                what = "no Q-net"
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

    def reset(self, env):
        self.n = n = env.n_envs
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
        self.n = len(state["stack"])
        self.stacker = FrameStacker(self.n, state["stack"].shape[1], state["stack"].shape[2:])
        self.stacker.buf[...] = state["stack"]
        self.fresh = np.array(state["fresh"], bool)
        self.state = None
        if "h" in state:
            self.state = (Tensor(np.array(state["h"])), Tensor(np.array(state["c"])))

    def act(self, obs, started=None):
        from ..autograd import no_grad
        frames = encode_depth(obs)
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

    def reset(self, env):
        self.n = env.n_envs
        for m in self.members:
            m.reset(env)

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
