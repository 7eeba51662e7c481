"""Exercise 2: the action table. This file is the one place to change.

One row per action: (forward speed in m/s, yaw rate in rad/s; positive turns left).
The paper's Table 3 has five actions, all at 2 m/s: straight, and turns at +-0.25 and
+-0.5 rad/s (turning radius v / |yaw rate| = 4 m at the sharpest).

Your task: add a sharper turn, e.g. [2.0, 0.75] and [2.0, -0.75] (radius 2.7 m), or a
second forward speed, e.g. [1.0, 0.0] (slow down to think). The Q-network's head gets
one output per row automatically. Then retrain and compare:

    python -m minid3rqn check actions
    python -m minid3rqn exercise actions             (your table)
    python -m minid3rqn exercise actions --baseline  (the paper's, to compare)

Rules: at least 2 rows; every forward speed > 0 (a drone that can hover would "survive"
50 steps without flying anywhere); no two identical rows.
"""
ACTIONS = [
    [2.0, 0.0],     # straight
    [2.0, 0.25],    # gentle left
    [2.0, -0.25],   # gentle right
    [2.0, 0.5],     # sharp left
    [2.0, -0.5],    # sharp right
]
