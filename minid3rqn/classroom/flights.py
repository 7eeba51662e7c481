"""Training flights that pay the student's reward (see ``adapters.classroom_flights``)."""
from __future__ import annotations

import numpy as np

from ..rl.flights import Flights
from .adapters import call_reward


class ClassroomFlights(Flights):
    """``Flights`` whose reward is ``reward_fn(d_nearest, collided[, yaw_rate])``.

    The library's flights pay the paper's reward (Eq. 4); this subclass recomputes the
    rewards of the flights that moved, from the same clearance and collision flags,
    with the student's function (which may also see the yaw rate of the action flown).
    """

    def __init__(self, *args, reward_fn=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.reward_fn = reward_fn

    def step(self, actions, active=None):
        res = super().step(actions, active)
        if self.reward_fn is None:
            return res
        act = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        idx = np.flatnonzero(act)
        if len(idx):
            yaw = self.actions[np.asarray(actions, dtype=np.int64)[idx], 1]
            r = call_reward(self.reward_fn, res.d_nearest[idx].astype(np.float64),
                            res.terminated[idx].copy(), yaw)
            res.rewards[idx] = np.broadcast_to(np.asarray(r, dtype=np.float64), idx.shape)
        return res
