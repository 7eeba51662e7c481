"""Baseline pilots, vectorized over N flights: straight, random, and a map-knowing oracle.

A policy is a callable ``policy(env) -> actions (N,) int64`` reading the flights' state
from a DroneEnv (N = 1) or VecDroneEnv: ``env.poses`` (N, 3), ``env.scenes`` (N worlds),
``env.actions`` (the action table), ``env.dt`` and ``env.safe_distance``.

The oracle is privileged: it reads the map. Each step it scores candidate plans (action
sequences) over a look-ahead horizon and flies the first action of the best.

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
"""
from __future__ import annotations

import numpy as np

from .distance import clearance_field, sample_fields
from .kinematics import fly_plans, loiter_actions, loiter_circles, plan_paths


def _n_flights(env) -> int:
    return len(env.poses)


def straight_policy(env) -> np.ndarray:
    """Always the action with the smallest |yaw rate| (fly straight)."""
    return np.full(_n_flights(env), int(np.argmin(np.abs(env.actions[:, 1]))), np.int64)


def random_policy(rng: np.random.Generator):
    """A policy drawing uniform random actions from ``rng``."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"random_policy: rng must be a numpy Generator; got {type(rng).__name__}")

    def policy(env) -> np.ndarray:
        return rng.integers(len(env.actions), size=_n_flights(env))
    return policy


class Oracle:
    """The look-ahead planner (module docstring). Call it as a policy: ``oracle(env)``.
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

    def __init__(self, segments=(1, 2, 4, 8), spacing: float = 0.4, margin: float = 0.25,
                 cap: float = 1.5, turn_cost: float = 0.02, resolution: float = 0.25,
                 certify: int = 4):
        if not segments or any(int(s) < 1 for s in segments):
            raise ValueError(f"Oracle: segments must be positive step counts; got {segments!r}")
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

    def __call__(self, env) -> np.ndarray:
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


oracle_policy = Oracle()
