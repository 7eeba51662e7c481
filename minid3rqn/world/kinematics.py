"""Drone kinematics at fixed altitude, the action table and the paper's reward.

An action is a pair (v, omega): forward speed v (m/s) and yaw rate omega (rad/s), held
for one action interval dt. Positive omega turns left (counter-clockwise seen from
above). Over a time tau the pose (x, y, yaw) follows an exact circular arc:

    yaw(tau) = yaw + omega tau
    (x, y)(tau) = (x, y) + v tau sinc(omega tau / 2) (cos(yaw + omega tau / 2),
                                                      sin(yaw + omega tau / 2))

where sinc(a) = sin(a) / a (and 1 at a = 0): the chord of the arc, of length
v tau sinc(omega tau / 2), points along the mean heading. The turning radius is
v / |omega| (4 m at 2 m/s and 0.5 rad/s).
"""
from __future__ import annotations

import math

import numpy as np

# The paper's Table 3: forward 2 m/s always; yaw rate 0, +0.25, -0.25, +0.5, -0.5 rad/s.
# One row per action: (forward speed m/s, yaw rate rad/s). Add a row for a new action.
ACTIONS = np.array([[2.0, 0.0],
                    [2.0, 0.25],
                    [2.0, -0.25],
                    [2.0, 0.5],
                    [2.0, -0.5]])
ACTION_INTERVAL = 0.4     # seconds per action (paper, Table 4)
SAFE_DISTANCE = 0.5       # metres: closer than this to an obstacle is a collision (paper)
MAX_SUBSTEP = 0.1         # metres of arc between two collision checks


def check_action_table(actions, name: str = "actions") -> np.ndarray:
    """Validate an action table: (n_actions, 2) finite floats, speeds >= 0, n >= 1."""
    arr = np.array(actions, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 1:
        raise ValueError(f"{name} must have shape (n_actions, 2) holding (forward speed, yaw "
                         f"rate) rows; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite; got {arr.tolist()}")
    if np.any(arr[:, 0] < 0):
        raise ValueError(f"{name}: forward speeds (column 0) must be >= 0; got {arr[:, 0]}")
    arr.setflags(write=False)
    return arr


def integrate_arc(poses, speed, yaw_rate, tau) -> np.ndarray:
    """Exact pose after flying an arc for time ``tau``: all arguments broadcast.

    poses (..., 3) as (x, y, yaw); speed, yaw_rate, tau broadcastable to poses[..., 0].
    Returns (..., 3) float64; yaw is not wrapped (it stays continuous).
    """
    poses = np.asarray(poses, dtype=np.float64)
    speed, yaw_rate, tau = (np.asarray(a, dtype=np.float64) for a in (speed, yaw_rate, tau))
    turn = yaw_rate * tau
    chord = speed * tau * np.sinc(turn / (2.0 * np.pi))      # np.sinc(x) = sin(pi x)/(pi x)
    mid = poses[..., 2] + 0.5 * turn
    return np.stack(np.broadcast_arrays(poses[..., 0] + chord * np.cos(mid),
                                        poses[..., 1] + chord * np.sin(mid),
                                        poses[..., 2] + turn), axis=-1)


def n_substeps(actions, dt: float = ACTION_INTERVAL, max_step: float = MAX_SUBSTEP) -> int:
    """Sub-steps per action so that no action flies more than ``max_step`` metres between
    two collision checks: ceil(max speed * dt / max_step), at least 1."""
    actions = np.asarray(actions, dtype=np.float64)
    return max(1, int(math.ceil(float(actions[:, 0].max()) * dt / max_step - 1e-9)))


def substep_poses(poses, speed, yaw_rate, dt: float, n_sub: int) -> np.ndarray:
    """Poses at the ends of ``n_sub`` equal sub-steps of one action.

    poses (N, 3), speed (N,), yaw_rate (N,) -> (N, n_sub, 3): entry k is the pose after
    (k + 1) dt / n_sub, so the last entry is the pose at the end of the action.
    """
    taus = dt * np.arange(1, n_sub + 1) / n_sub
    poses = np.asarray(poses, dtype=np.float64)
    return integrate_arc(poses[:, None, :], np.asarray(speed)[:, None],
                         np.asarray(yaw_rate)[:, None], taus[None, :])


def plan_paths(actions, dt: float, segments=(1, 2, 4, 8), spacing: float = 0.4):
    """Candidate plans for look-ahead planners, flown from pose (0, 0, 0).

    A plan holds action a_1 for ``segments[0]`` steps, then a_2 for ``segments[1]`` steps,
    and so on. a_1 ranges over the whole table; the later a_k over the planning actions:
    the hardest left turn, the hardest right turn and the straightest action among the
    fastest ones (enough to steer round obstacles, and 3 instead of n choices per segment).

    Returns (per_step (K, T) the action index of every step, points (K, M, 3) poses
    sampled along each plan by ``fly_plans``).
    """
    actions = np.asarray(actions, np.float64)
    fast = np.flatnonzero(actions[:, 0] == actions[:, 0].max())
    straightest = fast[np.argmin(np.abs(actions[fast, 1]))]
    later = np.unique(np.append(loiter_actions(actions), straightest))
    grids = np.meshgrid(np.arange(len(actions)), *[later] * (len(segments) - 1), indexing="ij")
    combos = np.stack(grids, -1).reshape(-1, len(segments))
    per_step = np.repeat(combos, segments, axis=1)                        # (K, T) action ids
    return per_step, fly_plans(np.zeros((len(per_step), 3)), per_step, actions, dt, spacing)


def fly_plans(poses, per_step, actions, dt: float, spacing: float = 0.4) -> np.ndarray:
    """Poses along action sequences: poses (K, 3), per_step (K, T) action ids ->
    (K, T * n, 3), sampled n = ceil(v_max dt / spacing) times per step."""
    actions = np.asarray(actions, np.float64)
    n_sub = n_substeps(actions, dt, spacing)
    taus = dt * np.arange(1, n_sub + 1) / n_sub
    pose = np.asarray(poses, np.float64)
    points = []
    for step in range(per_step.shape[1]):                  # a few steps, all plans at once
        a = per_step[:, step]
        points.append(integrate_arc(pose[:, None, :], actions[a, 0, None], actions[a, 1, None],
                                    taus[None, :]))
        pose = points[-1][:, -1]
    return np.concatenate(points, axis=1)


def loiter_actions(actions) -> np.ndarray:
    """Indices of the hardest left and hardest right turn among the fastest actions."""
    actions = np.asarray(actions, np.float64)
    fast = np.flatnonzero(actions[:, 0] == actions[:, 0].max())
    return fast[[np.argmax(actions[fast, 1]), np.argmin(actions[fast, 1])]]


def loiter_circles(poses, actions, spacing: float = 0.4) -> np.ndarray:
    """Points of the two circles a drone flies by holding the hardest left or right turn.

    poses (..., 3) -> (..., 2, J, 2): for direction d = +1 (left), -1 (right) with
    turning radius R = v / |omega|, centre c = (x, y) + d R (-sin yaw, cos yaw) and
        point(phi) = c + d R (sin(yaw + d phi), -cos(yaw + d phi)),
    phi = j spacing / R for j = 1 .. J (one full turn; J from the larger radius).
    A direction that does not turn (omega = 0) gives the straight line instead.
    """
    actions = np.asarray(actions, np.float64)
    idx = loiter_actions(actions)
    v, omega = actions[idx, 0], actions[idx, 1]
    radius = np.where(omega != 0, v / np.maximum(np.abs(omega), 1e-12), np.inf)
    length = 2 * np.pi * float(np.max(np.where(np.isfinite(radius), radius, 0.0)))
    n = max(1, int(math.ceil(length / spacing)))
    taus = np.arange(1, n + 1) * (length / n) / np.maximum(v, 1e-12)[:, None]   # (2, J)
    poses = np.asarray(poses, np.float64)[..., None, None, :]                   # (..., 1, 1, 3)
    return integrate_arc(poses, v[:, None], omega[:, None], taus)[..., :2]


def paper_reward(d_nearest, collided):
    """The paper's reward (Eq. 4): R = d_nearest without collision, -1 on collision.

    Works on scalars (returns float) and on arrays (elementwise, returns float64 array).
    """
    d = np.asarray(d_nearest, dtype=np.float64)
    c = np.asarray(collided, dtype=bool)
    r = np.where(c, -1.0, d)
    return float(r) if r.ndim == 0 else r
