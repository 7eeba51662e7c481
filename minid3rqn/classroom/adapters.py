"""Thin adapters that plug a student's change into the library's training code.

The exercises change one thing at a time: the reward, the action table, the camera, the
TD target, the photometric error, the depth seen in training. The library takes some of
these as arguments (``DroneEnv(actions=..., reward_fn=...)``, ``Flights(camera=...,
actions=...)``, the depth ``Trainer(..., photometric_error=...)``) but its agent's
training and evaluation loops build their flights themselves.
The adapters below swap, for the duration of a ``with`` block only, the one name that
the loop looks up:

    with classroom_flights(actions=table, camera=cam, reward_fn=reward):
        Trainer(cfg, out).run()               # rl.train builds these Flights
        evaluate_policy(policy, ...)          # and so does rl.evaluate
    with classroom_flights(depth_fn=corrupt): # around training only: the test flights
        Trainer(cfg, out).run()               # must see the depth as it is
    with td_target(my_target):                # rl.agent's double-Q target -> yours
        ...

Everything is restored when the block ends, also on an error.
"""
from __future__ import annotations

import contextlib
import importlib

import numpy as np


@contextlib.contextmanager
def patched(module_name: str, attr: str, value):
    """Temporarily set ``module.attr = value`` (the attribute must exist)."""
    module = importlib.import_module(module_name)
    if not hasattr(module, attr):
        raise RuntimeError(f"classroom adapter: {module_name} has no attribute {attr!r} any "
                           f"more; update minid3rqn/classroom/adapters.py")
    old = getattr(module, attr)
    setattr(module, attr, value)
    try:
        yield
    finally:
        setattr(module, attr, old)


@contextlib.contextmanager
def classroom_flights(actions=None, camera=None, reward_fn=None, depth_fn=None):
    """Inside the block, training (rl.train) and evaluation (rl.evaluate) fly
    ``Flights`` with these actions, camera and reward (None: the library's).

    ``depth_fn(depth, rng) -> depth`` (exercise 8) corrupts every depth map the flights
    observe, before it is encoded for the Q-net. It is meant for training only: put
    the training alone inside a block with ``depth_fn``, and evaluate outside it (or in
    a block without it), as ``runner.run_agent_exercise`` does."""

    from ..rl.flights import Flights

    def make(*args, **kwargs):
        if actions is not None:
            kwargs.setdefault("actions", np.asarray(actions, dtype=np.float64))
        if camera is not None:
            kwargs.setdefault("camera", camera)
        return Flights(*args, reward_fn=reward_fn, depth_fn=depth_fn, **kwargs)

    with contextlib.ExitStack() as stack:
        for module in ("minid3rqn.rl.train", "minid3rqn.rl.evaluate"):
            stack.enter_context(patched(module, "Flights", make))
        yield make


@contextlib.contextmanager
def td_target(fn):
    """Inside the block the agent's update uses ``fn(q_online_next, q_target_next,
    rewards, terminals, gamma) -> y`` instead of the double-Q target (None: unchanged)."""
    if fn is None:
        yield
        return

    def target(q_online_next, q_target_next, rewards, terminals, gamma):
        y = fn(np.asarray(q_online_next), np.asarray(q_target_next), np.asarray(rewards),
               np.asarray(terminals), gamma)
        return np.asarray(y, dtype=np.float32)

    with patched("minid3rqn.rl.agent", "double_q_targets", target):
        yield


__all__ = ["classroom_flights", "td_target", "patched"]
