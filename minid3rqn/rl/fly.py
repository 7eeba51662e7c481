"""The main job: fly a trained model in fresh worlds, write a GIF and a success rate.

GIF panels, one frame per step of flight 0:  top view (obstacles, path, heading) |
camera RGB | depth the Q-net sees | Q-values (chosen action highlighted).
"""
from __future__ import annotations

import time

import numpy as np

from .. import viz
from ..world import Camera, render_batch, topdown
from .evaluate import by_world, run_flights, wilson_interval
from .flights import Flights, FlightsConfig
from .policies import EnsemblePolicy, QNetPolicy

ACTION_NAMES = ["0", "+.25", "-.25", "+.5", "-.5"]


def fly(model, depth_estimator, scenario: str = "basic", seed: int = 0, n_flights: int = 200,
        gif="fly.gif", max_steps: int = 50, mirror: bool = False,
        horizon_row: float | None = None) -> dict:
    """Fly ``n_flights`` in fresh worlds (test seeds); GIF of flight 0; success rate.
    ``model``: a Q-net .npz, or several joined by '+' (an ensemble on their mean Q), or
    the loaded ``QNetPolicy`` list;
    ``mirror``: each net also flies the mirrored view (``QNetPolicy.mirrored``);
    ``horizon_row``: the camera's (``Camera.horizon_row``; None: the middle row)."""
    t0 = time.time()
    members = list(model) if isinstance(model, (list, tuple)) else \
        [QNetPolicy.load(part, "D3RQN") for part in str(model).split("+")]
    if mirror:
        members += [m.mirrored() for m in members]
    policy = members[0] if len(members) == 1 else EnsemblePolicy(members)
    depth = "pred" if depth_estimator is not None else "gt"
    flights = Flights(scenario, n_flights, seed=seed, depth=depth,
                      depth_estimator=depth_estimator, autoreset=False,
                      camera=Camera(horizon_row=horizon_row),
                      config=FlightsConfig(max_steps=max_steps, test_worlds=True))
    frames_out, path, crashed = [], [], [False]
    max_depth = flights.cfg.max_depth

    def record(t, obs, actions, res):
        k = 0                                   # the GIF follows flight 0
        if crashed[0] or (t > 0 and not path):
            return
        scene = flights.scene_of(k)
        if not path:
            path.append(obs["poses"][k])
        rgb = obs["rgb"][k] if obs["rgb"] is not None else \
            render_batch(scene, obs["poses"][k:k + 1], flights.camera)[0][0]
        bars = viz.bar_chart(policy.last_q[k], ACTION_NAMES, (160, 120), int(actions[k]),
                             title=f"Q-values, step {t + 1}")
        panels = [rgb, viz.depth_to_rgb(obs["depth"][k], 0.5, max_depth), bars]
        top = np.asarray(topdown(scene, np.array(path), obs["poses"][k], flights.camera, 192))
        frames_out.append(viz.hstack([top] + panels, 192))
        path.append(flights.poses[k].copy())
        if res.terminated[k]:
            crashed[0] = True
            top = np.asarray(topdown(scene, np.array(path), path[-1], flights.camera, 192))
            frames_out.append(viz.label(viz.hstack([top] + panels, 192), "COLLISION",
                                        (200, 4), (255, 40, 40)))

    survived = run_flights(policy, flights, max_steps, record=record)
    success = survived >= max_steps
    k = int(success.sum())
    lo, hi = wilson_interval(k, n_flights)
    # the flights share a pool of worlds: the interval by world (rl/evaluate.py) is the
    # one to read for "how well does it fly this scenario", and it is wider
    w = by_world(success, np.asarray(flights.world_seeds)[flights.world_of])
    one_world = len(w.flights) < 2          # then there is no interval by world
    gif = viz.write_gif(frames_out, gif, fps=4)
    return {"scenario": scenario, "seed": seed, "flights": n_flights, "successes": k,
            "success_rate": k / n_flights, "ci95": [round(lo, 4), round(hi, 4)],
            "worlds": len(w.flights),
            "ci95_by_world": None if one_world else [round(w.ci_low, 4), round(w.ci_high, 4)],
            "design_effect": None if one_world else round(w.design_effect, 3),
            "depth": depth, "gif": str(gif), "seconds": round(time.time() - t0, 1),
            "flight0_steps": int(survived[0])}


__all__ = ["fly"]
