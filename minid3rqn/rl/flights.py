"""Many flights at once, as the Q-learning code needs them: a thin layer over ``world``.

Each of the ``n`` flights lives in a world drawn from a pool of ``n_worlds`` scenes of
one scenario (training and evaluation draw their pools from disjoint seed ranges, so
test flights are in fresh worlds) and starts at a random free pose. One ``step``:

    1. ``world.stepper.step_drones``: fly the chosen (speed, yaw rate) for 0.4 s along
       the exact arc; collision if the clearance drops below 0.5 m anywhere on it; the
       drone ends at the arc's end and is paid reward_fn(d_nearest there, collided) (the
       paper's Eq. 4 unless ``reward_fn`` is given);
    2. observe the new view: GT depth (``depth="gt"``, one ray cast per column; the
       environment, ``world.env.VecDroneEnv``, renders RGB on every step, ~10x slower)
       or the DispNet's depth from the RGB frame (``depth="pred"``; metres through the
       estimator's own scale, fixed from the flight speed);
       ``depth_fn(depth, rng)``, if given, corrupts it (exercise 8);
    3. encode it for the Q-net, the paper's depth maps scaled into [0, 1]:
           x = min(d, max_depth) / max_depth.

After ``max_steps`` actions without a collision a flight is *truncated* (a success, not
a terminal state). With ``autoreset`` a finished flight restarts at once in a new world
and start pose, and ``final_frames`` holds the last frame of the finished episode (the
replay needs it for the bootstrap).
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..world import Camera, SceneBatch, make_scene, render_batch, sample_start_pose
from ..world.kinematics import ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, check_action_table
from ..world.renderer import render_depth_batch
from ..world.stepper import check_reward_fn, step_drones

TRAIN_SEEDS = 0                 # training worlds: seeds in [0, 1e6)
TEST_SEEDS = 1_000_000          # evaluation worlds: seeds in [1e6, 2e6)
TEST_WORLDS = 271828            # the evaluation seed of the test worlds (docs/results.md)


@dataclass
class FlightsConfig:
    max_steps: int = 50          # paper: success = 50 steps without collision
    n_worlds: int = 32           # ours: scenes in the pool of one Flights object
    max_depth: float = 10.0      # ours: depth clip (m) for the Q-net input
    test_worlds: bool = False    # draw worlds from the evaluation seed range


def encode_depth(depth: np.ndarray, max_depth: float = 10.0) -> np.ndarray:
    """Depth in metres -> the Q-net's frames, x = min(d, max_depth) / max_depth in [0, 1]
    (float32)."""
    return (np.clip(depth, 0.0, max_depth) / max_depth).astype(np.float32)


@dataclass
class StepResult:
    frames: np.ndarray       # (n, H, W) float32 next observation (a new episode's first
                             # frame for a flight that was reset)
    final_frames: np.ndarray  # (n, H, W) the frame after the action (before any reset)
    rewards: np.ndarray      # (n,) float32, Eq. 4 (or reward_fn's)
    terminated: np.ndarray   # (n,) bool collision
    truncated: np.ndarray    # (n,) bool time limit reached without collision
    success: np.ndarray      # (n,) bool == truncated
    d_nearest: np.ndarray    # (n,) clearance at the new pose (m)


def depth_only(batch: SceneBatch, poses: np.ndarray, camera: Camera) -> np.ndarray:
    """GT pinhole depth (n, H, W) without colours (see ``world.render_depth_batch``)."""
    return render_depth_batch(batch, poses, camera)


class Flights:
    """``n`` parallel flights in ``scenario``; see the module docstring.

    Args:
        scenario, n, seed: the scenario, the number of flights, the seed of the pool of
            worlds and of every start pose.
        config: FlightsConfig (default FlightsConfig()).
        depth: "gt" or "pred" (with ``depth_estimator``: predict(rgb uint8 (m, H, W, 3))
            -> depth (m, H, W) metres).
        autoreset: restart finished flights inside ``step``.
        camera: Camera (default Camera()).
        actions: (n_actions, 2) table of (speed m/s, yaw rate rad/s); default ACTIONS.
        reward_fn: (d_nearest, collided[, yaw_rate]) -> reward, on arrays; default the
            paper's (``world.paper_reward``).
        depth_fn: (depth (m, H, W) float32 metres, rng) -> depth of the same shape,
            positive and finite: every observed depth map is replaced by it before it is
            encoded, so the policy sees, and the replay stores, the corrupted depth
            (collisions, clearances and rewards still come from the world). ``rng``
            (``depth_rng``) is a generator of its own, seeded from ``seed`` apart from
            the one that draws worlds and starts: the same seed flies the same worlds
            from the same poses with or without ``depth_fn``.
    """

    def __init__(self, scenario: str, n: int, seed: int = 0, config: FlightsConfig | None = None,
                 depth: str = "gt", depth_estimator=None, autoreset: bool = True,
                 camera: Camera | None = None, actions=None, reward_fn=None, depth_fn=None):
        if depth not in ("gt", "pred"):
            raise ValueError(f"Flights: depth must be 'gt' or 'pred'; got {depth!r}")
        if depth == "pred" and depth_estimator is None:
            raise ValueError("Flights: depth='pred' needs a depth_estimator (a DepthEstimator "
                             "with predict(rgb uint8 (N, H, W, 3)) -> depth (N, H, W))")
        if n < 1:
            raise ValueError(f"Flights: n must be >= 1; got {n}")
        self.scenario, self.n = scenario, int(n)
        self.cfg = config or FlightsConfig()
        n_worlds = self.cfg.n_worlds
        if isinstance(n_worlds, bool) or not isinstance(n_worlds, (int, np.integer)) \
                or n_worlds < 1:
            raise ValueError(f"Flights: config.n_worlds (the pool of scenes) must be an int "
                             f">= 1; got {n_worlds!r}")
        self.depth_mode, self.estimator = depth, depth_estimator
        self.autoreset = autoreset
        self.camera = Camera() if camera is None else camera
        self.actions = check_action_table(ACTIONS if actions is None else actions,
                                          "Flights: actions")
        self.n_actions = len(self.actions)
        self.reward_fn = check_reward_fn(reward_fn, "Flights")
        if depth_fn is not None and not callable(depth_fn):
            raise TypeError(f"Flights: depth_fn must be callable (depth, rng) -> depth or None; "
                            f"got {type(depth_fn).__name__}")
        self.depth_fn = depth_fn
        self.depth_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        self.frame_shape = (self.camera.height, self.camera.width)
        self.rng = np.random.default_rng(seed)
        base = TEST_SEEDS if self.cfg.test_worlds else TRAIN_SEEDS
        self.world_seeds = base + self.rng.choice(1_000_000, size=n_worlds, replace=False)
        self.worlds = [make_scene(scenario, int(s)) for s in self.world_seeds]
        self.world_of = np.zeros(self.n, dtype=np.int64)
        self.poses = np.zeros((self.n, 3))
        self.t = np.zeros(self.n, dtype=np.int64)
        self.batch = None
        self.last_depth = None
        self.last_rgb = None

    # -- observing ------------------------------------------------------------------
    def observe(self, idx=None):
        """Depth (metres), frames ([0, 1]) and the RGB frames (``depth="pred"``; else
        None) of flights ``idx`` (all by default)."""
        idx = np.arange(self.n) if idx is None else np.asarray(idx)
        poses = self.poses[idx]
        sub = self._sub_batch(idx)
        rgb = None
        if self.depth_mode == "gt":
            depth = depth_only(sub, poses, self.camera)
        else:
            rgb, _ = render_batch(sub, poses, self.camera)
            depth = np.array(self.estimator.predict(rgb), dtype=np.float32)
        if self.depth_fn is not None:
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
            raise ValueError(f"Flights: depth_fn(depth, rng) must return positive finite "
                             f"float depths (metres) of the input's shape {depth.shape}; got "
                             f"{problem} (python -m minid3rqn check depth-errors finds why)")
        return arr.astype(np.float32)

    def encode(self, depth: np.ndarray) -> np.ndarray:
        """Depth (metres) -> frames in [0, 1]."""
        return encode_depth(depth, self.cfg.max_depth)

    def gt_frames(self) -> np.ndarray:
        """GT depth frames (n, H, W) in [0, 1] of every flight at its current pose, in
        either depth mode: what a privileged teacher sees (``rl.distill``)."""
        return self.encode(depth_only(self.batch, self.poses, self.camera))

    def _sub_batch(self, idx) -> SceneBatch:
        """The worlds of flights ``idx`` as a SceneBatch."""
        return self.batch if len(idx) == self.n else self.batch.subset(idx)

    def _store(self, idx, depth, rgb):
        if self.last_depth is None:
            self.last_depth = np.zeros((self.n,) + self.frame_shape, np.float32)
        self.last_depth[idx] = depth
        if rgb is not None:
            if self.last_rgb is None:
                self.last_rgb = np.zeros((self.n,) + self.frame_shape + (3,), np.uint8)
            self.last_rgb[idx] = rgb

    def _new_episodes(self, idx):
        for k in idx:
            w = int(self.rng.integers(len(self.worlds)))
            self.world_of[k] = w
            self.poses[k] = sample_start_pose(self.worlds[w], self.rng)
            self.t[k] = 0
            if self.batch is not None:
                self.batch.set(int(k), self.worlds[w])

    def reset(self) -> np.ndarray:
        """Start every flight afresh; returns frames (n, H, W)."""
        self._new_episodes(range(self.n))
        self.batch = SceneBatch([self.worlds[k] for k in self.world_of])
        depth, frames, rgb = self.observe()
        self._store(np.arange(self.n), depth, rgb)
        self.frames = frames
        return frames.copy()

    # -- acting ---------------------------------------------------------------------
    def step(self, actions, active=None) -> StepResult:
        """Apply one action per flight (ignored where ``active`` is False)."""
        actions = np.asarray(actions, dtype=np.int64)
        if actions.shape != (self.n,) or actions.min() < 0 or actions.max() >= self.n_actions:
            raise ValueError(f"Flights.step: actions must be ({self.n},) ints in "
                             f"[0, {self.n_actions}); got shape {actions.shape}")
        act = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        idx = np.flatnonzero(act)
        rewards = np.zeros(self.n, np.float32)
        term = np.zeros(self.n, bool)
        trunc = np.zeros(self.n, bool)
        d_near = np.zeros(self.n)
        final = self.frames.copy()
        if len(idx):
            moved = step_drones(self.poses[idx], self.actions, actions[idx],
                                self._sub_batch(idx), self.dt, self.safe_distance,
                                self.reward_fn)
            self.poses[idx] = moved.poses
            self.t[idx] += 1
            d_near[idx] = moved.d_nearest
            rewards[idx] = moved.rewards
            term[idx] = moved.collided
            trunc[idx] = ~moved.collided & (self.t[idx] >= self.cfg.max_steps)
            depth, frames, rgb = self.observe(idx)
            self._store(idx, depth, rgb)
            final[idx] = frames
            self.frames[idx] = frames
        done = np.flatnonzero(term | trunc)
        if self.autoreset and len(done):
            self._new_episodes(done)
            depth, frames, rgb = self.observe(done)
            self._store(done, depth, rgb)
            self.frames[done] = frames
        return StepResult(self.frames.copy(), final, rewards, term, trunc, trunc.copy(), d_near)

    # -- privileged information, for the oracle and the top view -------------------
    def scene_of(self, k: int):
        return self.worlds[self.world_of[k]]

    # The attributes the world's baseline pilots read (``world.policies``: env.poses,
    # env.scenes, env.actions, env.dt, env.safe_distance, env.steps), so that the world's
    # Oracle flies a Flights object unchanged.
    @property
    def scenes(self):
        return [self.worlds[w] for w in self.world_of]

    @property
    def steps(self):
        return self.t

    dt = ACTION_INTERVAL
    safe_distance = SAFE_DISTANCE

    # -- saving (exact resume) ------------------------------------------------------
    def state_dict(self) -> dict[str, np.ndarray]:
        return {"world_of": self.world_of, "poses": self.poses, "t": self.t,
                "frames": self.frames, "last_depth": self.last_depth}

    def meta_state(self) -> dict:
        return {"rng": json.dumps(self.rng.bit_generator.state),
                "depth_rng": json.dumps(self.depth_rng.bit_generator.state)}

    def load_state_dict(self, arrays: dict, meta: dict) -> None:
        self.world_of[...] = arrays["world_of"]
        self.poses[...] = arrays["poses"]
        self.t[...] = arrays["t"]
        self.frames = arrays["frames"].copy()
        self.last_depth = arrays["last_depth"].copy()
        self.batch = SceneBatch([self.worlds[k] for k in self.world_of])
        self.rng.bit_generator.state = json.loads(meta["rng"])
        self.depth_rng.bit_generator.state = json.loads(meta["depth_rng"])
