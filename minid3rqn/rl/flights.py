"""Many flights at once, as the Q-learning code needs them: a thin layer over ``world``.

Each of the ``n`` flights lives in a world drawn from a pool of ``n_worlds`` scenes of
one scenario (training and evaluation draw their pools from disjoint seed ranges, so
test flights are in fresh worlds) and starts at a random free pose. One ``step``:

    1. fly the chosen (speed, yaw rate) for 0.4 s along the exact arc, checking the
       clearance every 0.1 m (``kinematics.substep_poses``);
    2. collision if the clearance drops below 0.5 m at any check (paper; the same test
       as ``world.env.VecDroneEnv``, which renders RGB on every step: this layer casts
       depth only when the Q-net reads GT depth, ~10x faster);
    3. reward: the paper's Eq. 4, d_nearest at the new pose, or -1 on collision;
    4. render the new view: GT depth (``depth="gt"``, one ray cast per column) or the
       DispNet's depth from the RGB frame (``depth="pred"``; metres through the
       estimator's own scale, fixed from the flight speed, times ``depth_scale``).

The Q-nets read ``frames``, depth encoded into [0, 1] (``FlightsConfig.encoding``):

    "depth"    (the paper's depth maps)  x = min(d, max_depth) / max_depth
    "inverse"  (ours; inverse depth)     x = near / clip(d, near, max_depth),  near = 0.5 m

Inverse depth spends the input's range near the drone: 1 m, 2 m and 10 m read 0.5,
0.25 and 0.05, where as depth they read 0.1, 0.2 and 1.0; and a depth error of a given
fraction weighs less the farther away it is. Whether that helps a net on the DispNet's
depth: docs/experiments.md, "Which depth errors cost flights".

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
from ..world.distance import nearest_distance_batch
from ..world.geometry import relative_transform
from ..world.scenarios import DEFAULTS
from ..world.kinematics import (ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, n_substeps,
                                paper_reward, substep_poses)
from ..world.renderer import render_depth_batch

TRAIN_SEEDS = 0                 # training worlds: seeds in [0, 1e6)
TEST_SEEDS = 1_000_000          # evaluation worlds: seeds in [1e6, 2e6)
VALIDATION_SEEDS = 2_000_000    # validation worlds (choosing between models): [2e6, 3e6)


@dataclass
class FlightsConfig:
    max_steps: int = 50          # paper: success = 50 steps without collision
    n_worlds: int = 32           # ours: scenes in the pool of one Flights object
    max_depth: float = 10.0      # ours: depth clip (m) for the Q-net input
    depth_scale: float = 1.0     # extra factor on predicted depth (1: trust the estimator)
    test_worlds: bool = False    # draw worlds from the evaluation seed range
    validation_worlds: bool = False  # draw them from the validation range (model selection:
                                     # a choice made there never sees a test world)
    horizon_row: float | None = None  # ours: the camera's horizon row (None: the middle row;
                                      # Camera.horizon_row, docs/depth.md section 7)
    encoding: str = "depth"      # ours: what a frame's value is: "depth" or "inverse"
                                 # (inverse depth; the module docstring)
    depth_noise: float = 0.0     # ours: std of a smooth random error in log depth put on
                                 # every observed frame (0: none; Flights.depth_error)
    scene: dict | None = None    # ours: scenario parameters replacing the defaults in
                                 # make_scene (world.scenarios.DEFAULTS), e.g.
                                 # {"min_gap": 2.0}; None: the scenario as it is
    scene_mix: float = 1.0       # ours: the fraction of the pool built with ``scene``; the
                                 # other worlds are the scenario as it is (a mixed pool)


ENCODINGS = ("depth", "inverse")
NEAR = SAFE_DISTANCE             # "inverse": the distance (m) encoded as 1


def encode_depth(depth: np.ndarray, encoding: str = "depth", max_depth: float = 10.0) -> np.ndarray:
    """Depth in metres -> the Q-net's frames in [0, 1] (float32); see the module docstring."""
    if encoding == "depth":
        x = np.clip(depth, 0.0, max_depth) / max_depth
    elif encoding == "inverse":
        x = NEAR / np.clip(depth, NEAR, max_depth)
    else:
        raise ValueError(f"encode_depth: encoding must be one of {ENCODINGS}; got {encoding!r}")
    return x.astype(np.float32)


def _interpolate_knots(knots: np.ndarray, n: int) -> np.ndarray:
    """(m, k) values at k evenly spaced knots -> (m, n) linearly interpolated between
    them at n evenly spaced points (the first and last points on the end knots)."""
    k = knots.shape[1]
    x = np.linspace(0.0, k - 1, n)
    i0 = np.minimum(np.floor(x).astype(np.int64), k - 2)
    f = x - i0
    return knots[:, i0] * (1.0 - f) + knots[:, i0 + 1] * f


@dataclass
class StepResult:
    frames: np.ndarray       # (n, H, W) float32 next observation (a new episode's first
                             # frame for a flight that was reset)
    final_frames: np.ndarray  # (n, H, W) the frame after the action (before any reset)
    rewards: np.ndarray      # (n,) float32, Eq. 4
    terminated: np.ndarray   # (n,) bool collision
    truncated: np.ndarray    # (n,) bool time limit reached without collision
    success: np.ndarray      # (n,) bool == truncated
    d_nearest: np.ndarray    # (n,) clearance at the new pose (m)


def depth_only(batch: SceneBatch, poses: np.ndarray, camera: Camera) -> np.ndarray:
    """GT pinhole depth (n, H, W) without colours (see ``world.render_depth_batch``)."""
    return render_depth_batch(batch, poses, camera)


class Flights:
    """``n`` parallel flights in ``scenario``; see the module docstring."""

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
        if self.cfg.encoding not in ENCODINGS:
            raise ValueError(f"Flights: config.encoding must be one of {ENCODINGS}; got "
                             f"{self.cfg.encoding!r}")
        noise = self.cfg.depth_noise
        if isinstance(noise, bool) or not isinstance(noise, (int, float, np.floating)) \
                or not 0.0 <= noise < 1.0:
            raise ValueError(f"Flights: config.depth_noise (std of the log-depth error) must "
                             f"be a number in [0, 1); got {noise!r}")
        scene = self.cfg.scene
        if scene is not None:
            if not isinstance(scene, dict):
                raise ValueError(f"Flights: config.scene must be a dict of scenario "
                                 f"parameters or None; got {type(scene).__name__}")
            unknown = sorted(set(scene) - set(DEFAULTS.get(scenario, scene)))
            if unknown:
                raise ValueError(f"Flights: config.scene has unknown parameter(s) {unknown} "
                                 f"for scenario {scenario!r}; expected some of "
                                 f"{sorted(DEFAULTS[scenario])}")
        mix = self.cfg.scene_mix
        if isinstance(mix, bool) or not isinstance(mix, (int, float, np.floating)) \
                or not 0.0 <= mix <= 1.0:
            raise ValueError(f"Flights: config.scene_mix (the fraction of worlds built with "
                             f"config.scene) must be a number in [0, 1]; got {mix!r}")
        if mix != 1.0 and scene is None:
            raise ValueError(f"Flights: config.scene_mix is {mix:g} but config.scene is None; "
                             f"a mixed pool needs the parameters of its other worlds")
        n_worlds = self.cfg.n_worlds
        if isinstance(n_worlds, bool) or not isinstance(n_worlds, (int, np.integer)) \
                or n_worlds < 1:
            raise ValueError(f"Flights: config.n_worlds (the pool of scenes) must be an int "
                             f">= 1; got {n_worlds!r}")
        self.depth_mode, self.estimator = depth, depth_estimator
        self.autoreset = autoreset
        if camera is None:
            camera = Camera(horizon_row=self.cfg.horizon_row)
        elif self.cfg.horizon_row is not None and camera.cy != self.cfg.horizon_row:
            raise ValueError(f"Flights: camera has its horizon at row {camera.cy:g} but "
                             f"config.horizon_row is {self.cfg.horizon_row:g}; give one")
        self.camera = camera
        seen = getattr(depth_estimator, "horizon_row", None) if depth == "pred" else None
        if seen is not None and abs(seen - camera.cy) > 1e-6:
            raise ValueError(f"Flights: the depth estimator was trained on frames with the "
                             f"horizon at row {seen:g}, but these flights' camera has it at "
                             f"row {camera.cy:g} (FlightsConfig.horizon_row / --horizon-row)")
        self.actions = np.asarray(ACTIONS if actions is None else actions, dtype=np.float64)
        self.n_actions = len(self.actions)
        self.frame_shape = (self.camera.height, self.camera.width)
        self.n_sub = n_substeps(self.actions, ACTION_INTERVAL)
        self.rng = np.random.default_rng(seed)
        self.reward_fn, self.depth_fn = reward_fn, depth_fn
        self.depth_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        if self.cfg.test_worlds and self.cfg.validation_worlds:
            raise ValueError("Flights: config.test_worlds and config.validation_worlds are "
                             "both set; the two seed ranges are disjoint, pick one")
        base = (TEST_SEEDS if self.cfg.test_worlds else
                VALIDATION_SEEDS if self.cfg.validation_worlds else TRAIN_SEEDS)
        self.world_seeds = base + self.rng.choice(1_000_000, size=self.cfg.n_worlds, replace=False)
        # A mixed pool (scene_mix < 1): the first round(scene_mix * n_worlds) worlds are
        # built with the overrides, the rest as the scenario is (the seeds are random, so
        # which worlds get which is too).
        self.n_changed = round(self.cfg.scene_mix * self.cfg.n_worlds) if self.cfg.scene else 0
        changed = self.cfg.scene or {}
        self.worlds = [make_scene(scenario, int(s), **(changed if i < self.n_changed else {}))
                       for i, s in enumerate(self.world_seeds)]
        self.world_of = np.zeros(self.n, dtype=np.int64)
        self.poses = np.zeros((self.n, 3))
        self.t = np.zeros(self.n, dtype=np.int64)
        self.batch = None
        self.last_depth = None
        self.last_rgb = None
        self.last_poses = None          # the poses last_rgb was filmed from

    # -- observing ------------------------------------------------------------------
    def observe(self, idx=None):
        """Depth (metres) and frames ([0, 1]) for flights ``idx`` (all by default)."""
        idx = np.arange(self.n) if idx is None else np.asarray(idx)
        poses = self.poses[idx]
        sub = self._sub_batch(idx)
        rgb = None
        if self.depth_mode == "gt":
            depth = depth_only(sub, poses, self.camera)
        else:
            rgb, _ = render_batch(sub, poses, self.camera)
            if getattr(self.estimator, "needs_previous", False):
                # A two-frame DispNet reads the frame before; a cost volume also the
                # motion since (the odometry: the arc flown at the commanded speed and
                # yaw rate, which in our world is exactly the change of pose).
                prev, prev_poses = self._previous_view(idx, sub)
                motion = (relative_transform(poses, prev_poses)
                          if getattr(self.estimator, "cost_planes", 0) else None)
                depth = self.estimator.predict(rgb, prev=prev, motion=motion)
            else:
                depth = self.estimator.predict(rgb)
            depth = np.asarray(depth, dtype=np.float32) * self.cfg.depth_scale
        if self.cfg.depth_noise > 0:
            depth = (depth * np.exp(self.depth_error(len(idx)))).astype(np.float32)
        if self.depth_fn is not None:
            depth = _checked_depth(self.depth_fn(depth, self.depth_rng), depth)
        return depth, self.encode(depth), rgb

    def _previous_view(self, idx, sub: SceneBatch) -> tuple[np.ndarray, np.ndarray]:
        """The frames filmed one step before the current views of flights ``idx``, and
        the poses they were filmed from, for a two-frame or cost-volume DispNet
        (train-depth --prev-frame, --cost-volume): the last frame each flight saw; at an
        episode's start, the view from 0.8 m further back on its heading (the drone was
        already flying straight at 2 m/s when the episode began)."""
        idx = np.asarray(idx)
        fresh = (self.t[idx] == 0) if self.last_rgb is not None else np.ones(len(idx), bool)
        prev = np.empty((len(idx),) + self.frame_shape + (3,), np.uint8)
        prev_poses = np.empty((len(idx), 3))
        if (~fresh).any():
            prev[~fresh] = self.last_rgb[idx[~fresh]]
            prev_poses[~fresh] = self.last_poses[idx[~fresh]]
        if fresh.any():
            back = self.poses[idx[fresh]].copy()
            step = float(self.actions[0, 0]) * ACTION_INTERVAL
            back[:, 0] -= step * np.cos(back[:, 2])
            back[:, 1] -= step * np.sin(back[:, 2])
            part = sub if fresh.all() else sub.subset(np.flatnonzero(fresh))
            prev[fresh], _ = render_batch(part, back, self.camera)
            prev_poses[fresh] = back
        return prev, prev_poses

    def depth_error(self, m: int) -> np.ndarray:
        """A smooth random error in log depth for ``m`` frames, (m, H, W) (ours; a
        training-time augmentation, ``FlightsConfig.depth_noise`` = s).

        A DispNet's errors are not pixel noise: whole stretches of a frame are too near
        or too far together (docs/experiments.md, "Which depth errors cost flights"). So the
        error of pixel (row v, column u) is a sum of three smooth parts,

            e(v, u) = a + b(u) + c(v),   a ~ N(0, (s/2)^2),

        b drawn N(0, s^2) at 6 knots across the columns and c at 4 knots down the rows,
        each linearly interpolated in between; observed depth = depth * exp(e). Drawn
        afresh for every frame from the flights' generator (so a seed fixes it, and a
        resumed run draws the same)."""
        s = self.cfg.depth_noise
        H, W = self.frame_shape
        a = self.rng.normal(0.0, s / 2, (m, 1, 1))
        b = _interpolate_knots(self.rng.normal(0.0, s, (m, 6)), W)[:, None, :]
        c = _interpolate_knots(self.rng.normal(0.0, s, (m, 4)), H)[:, :, None]
        return a + b + c

    def encode(self, depth: np.ndarray) -> np.ndarray:
        """Depth (metres) -> frames, in this configuration's encoding."""
        return encode_depth(depth, self.cfg.encoding, self.cfg.max_depth)

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
                self.last_poses = np.zeros((self.n, 3))
            self.last_rgb[idx] = rgb
            self.last_poses[idx] = self.poses[idx]

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
            a = self.actions[actions[idx]]
            path = substep_poses(self.poses[idx], a[:, 0], a[:, 1], ACTION_INTERVAL, self.n_sub)
            clear = nearest_distance_batch(self._sub_batch(idx), path[:, :, :2])  # (m, n_sub)
            collided = clear.min(axis=1) < SAFE_DISTANCE
            self.poses[idx] = path[:, -1]
            self.t[idx] += 1
            d_near[idx] = clear[:, -1]
            if self.reward_fn is None:
                rewards[idx] = paper_reward(clear[:, -1], collided)
            else:
                rewards[idx] = _call_reward(self.reward_fn, clear[:, -1], collided, a[:, 1])
            term[idx] = collided
            trunc[idx] = ~collided & (self.t[idx] >= self.cfg.max_steps)
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

    def in_changed_world(self) -> np.ndarray:
        """(n,) bool: which flights are in a world built with ``config.scene`` (all of
        them when scene_mix is 1, none when there is no ``scene``); the rest fly the
        scenario as it is. ``rl.distill`` reads it to give each kind its own teacher."""
        return self.world_of < self.n_changed

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


def _call_reward(reward_fn, d_nearest, collided, yaw_rate):
    """reward_fn(d, collided, yaw_rate), or reward_fn(d, collided) if it takes two."""
    import inspect
    try:
        params = inspect.signature(reward_fn).parameters.values()
        three = any(p.kind == p.VAR_POSITIONAL for p in params) or len(
            [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]) >= 3
    except (TypeError, ValueError):
        three = False
    r = reward_fn(d_nearest, collided, yaw_rate) if three else reward_fn(d_nearest, collided)
    return np.broadcast_to(np.asarray(r, dtype=np.float64), np.shape(d_nearest))


def _checked_depth(out, depth: np.ndarray) -> np.ndarray:
    """What a depth_fn returned, as float32, if it is positive finite depths of the
    input's shape (ValueError otherwise)."""
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
        raise ValueError(f"Flights: depth_fn(depth, rng) must return positive finite float "
                         f"depths (metres) of the input's shape {depth.shape}; got {problem} "
                         f"(python -m minid3rqn check depth-errors finds why)")
    return arr.astype(np.float32)


__all__ = ["Flights", "FlightsConfig", "StepResult", "depth_only"]
