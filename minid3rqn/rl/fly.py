"""The main job: fly a trained model in fresh worlds, write a GIF and a success rate.

GIF panels, one frame per step of flight 0:  top view (obstacles, path, heading) |
camera RGB | depth the Q-net sees, over its colour key in metres | Q-values (chosen
action highlighted).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import viz
from ..config import FLIGHT_BYTES, at_least, check_seed, fits_memory, setting, validate
from ..io import WriteError
from ..world import DroneEnv, render_batch, topdown
from .evaluate import by_world, run_flights, wilson_interval
from .mirror import MirroredPolicy
from .models import actions_and_camera, ensemble_members, load_qnet_policy
from .observe import MAX_DEPTH
from .policies import EnsemblePolicy


@dataclass
class FlyConfig:
    """What ``fly`` flies."""
    model: str = setting("paper", "a shipped Q-net by name: paper (trained as the paper "
                                  "trains it) or distil (our distilled student); or a Q-net "
                                  ".npz (A.npz+B.npz+...: an ensemble on their mean "
                                  "Q-values)", source="run")
    scenario: str = setting("basic", "the worlds (the shipped DispNet of each reads them)",
                            source="run",
                            choices=("basic", "channel", "intersections", "corners"))
    depth: str = setting("pred", "what the Q-net reads: the DispNet's depth or GT depth",
                         source="run", choices=("gt", "pred"))
    flights: int = setting(32, "flights for the success rate (the DispNet runs on every "
                               "frame: keep it small)", source="run",
                          check=fits_memory(1, FLIGHT_BYTES, "flights flown together"))
    seed: int | None = setting(None, "world seed (none: random)", source="run",
                               check=at_least(0))
    gif: str = setting("runs/fly.gif", "the GIF of flight 0", source="run")
    mirror: bool = setting(False, "each Q-net also flies the mirrored view (a free "
                                  "two-member ensemble)", cli="main")
    flip_tta: bool = setting(False, "the DispNet's disparity averaged with its disparity on "
                                    "the mirrored frame", cli="main")

    def __post_init__(self):
        validate(self)


def action_names(actions) -> list[str]:
    """Short names of an action table's rows: the yaw rate, and the speed if not 2 m/s."""
    return [f"{w:+.2f}" if abs(v - 2.0) < 1e-9 else f"{v:g}m/s {w:+.2f}"
            for v, w in np.asarray(actions)]


def fly(model, depth_estimator, scenario: str = "basic", seed: int = 0, n_flights: int = 200,
        gif="runs/fly.gif", max_steps: int = 50, mirror: bool = False,
        progress: bool = False) -> dict:
    """Fly ``n_flights`` in fresh worlds (test seeds); GIF of flight 0; success rate.
    ``model``: a Q-net .npz, or several joined by '+' (an ensemble on their mean Q), or
    the loaded policies; they fly with the action table and camera they were trained
    with. ``mirror``: each net also flies the mirrored view (``rl.mirror``).
    ``progress``: a bar of the steps flown, from the first."""
    t0 = time.time()
    seed = check_seed(seed, "fly: seed")
    members = list(model) if isinstance(model, (list, tuple)) else \
        [load_qnet_policy(part) for part in ensemble_members(model)]
    actions, camera = actions_and_camera(*members)
    if mirror:
        members += [MirroredPolicy(m) for m in members]
    policy = members[0] if len(members) == 1 else EnsemblePolicy(members)
    depth = "pred" if depth_estimator is not None else "gt"
    env = DroneEnv(scenario, n_flights, seed=seed, worlds="test",
                   observation="pred" if depth == "pred" else "depth",
                   depth_model=depth_estimator, camera=camera, actions=actions,
                   max_steps=max_steps)
    names = action_names(actions)
    frames_out, path, crashed = [], [], [False]

    def record(t, seen, actions, terminated):
        k = 0                                   # the GIF follows flight 0
        if crashed[0] or (t > 0 and not path):
            return
        scene = env.scenes[k]
        if not path:
            path.append(seen["poses"][k])
        rgb = seen["rgb"][k] if seen["rgb"] is not None else \
            render_batch(scene, seen["poses"][k:k + 1], env.camera)[0][0]
        bars = viz.bar_chart(policy.last_q[k], names, (160, 120), int(actions[k]),
                             title=f"Q-values, step {t + 1}")
        depth = viz.resize(viz.depth_to_rgb(seen["obs"][k], 0.5, MAX_DEPTH), 192 - 24)
        key = viz.depth_key(depth.shape[1], 0.5, MAX_DEPTH, height=24)    # metres
        panels = [rgb, np.concatenate([depth, key]), bars]
        top = np.asarray(topdown(scene, np.array(path), seen["poses"][k], env.camera, 192))
        frames_out.append(viz.hstack([top] + panels, 192))
        path.append(env.poses[k].copy())
        if terminated[k]:
            crashed[0] = True
            top = np.asarray(topdown(scene, np.array(path), path[-1], env.camera, 192))
            frames_out.append(viz.label(viz.hstack([top] + panels, 192), "COLLISION",
                                        (200, 4), (255, 40, 40)))

    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=max_steps, unit="step", desc=f"fly {n_flights} flights",
                   dynamic_ncols=True, leave=False)

    def recorded(*step):
        record(*step)
        if bar is not None:
            bar.update(1)
    try:
        survived = run_flights(policy, env, max_steps, record=recorded)
    finally:
        if bar is not None:
            bar.close()
    success = survived >= max_steps
    k = int(success.sum())
    lo, hi = wilson_interval(k, n_flights)
    # the flights share a pool of worlds: the interval by world (rl/evaluate.py) is the
    # one to read for "how well does it fly this scenario", and it is wider
    w = by_world(success, env.scene_seeds)
    one_world = len(w.flights) < 2          # then there is no interval by world
    out = {"scenario": scenario, "seed": seed, "flights": n_flights, "successes": k,
            "success_rate": k / n_flights, "ci95": [round(lo, 4), round(hi, 4)],
            "worlds": len(w.flights),
            "ci95_by_world": None if one_world else [round(w.ci_low, 4), round(w.ci_high, 4)],
            "design_effect": None if one_world else round(w.design_effect, 3),
            "depth": depth, "gif": str(gif), "seconds": round(time.time() - t0, 1),
            "flight0_steps": int(survived[0])}
    try:
        viz.write_gif(frames_out, gif, fps=4)
    except WriteError as e:              # the flights are measured: say so with the error
        e.measured = {**out, "gif": None}
        raise
    return out
