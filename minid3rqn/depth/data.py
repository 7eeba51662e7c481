"""Image sequences for self-supervised depth: scripted flights, storage, triplets.

``collect`` flies a scripted pilot through scenes of a scenario, as the paper's
"manually controlled" flights: forward at 2 m/s, one frame every 0.4 s, turning to
keep clear of obstacles and varying its turns at random. Each frame is stored with
its ground-truth pose and depth, which only the evaluation reads.

A sequence file (``.npz``, written atomically) holds

    rgb     (F, H, W, 3) uint8     the frames
    depth   (F, H, W) float32      GT pinhole depth (metres)          evaluation only
    pose    (F, 3) float64         GT (x, y, yaw) of the drone         evaluation only
    flight  (F,) int32             which flight a frame belongs to (frames of a flight
                                   are consecutive, in time order)
    K       (3, 3) float64         the camera intrinsics

plus JSON metadata (the ``CollectConfig``, camera, command).

Training samples are triplets (previous, target, next) of consecutive frames of ONE
flight; ``triplet_indices`` lists the targets, ``Sequence.batch`` refuses frames that
straddle two flights.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import (as_dict, at_least, between, check_seed, command_line, fits_memory,
                      setting, shell_command, up_to, validate)
from ..io import load_npz, save_npz
from ..world.camera import Camera
from ..world.distance import nearest_distance, sample_start_pose
from ..world.kinematics import integrate_arc
from ..world.renderer import render_batch
from ..world.scenarios import SCENARIOS, make_scene
from .geometry import check_intrinsics

SPEED = 2.0          # m/s, the paper's forward speed
FRAME_DT = 0.4       # s between frames (paper, Table 2)
SAFE = 0.5           # m: closer is a collision (paper); the pilot ends the flight there
TEST_SEED_OFFSET = 1000   # held-out frames fly in the worlds of seed + 1000
TEST_FRAMES = 500


# Memory a collected frame takes while its sequence is made and saved (RGB, GT depth, the
# pose; the lists and their concatenation): peak memory of collect --frames 500 and 5000
# (/usr/bin/time), 89 MB and 407 MB.
FRAME_BYTES = 70e3


@dataclass
class CollectConfig:
    """The frames of one ``collect``: scripted flights in fresh worlds of a scenario."""
    scenario: str = setting("basic", "the world the frames are filmed in", source="paper",
                            choices=SCENARIOS)
    frames: int = setting(5000, "frames to collect", source="paper",
                          check=fits_memory(3, FRAME_BYTES, "frames"))
    seed: int = setting(0, "flight f flies in the world of seed x 100003 + f", source="run",
                        check=at_least(0))
    late_turns: float = setting(0.0, "share of the pilot's segments flown straight at "
                                     "obstacles, swerving late (0: the careful pilot)",
                                source="ours", check=between(0.0, 1.0))
    frames_per_flight: int = setting(50, "the longest flight, in frames", source="ours",
                                     check=up_to(3, 10 ** 4, "the paper's flights last "
                                                             "50 steps"))

    def __post_init__(self):
        validate(self)


def held_out(cfg: CollectConfig, frames: int = TEST_FRAMES) -> CollectConfig:
    """The held-out frames that go with training frames ``cfg``: the same scenario,
    other worlds (seed + 1000), the careful pilot, a frame every 0.4 s."""
    return CollectConfig(scenario=cfg.scenario, frames=frames,
                         seed=cfg.seed + TEST_SEED_OFFSET)


# -- the scripted pilot ----------------------------------------------------------------
def _arc_points(pose, yaw_rate, horizon: float, n: int) -> np.ndarray:
    """Positions (n, 2) along an arc flown from ``pose`` at SPEED for ``horizon`` s."""
    taus = np.linspace(horizon / n, horizon, n)
    return integrate_arc(np.asarray(pose)[None], SPEED, yaw_rate, taus)[:, :2]


class ScriptedPilot:
    """Keeps clear of obstacles and varies its turns (the paper's manual flights).

    Every step it scores candidate yaw rates in [-0.5, 0.5] rad/s by the smallest
    clearance along a 2.4 s arc (and whether the arc stays in the flyable region).
    Among the safe ones (clearance >= ``margin``) it takes the one nearest a wandering
    preferred yaw rate, which is redrawn at random every few steps; when none is safe
    it takes the clearest.

    ``late``: the share of those few-step segments flown as a *late turner*: straight
    ahead, looking only ``late_horizon`` s (a random 1.0-1.6 s, 2-3 m) ahead with a
    ``late_margin`` of 0.7 m, so it swerves only when an obstacle is close; the careful
    pilot (``late`` = 0) rarely films an obstacle 1-2 m straight ahead (docs/depth.md
    section 1).
    """

    def __init__(self, scene, rng: np.random.Generator, margin: float = 1.0,
                 horizon: float = 2.4, late: float = 0.0, late_margin: float = 0.7,
                 late_horizon: tuple[float, float] = (1.0, 1.6)):
        if not 0.0 <= late <= 1.0:
            raise ValueError(f"ScriptedPilot: late must be a share in [0, 1]; got {late}")
        self.scene, self.rng, self.margin, self.horizon = scene, rng, margin, horizon
        self.late, self.late_margin, self.late_horizon = late, late_margin, late_horizon
        self.candidates = np.linspace(-0.5, 0.5, 9)
        self.preferred, self.hold = 0.0, 0
        self.segment = (margin, horizon)          # (margin, horizon) of this segment

    def __call__(self, pose) -> float:
        if self.hold <= 0:
            self.preferred = float(self.rng.choice([-0.5, -0.25, 0.0, 0.0, 0.25, 0.5]))
            self.hold = int(self.rng.integers(2, 8))
            self.segment = (self.margin, self.horizon)
            # (late = 0 draws nothing more: the careful pilot's flights stay as they were)
            if self.late > 0 and self.rng.random() < self.late:
                self.preferred = 0.0
                self.segment = (self.late_margin, float(self.rng.uniform(*self.late_horizon)))
        self.hold -= 1
        margin, horizon = self.segment
        pts = np.stack([_arc_points(pose, w, horizon, 12) for w in self.candidates])
        clear = nearest_distance(self.scene, pts).min(axis=1)
        clear = np.where(self.scene.in_region(pts).all(axis=1), clear, -1.0)
        safe = clear >= margin
        if safe.any():
            cost = np.abs(self.candidates - self.preferred) + 10.0 * ~safe
            return float(self.candidates[int(np.argmin(cost))])
        return float(self.candidates[int(np.argmax(clear))])


# -- collection ------------------------------------------------------------------------
def fly(scene, n_frames: int, rng: np.random.Generator, late: float = 0.0) -> np.ndarray:
    """One scripted flight of up to ``n_frames`` camera poses (fewer if it comes too
    close), a frame every 0.4 s (the pilot decides at every frame); ``late``: the pilot's
    share of late-turn segments (``ScriptedPilot``)."""
    pilot = ScriptedPilot(scene, rng, late=late)
    poses = [sample_start_pose(scene, rng)]
    while len(poses) < n_frames:
        w = pilot(poses[-1])
        # Check clearance along the step, every 0.1 m.
        path = _arc_points(poses[-1], w, FRAME_DT, 8)
        if nearest_distance(scene, path).min() < SAFE:
            break
        poses.append(integrate_arc(poses[-1], SPEED, w, FRAME_DT))
    return np.stack(poses)


def collect(scenario: str = "basic", n_frames: int = 5000, frames_per_flight: int = 50,
            seed: int = 0, camera=None, progress: bool = True, late: float = 0.0) -> dict:
    """Fly scripted flights in fresh scenes of ``scenario`` until ``n_frames`` frames.

    Flight f flies in ``make_scene(scenario, seed=seed * 100003 + f)``; flights shorter
    than 3 frames (no triplet) are dropped, so when the last 1-2 frames cannot make a
    flight of their own the sequence ends up to 2 frames short of ``n_frames``. Returns
    the arrays of a sequence file. ``late``: the pilot's share of late-turn segments
    (``ScriptedPilot``).
    """
    if n_frames < 3:
        raise ValueError(f"collect: n_frames must be >= 3 (one triplet); got {n_frames}")
    if frames_per_flight < 3:
        raise ValueError(f"collect: frames_per_flight must be >= 3; got {frames_per_flight}")
    seed = check_seed(seed, "collect: seed")
    camera = camera or Camera()
    rng = np.random.default_rng(seed)
    rgb, depth, pose, flight = [], [], [], []
    total, f = 0, 0
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_frames, desc=f"collect {scenario}", unit="frame")
    while n_frames - total >= 3:        # a last flight of 1-2 frames would hold no triplet
        scene = make_scene(scenario, seed=seed * 100003 + f)
        poses = fly(scene, min(frames_per_flight, n_frames - total), rng, late)
        f += 1
        if len(poses) < 3:
            continue
        im, dp = render_batch(scene, poses, camera)
        rgb.append(im), depth.append(dp), pose.append(poses)
        flight.append(np.full(len(poses), len(flight), dtype=np.int32))
        total += len(poses)
        if bar is not None:
            bar.update(len(poses))
        if f > 20 * (n_frames // 3 + 1):
            raise RuntimeError(f"collect: scenario {scenario!r} gives flights too short to "
                               f"collect {n_frames} frames")
    if bar is not None:
        bar.close()
    return {"rgb": np.concatenate(rgb), "depth": np.concatenate(depth),
            "pose": np.concatenate(pose), "flight": np.concatenate(flight),
            "K": camera.K, "camera": (camera.height, camera.width, camera.hfov_deg, camera.cy)}


def save_sequence(path, data: dict, metadata: dict | None = None) -> Path:
    arrays = {k: data[k] for k in ("rgb", "depth", "pose", "flight", "K")}
    meta = dict(metadata or {})
    meta["camera"] = list(data.get("camera", ()))
    return save_npz(path, arrays, meta)


# -- sequences and triplets ------------------------------------------------------------
@dataclass
class Sequence:
    """Frames of one or more flights, validated. See the module docstring for fields."""

    rgb: np.ndarray
    flight: np.ndarray
    K: np.ndarray
    depth: np.ndarray | None = None
    pose: np.ndarray | None = None
    meta: dict | None = None

    def __post_init__(self):
        self.rgb = np.asarray(self.rgb)
        self.flight = np.asarray(self.flight)
        if self.rgb.ndim != 4 or self.rgb.shape[-1] != 3 or self.rgb.dtype != np.uint8:
            raise ValueError(f"Sequence: rgb must be uint8 (F, H, W, 3); got {self.rgb.dtype} "
                             f"{self.rgb.shape}")
        n = len(self.rgb)
        if n == 0:
            raise ValueError("Sequence: the sequence is empty (0 frames); collect frames first")
        if self.flight.shape != (n,):
            raise ValueError(f"Sequence: flight must be ({n},), one id per frame; got "
                             f"{self.flight.shape}")
        self.K = check_intrinsics(self.K, self.rgb.shape[1], self.rgb.shape[2], "Sequence: K")
        for name in ("depth", "pose"):
            value = getattr(self, name)
            if value is not None and len(value) != n:
                raise ValueError(f"Sequence: {name} has {len(value)} entries for {n} frames")
        # A flight's frames must be consecutive: ids may only change, never come back.
        starts = np.flatnonzero(np.diff(self.flight)) + 1
        ids = self.flight[np.concatenate([[0], starts])]
        if len(np.unique(ids)) != len(ids):
            raise ValueError("Sequence: the frames of a flight must be consecutive; flight "
                             "ids come back after another flight's frames")

    def __len__(self) -> int:
        return len(self.rgb)

    @property
    def shape(self) -> tuple[int, int]:
        return self.rgb.shape[1], self.rgb.shape[2]

    def triplet_indices(self) -> np.ndarray:
        return triplet_indices(self.flight)

    def batch(self, targets) -> tuple[np.ndarray, list[np.ndarray]]:
        """Targets (B,) -> (target (B, 3, H, W), [previous, next]) float32 in [0, 1]: the
        triplets around the targets, each from one flight."""
        targets = np.asarray(targets)
        if targets.min() < 1 or targets.max() >= len(self) - 1:
            raise IndexError(f"Sequence.batch: every target needs the frames before and "
                             f"after it inside the sequence of {len(self)} frames")
        ids = self.flight[targets]
        same = (self.flight[targets - 1] == ids) & (self.flight[targets + 1] == ids)
        if not same.all():
            raise ValueError(f"Sequence.batch: targets {targets[~same].tolist()} have "
                             f"neighbours from other flights; use triplet_indices() to pick "
                             f"targets")
        f = lambda idx: (self.rgb[idx].transpose(0, 3, 1, 2).astype(np.float32) / 255.0)
        return f(targets), [f(targets - 1), f(targets + 1)]

    def select_flights(self, flights) -> "Sequence":
        keep = np.isin(self.flight, np.asarray(flights))
        return Sequence(self.rgb[keep], self.flight[keep], self.K,
                        None if self.depth is None else self.depth[keep],
                        None if self.pose is None else self.pose[keep], self.meta)


def triplet_indices(flight) -> np.ndarray:
    """Indices t whose frames t-1, t, t+1 all belong to the same flight."""
    flight = np.asarray(flight)
    t = np.arange(1, max(len(flight) - 1, 1))
    return t[(flight[t - 1] == flight[t]) & (flight[t + 1] == flight[t])]


def collect_sequence(cfg: CollectConfig, path, progress: bool = True) -> Sequence:
    """Collect the frames of ``cfg``, save them to ``path`` with the ``collect`` command
    that makes them, and return them as read back from the file."""
    data = collect(cfg.scenario, cfg.frames, cfg.frames_per_flight, cfg.seed,
                   progress=progress, late=cfg.late_turns)
    command = shell_command(["collect", *command_line(CollectConfig, cfg), "--out", path])
    save_sequence(path, data, {**as_dict(cfg), "command": command})
    return load_sequence(path)


def load_sequence(path) -> Sequence:
    arrays, meta = load_npz(path)
    for key in ("rgb", "flight", "K"):
        if key not in arrays:
            raise KeyError(f"load_sequence: {str(path)!r} has no array {key!r}; write it with "
                           f"`python -m minid3rqn collect`")
    return Sequence(arrays["rgb"], arrays["flight"], arrays["K"], arrays.get("depth"),
                    arrays.get("pose"), meta)
