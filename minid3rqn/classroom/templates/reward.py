"""Exercise 1: the reward. This file is the one place to change.

The paper's reward (Eq. 4): after every action the drone earns the distance to the
nearest obstacle, d_nearest (metres), or -1 if it came closer than 0.5 m (a collision,
which ends the flight).

Your task: change it, then retrain and compare. Two ideas (pick one, or both):
  * penalise turning:     r = d_nearest - k * |yaw_rate|       (k around 1 to 4)
  * clip or scale d:      r = min(d_nearest, 3.0)   or   r = d_nearest / 5
Keep -1 on a collision (it must stay the worst outcome).

Rules the checker enforces (python -m minid3rqn check reward):
  * the trainer calls reward() once per step for ALL flights at once, with NumPy arrays
    (d_nearest float array, collided bool array, yaw_rate float array); use np.where,
    np.minimum, np.abs ... and never `if collided:`;
  * a collision must give a reward below every non-collision reward.

Then: python -m minid3rqn exercise reward            (your reward)
      python -m minid3rqn exercise reward --baseline (the paper's, to compare)
"""
import numpy as np


def reward(d_nearest, collided, yaw_rate=0.0):
    """Reward for one step.

    Args:
        d_nearest: distance to the nearest obstacle after the action, metres
            (a float, or an array with one entry per flight).
        collided: True where the drone came closer than 0.5 m (bool or bool array).
        yaw_rate: yaw rate of the action just flown, rad/s (0 = straight ahead;
            +-0.25, +-0.5 in the paper's action table).

    Returns:
        The reward: a float for float inputs, an array of the same shape for arrays.
    """
    d = np.asarray(d_nearest, dtype=np.float64)
    hit = np.asarray(collided, dtype=bool)
    r = np.where(hit, -1.0, d)          # the paper's Eq. 4
    return float(r) if r.ndim == 0 else r
