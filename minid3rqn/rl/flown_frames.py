"""Frames flown by a trained Q-net, as training data for the depth network (ours).

The paper trains its DispNet on frames of manually flown flights, and so does
``depth.data.collect`` (a scripted pilot). But the DispNet is then read by a Q-net,
which flies its own way: it holds its course longer, turns later, and passes
obstacles at the distances it has learnt to tolerate. The depth errors that cost
flights are those at 2-4 m, where the Q-net decides (docs/experiments.md, "Which depth
errors cost flights"). ``collect_flown`` films what the Q-net itself sees:

    for every chunk of ``chunk`` flights (fresh training worlds, its own seed):
        fly the policy (on the DispNet's depth, as deployed) until it collides or
        ``max_steps`` actions are done, recording its start pose and the pose after
        every action, except the action that brought it within the safe distance
        (that step can end with the camera at, or in, an obstacle; the scripted pilot
        stops before such a step too);
    render each flight's poses (RGB, and GT depth for evaluation only)

and returns the arrays of a sequence file, exactly as ``collect`` does: consecutive
frames of one flight are one action (0.4 s, 0.8 m at 2 m/s) apart, the step the
depth losses expect. The view synthesis needs no labels, so this is still the
paper's self-supervised training: the Q-net only chooses where the camera goes.

``epsilon`` > 0 mixes in random actions (the pilot then also visits states just off
its own path). A random draw is seeded by the chunk, so a seed fixes the frames.
"""
from __future__ import annotations

import numpy as np

from ..world import Camera
from .evaluate import _chunk_seeds, run_flights
from .flights import Flights, FlightsConfig


def flown_poses(policy, flights: Flights, max_steps: int) -> list[np.ndarray]:
    """Fly ``flights`` once with ``policy``; the camera poses of every flight, (F_k, 3).

    A flight's poses are its start and the pose after each action it took safely: the
    action that brought it within the safe distance ends the flight without a frame."""
    starts = None
    steps = []

    def record(t, obs, actions, res):
        nonlocal starts
        if starts is None:
            starts = obs["poses"].copy()
        safe = obs["active"] & ~res.terminated
        steps.append((safe, obs["flights"].poses.copy()))

    run_flights(policy, flights, max_steps, record=record)
    safe = np.stack([s for s, _ in steps])                     # (T, n)
    after = np.stack([p for _, p in steps])                    # (T, n, 3)
    # a flight's safe steps come first (it stops at its first unsafe one)
    return [np.concatenate([starts[k][None], after[safe[:, k], k]]) for k in range(flights.n)]


def collect_flown(policy, scenario: str = "basic", n_frames: int = 15000, seed: int = 0,
                  depth: str = "pred", depth_estimator=None, camera: Camera | None = None,
                  max_steps: int = 49, chunk: int = 64, progress: bool = True) -> dict:
    """``n_frames`` frames of ``policy``'s own flights in training worlds of ``scenario``.

    Returns the arrays of a sequence file (``depth.data.save_sequence``). Flights shorter
    than 3 frames (no triplet) are dropped, and the last flight is cut to fit, so the
    total can be up to 2 frames short of ``n_frames`` (as with ``collect``).
    ``max_steps`` actions give at most ``max_steps + 1`` frames per flight.
    """
    from ..depth.data import FRAME_DT, _render
    from ..world.kinematics import ACTION_INTERVAL, ACTIONS
    if n_frames < 3:
        raise ValueError(f"collect_flown: n_frames must be >= 3 (one triplet); got {n_frames}")
    if max_steps < 2:
        raise ValueError(f"collect_flown: max_steps must be >= 2 (3 frames); got {max_steps}")
    if chunk < 1:
        raise ValueError(f"collect_flown: chunk must be >= 1; got {chunk}")
    if abs(ACTION_INTERVAL - FRAME_DT) > 1e-12 or not np.allclose(ACTIONS[:, 0], 2.0):
        raise ValueError("collect_flown: the depth data expects one frame per 0.4 s at "
                         "2 m/s; the world's action table no longer flies that")
    camera = camera or Camera()
    cfg = FlightsConfig(n_worlds=chunk, max_steps=max_steps)
    rgb, gt, pose, flight = [], [], [], []
    total = 0
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_frames, desc=f"collect flown {scenario}", unit="frame")
    # chunks of a seed sequence, as evaluate_policy's: enough for flights of 3 frames
    for n, child in _chunk_seeds(seed, chunk * (n_frames // 3 + 1), chunk):
        if n_frames - total < 3:
            break
        if hasattr(policy, "reseed"):
            policy.reseed((child, 0xF11E))
        flights = Flights(scenario, n, seed=child, config=cfg, depth=depth,
                          depth_estimator=depth_estimator, autoreset=False, camera=camera)
        for k, poses in enumerate(flown_poses(policy, flights, max_steps)):
            poses = poses[:n_frames - total]
            if len(poses) < 3:
                continue
            im, dp = _render(flights.scene_of(k), poses, camera)
            rgb.append(im), gt.append(dp), pose.append(poses)
            flight.append(np.full(len(poses), len(flight), dtype=np.int32))
            total += len(poses)
            if bar is not None:
                bar.update(len(poses))
            if n_frames - total < 3:
                break
    if bar is not None:
        bar.close()
    return {"rgb": np.concatenate(rgb), "depth": np.concatenate(gt),
            "pose": np.concatenate(pose), "flight": np.concatenate(flight),
            "K": camera.K, "camera": (camera.height, camera.width, camera.hfov_deg, camera.cy),
            "dt": FRAME_DT, "crab_deg": 0.0}


__all__ = ["collect_flown", "flown_poses"]
