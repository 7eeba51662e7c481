"""The quadrotor environment: N flights at once (``VecDroneEnv``), or one (``DroneEnv``).

Gymnasium conventions without the dependency:

    obs, info = env.reset(seed=None, options=None)
    obs, reward, terminated, truncated, info = env.step(action)

One step is ``stepper.step_drones`` (the arc flown, the collision check, the reward:
see there), the step of every flight in the package; then

    terminated = collided,    truncated = (steps == max_steps) and not collided.

Observation: the RGB frame (H, W, 3) uint8 from the new pose. ``info`` holds "pose"
(x, y, yaw), "depth" (H, W) float32 ground truth, "d_nearest", "collided", "step" and
"scene_seed" (``VecDroneEnv``: one row per flight). A flight that has ended stays put
(``step`` skips it: reward 0, flags as they ended) until the next ``reset``.

Worlds. Every ``reset`` generates a fresh world from the flight's generator unless
``options`` say otherwise:
    {"scene_seed": k}   this scenario's world number k;
    {"pose": (x, y, yaw)} start there instead of a random free start pose.
``reset(seed=s)`` re-seeds the generators first, so a seed fixes worlds and starts.

Changing the actions or the reward is one constructor argument:
    DroneEnv(actions=[[2.0, 0.0], [2.0, 0.3], [2.0, -0.3]], reward_fn=my_reward).
"""
from __future__ import annotations

import numpy as np

from .camera import Camera
from .distance import nearest_distance_batch, sample_start_pose
from .kinematics import ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, check_action_table
from .renderer import render_batch
from .scenarios import SCENARIOS, make_scene
from .scene import SceneBatch
from .stepper import check_reward_fn, step_drones

SCENE_SEED_RANGE = 2 ** 31


class Discrete:
    """The action space {0, 1, ..., n - 1} (n >= 1: the rows of a checked action table)."""

    def __init__(self, n: int):
        self.n = int(n)

    def contains(self, x) -> bool:
        return isinstance(x, (int, np.integer)) and not isinstance(x, bool) and 0 <= x < self.n


def _check_common(scenario, camera, actions, reward_fn, max_steps, safe_distance, dt, name):
    if scenario not in SCENARIOS:
        raise ValueError(f"{name}: scenario must be one of {SCENARIOS}; got {scenario!r}")
    camera = Camera() if camera is None else camera
    if not isinstance(camera, Camera):
        raise TypeError(f"{name}: camera must be a Camera or None; got {type(camera).__name__}")
    actions = check_action_table(ACTIONS if actions is None else actions, f"{name}: actions")
    reward_fn = check_reward_fn(reward_fn, name)
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


def _check_options(options, n, name):
    """``options`` as a dict, with "pose" as (n, 3) finite start poses."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"{name}: options must be a dict or None; got {type(options).__name__}")
    unknown = set(options) - {"scene_seed", "pose"}
    if unknown:
        raise ValueError(f"{name}: unknown option(s) {sorted(unknown)}; expected some of "
                         f"['pose', 'scene_seed']")
    if "pose" in options:
        try:
            poses = np.broadcast_to(np.asarray(options["pose"], np.float64), (n, 3))
        except (TypeError, ValueError):
            poses = None
        if poses is None or not np.all(np.isfinite(poses)):
            raise ValueError(f"{name}: options['pose'] must be 3 finite numbers (x, y, yaw), "
                             f"or one such row per flight ({n}, 3); got {options['pose']!r}")
        options = {**options, "pose": poses}
    return options


class VecDroneEnv:
    """N flights stepped together: batched kinematics, distances and rendering.

    Args:
        n_envs: number of flights N.
        scenario: one of SCENARIOS.
        seed: int; flight i draws its worlds and starts from
            ``np.random.default_rng([seed, first_index + i])``.
        camera: Camera (default 32x104, 90 deg).
        actions: (n_actions, 2) table of (forward speed m/s, yaw rate rad/s); default ACTIONS.
        reward_fn: (d_nearest, collided[, yaw_rate]) -> reward, on arrays; default
            ``paper_reward``.
        max_steps: steps before truncation (50, the paper's success criterion).
        safe_distance: collision threshold on the clearance (0.5 m, paper).
        dt: seconds per action (0.4, paper).
        observe: render obs and GT depth (False skips rendering: obs is None).
        first_index: index of flight 0 in the seed stream (for splitting a large
            evaluation into chunks that reproduce one big run).

    ``reset``/``step`` return batched arrays (module docstring); ``active`` (N,) marks
    the flights not yet ended.
    """

    def __init__(self, n_envs: int, scenario: str = "basic", seed=0,
                 camera: Camera | None = None, actions=None, reward_fn=None, max_steps: int = 50,
                 safe_distance: float = SAFE_DISTANCE, dt: float = ACTION_INTERVAL,
                 observe: bool = True, first_index: int = 0):
        name = type(self).__name__
        self.n_envs = _check_positive_int(n_envs, f"{name}: n_envs")
        self.camera, self.actions, self.reward_fn = _check_common(
            scenario, camera, actions, reward_fn, max_steps, safe_distance, dt, name)
        self.scenario, self.max_steps = scenario, int(max_steps)
        self.safe_distance, self.dt = float(safe_distance), float(dt)
        self.observe, self.first_index = bool(observe), int(first_index)
        self.action_space = Discrete(len(self.actions))
        self._seed(seed)
        self.scenes = [None] * self.n_envs
        self.batch = None
        self.scene_seeds = np.zeros(self.n_envs, np.int64)
        self.poses = np.zeros((self.n_envs, 3))
        self.steps = np.zeros(self.n_envs, np.int64)
        self.active = np.zeros(self.n_envs, bool)
        self._last = None

    def _seed(self, seed):
        self.rngs = [np.random.default_rng([seed, self.first_index + i])
                     for i in range(self.n_envs)]

    def _reset_one(self, i, options):
        rng = self.rngs[i]
        scene_seed = int(rng.integers(SCENE_SEED_RANGE))             # always drawn: keeps
        if "scene_seed" in options:                                  # the stream aligned
            scene_seed = int(np.broadcast_to(options["scene_seed"], (self.n_envs,))[i])
        self.scenes[i] = make_scene(self.scenario, scene_seed)
        self.scene_seeds[i] = scene_seed
        if "pose" in options:
            start = options["pose"][i]
        else:
            start = sample_start_pose(self.scenes[i], rng, self.actions, self.dt,
                                      self.safe_distance)
        self.poses[i] = start
        self.steps[i] = 0
        self.active[i] = True

    def reset(self, seed=None, options=None):
        """Start all N flights: (obs, info). ``seed`` re-seeds as in the constructor;
        ``options`` as in the module docstring, "scene_seed" and "pose" may be per flight."""
        options = _check_options(options, self.n_envs, f"{type(self).__name__}.reset")
        if seed is not None:
            self._seed(seed)
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

    def _check_actions(self, actions) -> np.ndarray:
        name = f"{type(self).__name__}.step"
        if self._last is None:
            raise RuntimeError(f"{name}: call reset() first")
        a = np.asarray(actions)
        if a.shape != (self.n_envs,) or a.dtype.kind not in "iu":
            raise ValueError(f"{name}: actions must be an int array of shape ({self.n_envs},); "
                             f"got shape {a.shape}, dtype {a.dtype}")
        if np.any((a < 0) | (a >= self.action_space.n)):
            raise ValueError(f"{name}: actions must lie in [0, {self.action_space.n}); got "
                             f"{a[(a < 0) | (a >= self.action_space.n)][:5].tolist()}")
        return a

    def step(self, actions):
        """Fly one action per flight: actions (N,) ints -> (obs, reward, terminated,
        truncated, info), all batched."""
        a = self._check_actions(actions)
        prev = self._last[1]
        d, collided = prev["d_nearest"].copy(), prev["collided"].copy()
        reward = np.zeros(self.n_envs)
        idx = np.flatnonzero(self.active)
        if len(idx):
            batch = self.batch if len(idx) == self.n_envs else self.batch.subset(idx)
            moved = step_drones(self.poses[idx], self.actions, a[idx], batch, self.dt,
                                self.safe_distance, self.reward_fn)
            self.poses[idx] = moved.poses
            d[idx], collided[idx], reward[idx] = moved.d_nearest, moved.collided, moved.rewards
            self.steps[idx] += 1
        terminated = collided                      # ended flights keep their flags
        truncated = ~collided & (self.steps >= self.max_steps)
        done = self.active & (terminated | truncated)
        self.active &= ~done
        obs, info = self._observe(d, terminated.copy())
        return obs, reward, terminated, truncated, info


class DroneEnv(VecDroneEnv):
    """One flight in one world: ``VecDroneEnv`` with N = 1, taking and giving one
    flight's values: an int action; obs (H, W, 3); a float reward; bool flags; info with
    "pose" (3,), "depth" (H, W) and numbers. Once the flight has ended, ``step`` raises
    until ``reset``.

    Args: as VecDroneEnv's, without n_envs and first_index. ``seed`` (an int
    or a sequence of ints) seeds the generator of worlds and starts as
    ``np.random.default_rng(seed)``: ``DroneEnv(seed=[s, i])`` flies flight i of
    ``VecDroneEnv(n, seed=s)``.
    """

    def __init__(self, scenario: str = "basic", seed=0, camera: Camera | None = None,
                 actions=None, reward_fn=None, max_steps: int = 50,
                 safe_distance: float = SAFE_DISTANCE, dt: float = ACTION_INTERVAL,
                 observe: bool = True):
        super().__init__(1, scenario, seed, camera, actions, reward_fn, max_steps,
                         safe_distance, dt, observe)

    def _seed(self, seed):
        self.rngs = [np.random.default_rng(seed)]

    @property
    def pose(self) -> np.ndarray:
        return self.poses[0]

    @property
    def scene(self):
        return self.scenes[0]

    @property
    def scene_seed(self) -> int:
        return int(self.scene_seeds[0])

    @property
    def done(self) -> bool:
        return not self.active[0]

    @staticmethod
    def _one(obs, info):
        """Flight 0's obs and info, numbers as Python scalars."""
        one = {k: v[0].item() if v.ndim == 1 else v[0] for k, v in info.items()}
        return None if obs is None else obs[0], one

    def reset(self, seed=None, options=None):
        """Start a new flight: (obs, info). See the module docstring for ``options``."""
        return self._one(*super().reset(seed, options))

    def step(self, action):
        """Fly one action: (obs, reward, terminated, truncated, info)."""
        if self.done:
            raise RuntimeError("DroneEnv.step: the episode has ended (or never started); "
                               "call reset() first")
        if not self.action_space.contains(action):
            raise ValueError(f"DroneEnv.step: action must be an int in [0, {self.action_space.n});"
                             f" got {action!r}")
        obs, reward, term, trunc, info = super().step(np.array([action], np.int64))
        obs, info = self._one(obs, info)
        return obs, float(reward[0]), bool(term[0]), bool(trunc[0]), info
