"""What a Q-net reads: the env's depth in metres, encoded, then stacked.

Two steps between ``world.DroneEnv``'s observation and the Q-net, the same in training
(``rl.train``), evaluation and ``fly`` (``QNetPolicy``) and distillation:

    1. encode: the paper's depth maps scaled into [0, 1] (1 = far),
           x = min(d, max_depth) / max_depth,      max_depth = 10 m (ours);
    2. stack: the last ``stack`` encoded frames of each flight as the channels,
       (N, stack, H, W); at an episode's start its first frame fills the stack
       (``agent.FrameStacker``; the recurrent variants read stack = 1).

A Gymnasium library gets the same two steps as wrappers (``minid3rqn.gym``,
examples/10_sb3_dqn.py).
"""
from __future__ import annotations

import numpy as np

MAX_DEPTH = 10.0        # ours: depth clip (m) of the Q-net's input


def encode_depth(depth, max_depth: float = MAX_DEPTH) -> np.ndarray:
    """Depth in metres -> the Q-net's frames, x = min(d, max_depth) / max_depth in [0, 1]
    (float32, the shape of ``depth``)."""
    return (np.clip(depth, 0.0, max_depth) / max_depth).astype(np.float32)
