"""One step of m drones at once: fly the arc, check for collision, pay the reward.

Every flight in the package is stepped here, through ``env.DroneEnv``; what a flight
observes afterwards is the env's:

    1. fly: the chosen action (v, omega) is held for dt seconds along the exact arc
       (``kinematics.integrate_arc``), sampled at S equally spaced points no more than
       0.1 m of arc apart (``kinematics.n_substeps``; point S is the arc's end);
    2. check: d_k = the clearance at point k (``distance.nearest_distance_batch``),
           collided = min_k d_k < safe_distance            (0.5 m, paper);
       no wall is flown through unnoticed: every point of the arc is within 0.05 m of
       a checked point;
    3. move: the drone ends at the arc's end, and d_nearest = d_S is read there (a
       collision ends the episode, so that end pose is only ever drawn, never flown on);
    4. pay: reward = reward_fn(d_nearest, collided[, yaw_rate])   (paper, Eq. 4:
       d_nearest, or -1 on collision: ``kinematics.paper_reward``).

A reward function takes (d_nearest, collided) like the paper's, or also the yaw rate
of the action flown (exercise 1: to price turning); ``call_reward`` tells the two
apart. It is called with arrays, one entry per flight.
"""
from __future__ import annotations

import inspect
from typing import NamedTuple

import numpy as np

from .distance import nearest_distance_batch
from .kinematics import ACTION_INTERVAL, SAFE_DISTANCE, n_substeps, paper_reward, substep_poses
from .scene import SceneBatch


def accepts_yaw_rate(reward_fn) -> bool:
    """Whether ``reward_fn`` takes a third positional argument (the yaw rate)."""
    try:
        params = list(inspect.signature(reward_fn).parameters.values())
    except (TypeError, ValueError):
        return False
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return True
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(positional) >= 3


def call_reward(reward_fn, d_nearest, collided, yaw_rate):
    """reward_fn(d, collided, yaw_rate) if it takes the yaw rate, else reward_fn(d, collided)."""
    if accepts_yaw_rate(reward_fn):
        return reward_fn(d_nearest, collided, yaw_rate)
    return reward_fn(d_nearest, collided)


def check_reward_fn(reward_fn, name: str):
    """``reward_fn``, or ``paper_reward`` for None; TypeError if it is not callable."""
    if reward_fn is None:
        return paper_reward
    if not callable(reward_fn):
        raise TypeError(f"{name}: reward_fn must be callable (d_nearest, collided[, yaw_rate]) "
                        f"-> reward; got {type(reward_fn).__name__}")
    return reward_fn


def action_arcs(poses, actions, chosen, dt: float = ACTION_INTERVAL) -> np.ndarray:
    """The checked points of each flight's arc: poses (m, 3), actions (n_actions, 2) of
    (v, omega), chosen (m,) indices -> (m, S, 3), S = ``n_substeps(actions, dt)``; the
    last point is the pose at the arc's end."""
    a = actions[chosen]
    return substep_poses(poses, a[:, 0], a[:, 1], dt, n_substeps(actions, dt))


class Moved(NamedTuple):
    """What one step did to m flights."""
    poses: np.ndarray        # (m, 3) float64 at the arc's end
    d_nearest: np.ndarray    # (m,) float64 clearance there (metres)
    collided: np.ndarray     # (m,) bool: clearance < safe_distance somewhere on the arc
    rewards: np.ndarray      # (m,) float64 reward_fn's


def step_drones(poses, actions, chosen, scenes: SceneBatch, dt: float = ACTION_INTERVAL,
                safe_distance: float = SAFE_DISTANCE, reward_fn=paper_reward) -> Moved:
    """One step of m flights (the module docstring).

    poses (m, 3) as (x, y, yaw); actions the (n_actions, 2) table; chosen (m,) ints, the
    action of each flight; scenes: a SceneBatch of m worlds, flight i in world i.
    """
    arcs = action_arcs(poses, actions, chosen, dt)                        # (m, S, 3)
    clear = nearest_distance_batch(scenes, arcs[:, :, :2])                # (m, S)
    collided = clear.min(axis=1) < safe_distance
    d = clear[:, -1]
    r = call_reward(reward_fn, d.copy(), collided.copy(), actions[chosen, 1])
    try:
        rewards = np.array(np.broadcast_to(np.asarray(r, np.float64), d.shape))
    except ValueError:
        raise ValueError(f"step_drones: reward_fn must return a number or an array of shape "
                         f"{d.shape} (one reward per flight); got shape {np.shape(r)}") from None
    return Moved(arcs[:, -1], d, collided, rewards)
