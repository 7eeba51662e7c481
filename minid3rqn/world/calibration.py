"""Calibration of the scenarios with the baseline pilots: success rates over many flights.

A flight succeeds when it completes 50 steps (the paper's criterion)
without collision. Flight k of a scenario starts in world and pose drawn from the seed
sequence [seed, k] (as ``VecDroneEnv``), so all policies fly the same worlds from the
same starts, and a run split into chunks equals one big run.

Command used for docs/world.md:

    python -m minid3rqn calibrate --n-flights 2000 --seed 0
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from .env import VecDroneEnv
from .policies import Oracle, random_policy, straight_policy
from .scenarios import SCENARIOS

POLICIES = ("oracle", "straight", "random")


def make_policy(name: str, seed: int, chunk_index: int):
    """A fresh policy by name (the random policy gets its own seeded generator)."""
    if name == "oracle":
        return Oracle()
    if name == "straight":
        return straight_policy
    return random_policy(np.random.default_rng([seed, 2 ** 20, chunk_index]))


def fly(scenario: str, policy, n_flights: int, seed: int = 0, first_index: int = 0) -> dict:
    """Fly ``n_flights`` flights to their end (50 steps at most): dict of per-flight
    arrays "success" and "steps"."""
    env = VecDroneEnv(n_flights, scenario, seed=seed, observe=False, first_index=first_index)
    env.reset()
    info = None
    while env.active.any():
        _, _, _, _, info = env.step(policy(env))
    return {"success": ~info["collided"], "steps": info["step"].copy()}


def calibrate(scenarios=SCENARIOS, n_flights: int = 2000, seed: int = 0, policies=POLICIES,
              chunk: int = 250, verbose: bool = False) -> dict:
    """Success rates of each policy in each scenario over ``n_flights`` flights.

    Returns {scenario: {policy: {"success": rate, "successes": count, "flights": n,
    "mean_steps": mean steps flown, "seconds": wall time}}}.
    """
    scenarios = (scenarios,) if isinstance(scenarios, str) else tuple(scenarios)
    for s in scenarios:
        if s not in SCENARIOS:
            raise ValueError(f"calibrate: scenarios must be among {SCENARIOS}; got {s!r}")
    for p in policies:
        if p not in POLICIES:
            raise ValueError(f"calibrate: policies must be among {POLICIES}; got {p!r}")
    if (isinstance(n_flights, bool) or not isinstance(n_flights, (int, np.integer))
            or n_flights < 1):
        raise ValueError(f"calibrate: n_flights must be an int >= 1; got {n_flights!r}")
    results = {}
    for scenario in scenarios:
        results[scenario] = {}
        for name in policies:
            start = time.time()
            success, steps = [], []
            for c, first in enumerate(range(0, n_flights, chunk)):
                out = fly(scenario, make_policy(name, seed, c), min(chunk, n_flights - first),
                          seed, first)
                success.append(out["success"])
                steps.append(out["steps"])
            success, steps = np.concatenate(success), np.concatenate(steps)
            results[scenario][name] = {
                "success": float(success.mean()), "successes": int(success.sum()),
                "flights": int(n_flights), "mean_steps": float(steps.mean()),
                "seconds": round(time.time() - start, 1)}
            if verbose:
                print(f"{scenario:14s} {name:9s} success {success.mean():.4f} "
                      f"({success.sum()}/{n_flights}), mean steps {steps.mean():.1f}, "
                      f"{time.time() - start:.0f} s", flush=True)
    return results


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command-line options (also used by ``python -m minid3rqn calibrate``)."""
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS,
                        help="the scenarios to fly (default: all)")
    parser.add_argument("--n-flights", type=int, default=2000, help="flights per cell")
    parser.add_argument("--seed", type=int, default=0,
                        help="flight k flies the world and pose of the seed sequence [seed, k]")


def run(args) -> int:
    """Run the calibration for parsed ``args``; print a line per cell."""
    from ..config import UsageError
    if args.n_flights < 1:
        raise UsageError(f"--n-flights: expected a number >= 1; got {args.n_flights}")
    if args.seed < 0:
        raise UsageError(f"--seed: expected a number >= 0; got {args.seed}")
    calibrate(args.scenarios, args.n_flights, args.seed, verbose=True)
    return 0
