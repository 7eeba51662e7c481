"""The drone environment: N flights stepped together (N = 1: one drone), Gymnasium-shaped.

    env = DroneEnv("basic", n_envs=16, seed=0, worlds="train", observation="depth")
    obs, info = env.reset(seed=None, options=None)
    obs, reward, terminated, truncated, info = env.step(actions)      # (N,) ints

Every flight of the package is flown here (training, evaluation, ``fly``, the classroom,
and any Gymnasium library through ``minid3rqn.gym``). One step:

    1. ``stepper.step_drones``: fly the chosen (speed, yaw rate) for 0.4 s along the
       exact arc; collision if the clearance drops below 0.5 m anywhere on it; the drone
       ends at the arc's end, paid reward_fn(d_nearest there, collided) (Eq. 4 default);
    2. observe the new view, chosen at construction (``observation``): "depth" (GT depth
       in metres, (N, H, W) float32), "pred" (the DispNet's depth in metres from the RGB
       frame, ``depth_model``), "rgb" ((N, H, W, 3) uint8) or None (poses only);
       ``depth_fn(depth, rng)`` replaces every depth map seen (exercise 8); the Q-nets
       read it encoded and stacked (``rl.observe``), a step of their own;
    3. terminated = collided; truncated = ``max_steps`` actions flown without one (the
       paper's success, not a terminal state; ``info["is_success"]``).

Worlds: ``worlds="train"`` draws a pool of ``n_worlds`` worlds from the training seeds
[0, 1e6), ``"test"`` from the evaluation seeds [1e6, 2e6); a sequence of world seeds is
the pool. Each episode flies a world of the pool from a random free start;
``reset(options=...)`` may pin them, {"scene_seed": k} and {"pose": (x, y, yaw)} (one
value or one per flight). Everything random comes from ``seed`` (None: fresh entropy);
``reset(seed=s)`` starts over as if constructed with s.

A flight that has ended stays put until the next ``reset`` (not stepped: reward 0, both
flags False); with ``autoreset`` it restarts at once, and ``info["final_obs"]`` holds
every flight's observation before any restart. ``info`` also holds "d_nearest",
"collided", "is_success", "step" and "scene_seed" (each flight's world), one entry per
flight. ``render()`` (``render_mode="rgb_array"``): flight 0's top view and camera frame.
"""
from __future__ import annotations

import json

import numpy as np

from .camera import Camera
from .distance import nearest_distance_batch, sample_start_pose
from .kinematics import ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, check_action_table
from .renderer import render_batch, render_depth_batch
from .scenarios import SCENARIOS, make_scene
from .scene import SceneBatch
from .stepper import check_reward_fn, step_drones

WORLD_SEEDS = {"train": 0, "test": 1_000_000}     # each range holds 1e6 world seeds
OBSERVATIONS = ("depth", "pred", "rgb", None)
RENDER_MODES = (None, "rgb_array")


def _positive_int(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an int >= 1; got {value!r}")
    return int(value)


def draw_worlds(worlds, rng: np.random.Generator, n_worlds: int) -> np.ndarray:
    """The pool of world seeds: ``n_worlds`` distinct seeds of the ``worlds`` range
    ("train" or "test") drawn from ``rng``; or ``worlds`` itself, a sequence of seeds."""
    if isinstance(worlds, str):
        return WORLD_SEEDS[worlds] + rng.choice(1_000_000, size=n_worlds, replace=False)
    return np.asarray(worlds, np.int64)


class DroneEnv:
    """N flights in worlds of one scenario; see the module docstring.

    Args:
        scenario: one of SCENARIOS.
        n_envs: the number of flights N.
        seed: the seed of the pool of worlds, of every start pose and of ``depth_fn``'s
            generator (None: fresh entropy).
        worlds: "train" | "test" | a sequence of world seeds (the pool).
        n_worlds: worlds in the pool drawn from a seed range.
        observation: "depth" | "pred" | "rgb" | None.
        depth_model: the DispNet for "pred" (``depth.evaluate.DepthEstimator``).
        depth_fn: (depth (m, H, W) metres, rng) -> positive finite depth of that shape,
            seen in place of every depth map (rewards and collisions are the world's);
            ``rng`` is its own, so a seed flies the same flights with or without it.
        camera: Camera (default 32x104, 90 degrees).
        actions: (n_actions, 2) table of (speed m/s, yaw rate rad/s); default ACTIONS.
        reward_fn: (d_nearest, collided[, yaw_rate]) -> reward, on arrays; default the
            paper's (``kinematics.paper_reward``).
        max_steps: actions before truncation (50, the paper's success).
        autoreset: restart finished flights inside ``step``.
        render_mode: None or "rgb_array".
    """

    safe_distance, dt = SAFE_DISTANCE, ACTION_INTERVAL   # the collision threshold (paper)

    def __init__(self, scenario: str = "basic", n_envs: int = 1, *, seed=None, worlds="train",
                 n_worlds: int = 32, observation: str | None = "depth", depth_model=None,
                 depth_fn=None, camera: Camera | None = None, actions=None, reward_fn=None,
                 max_steps: int = 50, autoreset: bool = False, render_mode: str | None = None):
        name = "DroneEnv"
        if scenario not in SCENARIOS:
            raise ValueError(f"{name}: scenario must be one of {SCENARIOS}; got {scenario!r}")
        self.n_envs = _positive_int(n_envs, f"{name}: n_envs")
        pool = None if isinstance(worlds, str) or worlds is None else np.asarray(worlds)
        if worlds not in WORLD_SEEDS if pool is None else (pool.ndim != 1 or len(pool) < 1
                                                            or pool.dtype.kind not in "iu"
                                                            or (pool < 0).any()):
            raise ValueError(f"{name}: worlds must be 'train', 'test' or a sequence of world "
                             f"seeds (ints >= 0); got {worlds!r}")
        self.n_worlds = _positive_int(n_worlds, f"{name}: n_worlds (the pool of worlds)") \
            if pool is None else len(pool)
        if observation not in OBSERVATIONS:
            raise ValueError(f"{name}: observation must be one of {OBSERVATIONS}; "
                             f"got {observation!r}")
        if (observation == "pred") != (depth_model is not None):
            raise ValueError(f"{name}: depth_model (a DispNet with predict(rgb uint8 (N, H, "
                             f"W, 3)) -> depth (N, H, W)) is given with observation='pred' "
                             f"and only then; got observation={observation!r}, depth_model "
                             f"{type(depth_model).__name__}")
        if depth_fn is not None and (not callable(depth_fn) or observation in ("rgb", None)):
            raise TypeError(f"{name}: depth_fn must be callable (depth, rng) -> depth, with "
                            f"observation 'depth' or 'pred'; got {type(depth_fn).__name__} "
                            f"with observation={observation!r}")
        self.camera = Camera() if camera is None else camera
        if not isinstance(self.camera, Camera):
            raise TypeError(f"{name}: camera must be a Camera or None; got "
                            f"{type(camera).__name__}")
        self.actions = check_action_table(ACTIONS if actions is None else actions,
                                          f"{name}: actions")
        self.reward_fn = check_reward_fn(reward_fn, name)
        self.max_steps = _positive_int(max_steps, f"{name}: max_steps")
        if render_mode not in RENDER_MODES:
            raise ValueError(f"{name}: render_mode must be one of {RENDER_MODES}; got "
                             f"{render_mode!r}")
        self.scenario, self.worlds_kind = scenario, worlds
        self.observation, self.estimator, self.depth_fn = observation, depth_model, depth_fn
        self.autoreset, self.render_mode = bool(autoreset), render_mode
        self.n_actions, self.frame_shape = len(self.actions), self.camera.shape
        n = self.n_envs
        self.poses, self.d_nearest = np.zeros((n, 3)), np.zeros(n)
        self.steps, self.scene_seeds = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self.active, self.scenes = np.zeros(n, bool), [None] * n
        self.batch = self.obs = self.last_rgb = None
        self._path = []
        self._seed(seed)

    def _seed(self, seed) -> None:
        """The generators and the pool of worlds of ``seed`` (the constructor's)."""
        ss = np.random.SeedSequence(seed)
        self.rng = np.random.default_rng(ss)
        self.depth_rng = np.random.default_rng(ss.spawn(1)[0])
        self.world_seeds = draw_worlds(self.worlds_kind, self.rng, self.n_worlds)
        self.worlds = [make_scene(self.scenario, int(s)) for s in self.world_seeds]

    # -- observing ------------------------------------------------------------------
    def batch_of(self, idx) -> SceneBatch:
        """The worlds of flights ``idx`` (ints) as a SceneBatch."""
        return self.batch if len(idx) == self.n_envs else self.batch.subset(idx)

    def observe(self, idx) -> None:
        """Observe flights ``idx`` (ints) at their poses into ``self.obs`` (and the RGB
        frames into ``self.last_rgb``, when rendered)."""
        if self.observation is None:
            return
        poses, sub = self.poses[idx], self.batch_of(idx)
        if self.observation == "depth":
            obs, rgb = render_depth_batch(sub, poses, self.camera), None
        else:
            rgb, _ = render_batch(sub, poses, self.camera)
            obs = rgb if self.observation == "rgb" else \
                np.array(self.estimator.predict(rgb), dtype=np.float32)
        if self.depth_fn is not None:
            obs = self.corrupt(obs)
        if self.obs is None:
            self.obs = np.zeros((self.n_envs,) + obs.shape[1:], obs.dtype)
        self.obs[idx] = obs
        if rgb is not None:
            if self.last_rgb is None:
                self.last_rgb = np.zeros((self.n_envs,) + rgb.shape[1:], np.uint8)
            self.last_rgb[idx] = rgb

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
            raise ValueError(f"DroneEnv: depth_fn(depth, rng) must return positive finite "
                             f"float depths (metres) of the input's shape {depth.shape}; got "
                             f"{problem} (python -m minid3rqn check depth-errors finds why)")
        return arr.astype(np.float32)

    def gt_depth(self) -> np.ndarray:
        """GT depth (N, H, W) in metres of every flight at its pose, whatever the
        observation: what a privileged teacher sees (``rl.distill``)."""
        return render_depth_batch(self.batch, self.poses, self.camera)

    def _result(self, collided, success):
        """(obs, info) as ``reset`` and ``step`` return them (copies)."""
        return None if self.obs is None else self.obs.copy(), {
            "d_nearest": self.d_nearest.copy(), "collided": collided, "is_success": success,
            "step": self.steps.copy(), "scene_seed": self.scene_seeds.copy()}

    # -- episodes -------------------------------------------------------------------
    def _new_episodes(self, idx, options=None) -> None:
        options = options or {}
        for k in idx:
            w = int(self.rng.integers(self.n_worlds))
            seed, scene = int(self.world_seeds[w]), self.worlds[w]
            if "scene_seed" in options:
                seed = int(options["scene_seed"][k])
                scene = make_scene(self.scenario, seed)
            self.scenes[k], self.scene_seeds[k] = scene, seed
            self.poses[k] = options["pose"][k] if "pose" in options else sample_start_pose(
                scene, self.rng, self.actions, self.dt, self.safe_distance)
            self.steps[k] = 0
            self.active[k] = True
            if self.batch is not None:
                self.batch.set(int(k), scene)

    def _check_options(self, options) -> dict:
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise TypeError(f"DroneEnv.reset: options must be a dict or None; got "
                            f"{type(options).__name__}")
        unknown = set(options) - {"scene_seed", "pose"}
        if unknown:
            raise ValueError(f"DroneEnv.reset: unknown option(s) {sorted(unknown)}; expected "
                             f"some of ['pose', 'scene_seed']")
        out, n = {}, self.n_envs
        if "scene_seed" in options:
            seeds = np.asarray(options["scene_seed"])
            if seeds.dtype.kind not in "iu" or seeds.ndim > 1 or (seeds < 0).any():
                raise ValueError(f"DroneEnv.reset: options['scene_seed'] must be a world seed "
                                 f"(int >= 0) or one per flight; got {options['scene_seed']!r}")
            out["scene_seed"] = np.broadcast_to(seeds, (n,))
        if "pose" in options:
            try:
                poses = np.broadcast_to(np.asarray(options["pose"], np.float64), (n, 3))
            except (TypeError, ValueError):
                poses = None
            if poses is None or not np.all(np.isfinite(poses)):
                raise ValueError(f"DroneEnv.reset: options['pose'] must be 3 finite numbers "
                                 f"(x, y, yaw), or one such row per flight ({n}, 3); got "
                                 f"{options['pose']!r}")
            out["pose"] = poses
        return out

    def reset(self, *, seed=None, options=None):
        """Start every flight afresh: (obs, info). ``seed``: start over as if constructed
        with it; ``options``: the module docstring."""
        options = self._check_options(options)
        if seed is not None:
            self._seed(seed)
        self.batch = None
        self._new_episodes(range(self.n_envs), options)
        self.batch = SceneBatch(self.scenes)
        self.d_nearest = nearest_distance_batch(self.batch, self.poses[:, None, :2])[:, 0]
        self.observe(np.arange(self.n_envs))
        self._path = [self.poses[0].copy()]
        return self._result(np.zeros(self.n_envs, bool), np.zeros(self.n_envs, bool))

    # -- acting ---------------------------------------------------------------------
    def _check_actions(self, actions) -> np.ndarray:
        if self.batch is None:
            raise RuntimeError("DroneEnv.step: call reset() first")
        a = np.asarray(actions)
        if a.shape != (self.n_envs,) or a.dtype.kind not in "iu":
            raise ValueError(f"DroneEnv.step: actions must be an int array of shape "
                             f"({self.n_envs},); got shape {a.shape}, dtype {a.dtype}")
        bad = (a < 0) | (a >= self.n_actions)
        if bad.any():
            raise ValueError(f"DroneEnv.step: actions must lie in [0, {self.n_actions}); got "
                             f"{a[bad][:5].tolist()}")
        return a.astype(np.int64)

    def step(self, actions):
        """Fly one action per flight: actions (N,) ints -> (obs, reward, terminated,
        truncated, info), one entry per flight (module docstring)."""
        actions = self._check_actions(actions)
        n = self.n_envs
        rewards = np.zeros(n, np.float32)
        term, trunc = np.zeros(n, bool), np.zeros(n, bool)
        idx = np.flatnonzero(self.active)
        if len(idx):
            moved = step_drones(self.poses[idx], self.actions, actions[idx],
                                self.batch_of(idx), self.dt, self.safe_distance,
                                self.reward_fn)
            self.poses[idx] = moved.poses
            self.steps[idx] += 1
            self.d_nearest[idx] = moved.d_nearest
            rewards[idx] = moved.rewards
            term[idx] = moved.collided
            trunc[idx] = ~moved.collided & (self.steps[idx] >= self.max_steps)
            self.observe(idx)
        if self.active[0]:
            self._path.append(self.poses[0].copy())
        done = np.flatnonzero(term | trunc)
        obs, info = self._result(term.copy(), trunc.copy())
        if self.autoreset:
            info["final_obs"] = obs
            if len(done):                 # the new episodes' first views
                self._new_episodes(done)
                self.observe(done)
                obs = self._result(term, trunc)[0]
                if done[0] == 0:
                    self._path = [self.poses[0].copy()]
        else:
            self.active[done] = False
        return obs, rewards, term, trunc, info

    # -- pictures -------------------------------------------------------------------
    def render(self):
        """``render_mode="rgb_array"``: the top view of flight 0 (its path, heading and
        field of view) beside its camera frame, (H, W, 3) uint8; None otherwise."""
        if self.render_mode is None:
            return None
        if self.batch is None:
            raise RuntimeError("DroneEnv.render: call reset() first")
        from .. import viz
        from .topview import topdown
        rgb, _ = render_batch(self.scenes[0], self.poses[:1], self.camera)
        top = np.asarray(topdown(self.scenes[0], np.array(self._path), self.poses[0],
                                 self.camera, 192))
        return viz.hstack([top, viz.resize(rgb[0], 192)], 192)

    # -- saving (exact resume) ------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        state = {"world_seeds": self.world_seeds, "scene_seeds": self.scene_seeds,
                 "poses": self.poses, "steps": self.steps, "active": self.active,
                 "d_nearest": self.d_nearest}
        if self.obs is not None:
            state["obs"] = self.obs
        return {k: np.array(v) for k, v in state.items()}

    def meta_state(self) -> dict:
        return {"rng": json.dumps(self.rng.bit_generator.state),
                "depth_rng": json.dumps(self.depth_rng.bit_generator.state)}

    def load_state_dict(self, arrays: dict, meta: dict) -> None:
        if not np.array_equal(arrays["world_seeds"], self.world_seeds):
            self.world_seeds = np.array(arrays["world_seeds"])
            self.worlds = [make_scene(self.scenario, int(s)) for s in self.world_seeds]
        pool = {int(s): w for s, w in zip(self.world_seeds, self.worlds)}
        self.scene_seeds[...] = arrays["scene_seeds"]
        self.scenes = [pool.get(int(s)) or make_scene(self.scenario, int(s))
                       for s in self.scene_seeds]
        for key in ("poses", "steps", "active", "d_nearest"):
            getattr(self, key)[...] = arrays[key]
        self.obs = np.array(arrays["obs"]) if "obs" in arrays else None
        self.batch = SceneBatch(self.scenes)
        self._path = [self.poses[0].copy()]
        self.rng.bit_generator.state = json.loads(meta["rng"])
        self.depth_rng.bit_generator.state = json.loads(meta["depth_rng"])
