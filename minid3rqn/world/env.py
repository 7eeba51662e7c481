"""The quadrotor environment, one flight (``DroneEnv``) or N flights at once (``VecDroneEnv``).

Gymnasium conventions without the dependency:

    obs, info = env.reset(seed=None, options=None)
    obs, reward, terminated, truncated, info = env.step(action)

One step. The action index picks a row (v, omega) of the action table; the drone flies
the exact arc for ``dt`` seconds (``kinematics.integrate_arc``), checked for collision at
``n_sub`` equally spaced points no more than 0.1 m of arc apart. If any point has
d_nearest < ``safe_distance`` the drone stops at the first such point and the episode
terminates (a wall cannot be tunnelled through: every point of the path is within 0.05 m
of a checked point). Otherwise it ends at the arc's end. Then

    reward = reward_fn(d_nearest at the new pose, collided)     (paper: d or -1)
    terminated = collided,    truncated = (steps == max_steps) and not collided.

Observation: the RGB frame (H, W, 3) uint8 from the new pose. ``info`` holds "pose"
(x, y, yaw), "depth" (H, W) float32 ground truth, "d_nearest", "collided", "step" and
"scene_seed".

Worlds. Every ``reset`` generates a fresh world from the environment's generator (for
training diversity; ``episodes_per_world=k`` keeps each world for k episodes, since a
new world costs about as much as a few dozen steps) unless ``options`` say otherwise:
    {"scene_seed": k}   this scenario's world number k;
    {"new_world": False} keep the current world (a new start pose only);
    {"pose": (x, y, yaw)} start there instead of a random free start pose.
``reset(seed=s)`` re-seeds the generator first, so a seed fixes worlds and starts.

Changing the actions or the reward is one constructor argument:
    DroneEnv(actions=[[2.0, 0.0], [2.0, 0.3], [2.0, -0.3]], reward_fn=my_reward)
where ``my_reward(d_nearest, collided)`` must accept NumPy arrays too (VecDroneEnv calls
it once per step for all flights).
"""
from __future__ import annotations

import numpy as np

from .camera import Camera
from .distance import nearest_distance_batch, pymunk_nearest_distance, sample_start_pose
from .kinematics import (ACTION_INTERVAL, ACTIONS, MAX_SUBSTEP, SAFE_DISTANCE,
                         check_action_table, n_substeps, paper_reward, substep_poses)
from .renderer import render_batch
from .scenarios import SCENARIOS, make_scene
from .scene import SceneBatch

SCENE_SEED_RANGE = 2 ** 31


class Discrete:
    """The action space {0, 1, ..., n - 1}."""

    def __init__(self, n: int):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"Discrete: n must be an int >= 1; got {n!r}")
        self.n = int(n)

    def sample(self, rng: np.random.Generator, size=None):
        """A uniform random action (or an int64 array of ``size`` of them)."""
        return int(rng.integers(self.n)) if size is None else rng.integers(self.n, size=size)

    def contains(self, x) -> bool:
        return isinstance(x, (int, np.integer)) and not isinstance(x, bool) and 0 <= x < self.n

    def __repr__(self) -> str:
        return f"Discrete({self.n})"


class Box:
    """A box of arrays: ``shape``, ``dtype``, elementwise bounds ``low`` .. ``high``."""

    def __init__(self, low, high, shape, dtype):
        self.low, self.high, self.shape, self.dtype = low, high, tuple(shape), np.dtype(dtype)

    def contains(self, x) -> bool:
        x = np.asarray(x)
        return x.shape == self.shape and x.dtype == self.dtype and bool(
            np.all(x >= self.low) and np.all(x <= self.high))

    def __repr__(self) -> str:
        return f"Box({self.low}, {self.high}, {self.shape}, {self.dtype.name})"


def _check_common(scenario, camera, actions, reward_fn, max_steps, safe_distance, dt, name):
    if scenario not in SCENARIOS:
        raise ValueError(f"{name}: scenario must be one of {SCENARIOS}; got {scenario!r}")
    camera = Camera() if camera is None else camera
    if not isinstance(camera, Camera):
        raise TypeError(f"{name}: camera must be a Camera or None; got {type(camera).__name__}")
    actions = check_action_table(ACTIONS if actions is None else actions, f"{name}: actions")
    reward_fn = paper_reward if reward_fn is None else reward_fn
    if not callable(reward_fn):
        raise TypeError(f"{name}: reward_fn must be callable (d_nearest, collided) -> reward; "
                        f"got {type(reward_fn).__name__}")
    _check_positive_int(max_steps, f"{name}: max_steps")
    if not safe_distance >= 0:
        raise ValueError(f"{name}: safe_distance must be >= 0; got {safe_distance!r}")
    if not dt > 0:
        raise ValueError(f"{name}: dt must be > 0; got {dt!r}")
    return camera, actions, reward_fn


def _check_positive_int(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an int >= 1; got {value!r}")
    return int(value)


def _check_options(options, name):
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"{name}: options must be a dict or None; got {type(options).__name__}")
    unknown = set(options) - {"scene_seed", "new_world", "pose"}
    if unknown:
        raise ValueError(f"{name}: unknown option(s) {sorted(unknown)}; expected some of "
                         f"['new_world', 'pose', 'scene_seed']")
    return options


class DroneEnv:
    """One flight in one world (module docstring).

    Args:
        scenario: one of SCENARIOS.
        seed: int (or sequence of ints) seeding the generator of worlds and starts.
        camera: Camera (default 32x104, 90 deg).
        actions: (n_actions, 2) table of (forward speed m/s, yaw rate rad/s); default ACTIONS.
        reward_fn: (d_nearest, collided) -> reward; default ``paper_reward``.
        max_steps: steps before truncation (50, the paper's success criterion).
        safe_distance: collision threshold on d_nearest (0.5 m, paper).
        dt: seconds per action (0.4, paper).
        scene_overrides: dict of scenario parameters passed to ``make_scene``.
        observe: render obs and GT depth (False skips rendering: obs is None).
        episodes_per_world: episodes flown in each generated world (1: a new world
            every reset).
    """

    def __init__(self, scenario: str = "basic", seed=0, camera: Camera | None = None,
                 actions=None, reward_fn=None, max_steps: int = 50,
                 safe_distance: float = SAFE_DISTANCE, dt: float = ACTION_INTERVAL,
                 scene_overrides: dict | None = None, observe: bool = True,
                 episodes_per_world: int = 1):
        self.camera, self.actions, self.reward_fn = _check_common(
            scenario, camera, actions, reward_fn, max_steps, safe_distance, dt, "DroneEnv")
        self.scenario, self.max_steps = scenario, int(max_steps)
        self.safe_distance, self.dt = float(safe_distance), float(dt)
        self.scene_overrides = dict(scene_overrides or {})
        self.observe = bool(observe)
        self.episodes_per_world = _check_positive_int(episodes_per_world, "DroneEnv: "
                                                      "episodes_per_world")
        self.episodes = 0
        self.n_sub = n_substeps(self.actions, self.dt, MAX_SUBSTEP)
        self.action_space = Discrete(len(self.actions))
        self.observation_space = Box(0, 255, (self.camera.height, self.camera.width, 3), np.uint8)
        self.rng = np.random.default_rng(seed)
        self.scene = None
        self.scene_seed = None
        self.pose = None
        self.steps = 0
        self.done = True

    # Policies read the state as N = 1 flights.
    @property
    def scenes(self):
        return [self.scene]

    @property
    def poses(self) -> np.ndarray:
        return self.pose[None].copy()

    def reset(self, seed=None, options=None):
        """Start a new flight: (obs, info). See the module docstring for ``options``."""
        options = _check_options(options, "DroneEnv.reset")
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            self.episodes = 0
        scene_seed = int(self.rng.integers(SCENE_SEED_RANGE))       # always drawn: keeps
        if "scene_seed" in options:                                  # the stream aligned
            scene_seed = int(options["scene_seed"])
        due = self.episodes % self.episodes_per_world == 0
        if options.get("new_world", due or "scene_seed" in options) or self.scene is None:
            self.scene = make_scene(self.scenario, scene_seed, **self.scene_overrides)
            self.scene_seed = scene_seed
        self.episodes += 1
        if "pose" in options:
            start = np.asarray(options["pose"], dtype=np.float64)
            if start.shape != (3,) or not np.all(np.isfinite(start)):
                raise ValueError(f"DroneEnv.reset: options['pose'] must be 3 finite numbers "
                                 f"(x, y, yaw); got {options['pose']!r}")
        else:
            start = sample_start_pose(self.scene, self.rng, self.actions, self.dt,
                                      self.safe_distance)
        self.pose = start.copy()
        self.steps = 0
        self.done = False
        d = float(pymunk_nearest_distance(self.scene, self.pose[:2]))
        return self._observe(d, False)

    def _observe(self, d, collided):
        info = {"pose": self.pose.copy(), "d_nearest": d, "collided": collided,
                "step": self.steps, "scene_seed": self.scene_seed}
        obs = None
        if self.observe:
            rgb, depth = render_batch(self.scene, self.pose[None], self.camera)
            obs, info["depth"] = rgb[0], depth[0]
        return obs, info

    def step(self, action):
        """Fly one action: (obs, reward, terminated, truncated, info)."""
        if self.done:
            raise RuntimeError("DroneEnv.step: the episode has ended (or never started); "
                               "call reset() first")
        if not self.action_space.contains(action):
            raise ValueError(f"DroneEnv.step: action must be an int in [0, {self.action_space.n});"
                             f" got {action!r}")
        v, omega = self.actions[int(action)]
        path = substep_poses(self.pose[None], np.array([v]), np.array([omega]), self.dt,
                             self.n_sub)[0]                          # (n_sub, 3)
        d_path = pymunk_nearest_distance(self.scene, path[:, :2])
        hits = np.flatnonzero(d_path < self.safe_distance)
        collided = len(hits) > 0
        k = int(hits[0]) if collided else self.n_sub - 1
        self.pose = path[k].copy()
        self.steps += 1
        d = float(d_path[k])
        reward = float(self.reward_fn(d, collided))
        terminated = collided
        truncated = (not collided) and self.steps >= self.max_steps
        self.done = terminated or truncated
        obs, info = self._observe(d, collided)
        return obs, reward, terminated, truncated, info


class VecDroneEnv:
    """N flights stepped together: batched kinematics, distances and rendering.

    Flight i is the flight of ``DroneEnv(scenario, seed=[seed, first_index + i], ...)``:
    same worlds, starts and, for the same actions, the same trajectories (distances come
    from ``nearest_distance_batch``, which matches pymunk's to rounding).

    Args: as DroneEnv, plus
        n_envs: number of flights N.
        autoreset: when a flight ends, start its next episode in the same ``step`` call
            (its last obs, pose and depth go to info["final_obs"], ["final_pose"],
            ["final_depth"], marked by info["done"]). Without autoreset an ended flight
            stays put: it is skipped by ``step`` (reward 0, flags as they ended) and
            ``active`` turns False; ``reset`` starts all flights again.
        first_index: index of flight 0 in the seed stream (for splitting a large
            evaluation into chunks that reproduce one big run).

    ``reset``/``step`` return batched arrays: obs (N, H, W, 3) uint8, reward (N,),
    terminated (N,), truncated (N,) and info with "pose" (N, 3), "depth" (N, H, W),
    "d_nearest" (N,), "collided" (N,), "step" (N,), "scene_seed" (N,).
    """

    def __init__(self, n_envs: int, scenario: str = "basic", seed: int = 0,
                 camera: Camera | None = None, actions=None, reward_fn=None, max_steps: int = 50,
                 safe_distance: float = SAFE_DISTANCE, dt: float = ACTION_INTERVAL,
                 scene_overrides: dict | None = None, observe: bool = True,
                 episodes_per_world: int = 1, autoreset: bool = True, first_index: int = 0):
        if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
            raise ValueError(f"VecDroneEnv: n_envs must be an int >= 1; got {n_envs!r}")
        self.camera, self.actions, self.reward_fn = _check_common(
            scenario, camera, actions, reward_fn, max_steps, safe_distance, dt, "VecDroneEnv")
        self.n_envs, self.scenario, self.max_steps = int(n_envs), scenario, int(max_steps)
        self.safe_distance, self.dt = float(safe_distance), float(dt)
        self.scene_overrides = dict(scene_overrides or {})
        self.observe, self.autoreset = bool(observe), bool(autoreset)
        self.episodes_per_world = _check_positive_int(episodes_per_world, "VecDroneEnv: "
                                                      "episodes_per_world")
        self.episodes = np.zeros(int(n_envs), np.int64)
        self.seed, self.first_index = seed, int(first_index)
        self.n_sub = n_substeps(self.actions, self.dt, MAX_SUBSTEP)
        self.action_space = Discrete(len(self.actions))
        self.observation_space = Box(0, 255, (self.n_envs, self.camera.height,
                                              self.camera.width, 3), np.uint8)
        self.rngs = [np.random.default_rng([seed, self.first_index + i])
                     for i in range(self.n_envs)]
        self.scenes = [None] * self.n_envs
        self.batch = None
        self.scene_seeds = np.zeros(self.n_envs, np.int64)
        self.poses = np.zeros((self.n_envs, 3))
        self.steps = np.zeros(self.n_envs, np.int64)
        self.active = np.zeros(self.n_envs, bool)
        self._last = None

    def _reset_one(self, i, options):
        rng = self.rngs[i]
        scene_seed = int(rng.integers(SCENE_SEED_RANGE))
        if "scene_seed" in options:
            scene_seed = int(np.broadcast_to(options["scene_seed"], (self.n_envs,))[i])
        due = self.episodes[i] % self.episodes_per_world == 0
        if options.get("new_world", due or "scene_seed" in options) or self.scenes[i] is None:
            self.scenes[i] = make_scene(self.scenario, scene_seed, **self.scene_overrides)
            self.scene_seeds[i] = scene_seed
            if self.batch is not None:
                self.batch.set(i, self.scenes[i])
        self.episodes[i] += 1
        if "pose" in options:
            start = np.broadcast_to(np.asarray(options["pose"], np.float64), (self.n_envs, 3))[i]
        else:
            start = sample_start_pose(self.scenes[i], rng, self.actions, self.dt,
                                      self.safe_distance)
        self.poses[i] = start
        self.steps[i] = 0
        self.active[i] = True

    def reset(self, seed=None, options=None):
        """Start all N flights: (obs, info). ``seed`` re-seeds as in the constructor;
        ``options`` as DroneEnv's, where "scene_seed" and "pose" may be per flight."""
        options = _check_options(options, "VecDroneEnv.reset")
        if seed is not None:
            self.seed = seed
            self.rngs = [np.random.default_rng([seed, self.first_index + i])
                         for i in range(self.n_envs)]
            self.episodes[:] = 0
        for i in range(self.n_envs):
            self._reset_one(i, options)
        if self.batch is None or any(a is not b for a, b in zip(self.batch.scenes, self.scenes)):
            self.batch = SceneBatch(self.scenes)
        d = nearest_distance_batch(self.batch, self.poses[:, None, :2])[:, 0]
        return self._observe(d, np.zeros(self.n_envs, bool))

    def _observe(self, d, collided):
        info = {"pose": self.poses.copy(), "d_nearest": d, "collided": collided,
                "step": self.steps.copy(), "scene_seed": self.scene_seeds.copy()}
        obs = None
        if self.observe:
            obs, info["depth"] = render_batch(self.batch, self.poses, self.camera)
        self._last = (obs, info)
        return obs, info

    def step(self, actions):
        """Fly one action per flight: actions (N,) ints -> (obs, reward, terminated,
        truncated, info), all batched."""
        if self._last is None:
            raise RuntimeError("VecDroneEnv.step: call reset() first")
        a = np.asarray(actions)
        if a.shape != (self.n_envs,) or a.dtype.kind not in "iu":
            raise ValueError(f"VecDroneEnv.step: actions must be an int array of shape "
                             f"({self.n_envs},); got shape {a.shape}, dtype {a.dtype}")
        if np.any((a < 0) | (a >= self.action_space.n)):
            raise ValueError(f"VecDroneEnv.step: actions must lie in [0, {self.action_space.n});"
                             f" got {a[(a < 0) | (a >= self.action_space.n)][:5].tolist()}")
        live = self.active.copy()
        v, omega = self.actions[a, 0], self.actions[a, 1]
        path = substep_poses(self.poses, v, omega, self.dt, self.n_sub)        # (N, S, 3)
        d_path = nearest_distance_batch(self.batch, path[..., :2])             # (N, S)
        bad = d_path < self.safe_distance
        collided = bad.any(axis=1) & live
        k = np.where(collided, np.argmax(bad, axis=1), self.n_sub - 1)
        rows = np.arange(self.n_envs)
        new_pose = path[rows, k]
        d = d_path[rows, k]
        prev_info = self._last[1]
        self.poses = np.where(live[:, None], new_pose, self.poses)
        d = np.where(live, d, prev_info["d_nearest"])
        self.steps += live
        reward = np.where(live, np.asarray(self.reward_fn(d, collided), np.float64), 0.0)
        terminated = np.where(live, collided, prev_info["collided"])
        truncated = np.where(live, ~collided & (self.steps >= self.max_steps),
                             ~prev_info["collided"] & (self.steps >= self.max_steps))
        done = live & (terminated | truncated)
        self.active &= ~done
        obs, info = self._observe(d, terminated.copy())
        info["done"] = done
        if self.autoreset and done.any():
            # Keep the last frame of the ended flights, start their next episodes and
            # render only their first frames.
            idx = np.flatnonzero(done)
            info["final_pose"] = info["pose"].copy()
            if self.observe:
                info["final_obs"], info["final_depth"] = obs.copy(), info["depth"].copy()
            for i in idx:
                self._reset_one(i, {})
            d_new = nearest_distance_batch(self.batch, self.poses[:, None, :2])[:, 0]
            info["pose"][idx] = self.poses[idx]
            info["d_nearest"] = np.where(done, d_new, d)
            info["collided"] = np.where(done, False, info["collided"])
            info["step"][idx] = 0
            info["scene_seed"][idx] = self.scene_seeds[idx]
            if self.observe:
                rgb, depth = render_batch([self.scenes[i] for i in idx], self.poses[idx],
                                          self.camera)
                obs[idx], info["depth"][idx] = rgb, depth
        return obs, reward, terminated, truncated, info


__all__ = ["Discrete", "Box", "DroneEnv", "VecDroneEnv"]
