"""Success rate over many test flights, batched, with a 95% Wilson interval.

A flight succeeds if it flies ``max_steps`` (50, the paper's test) actions without a
collision. All flights of a chunk are stepped together (one render call, one network
forward for the whole chunk); a flight that has crashed stops being simulated.

Wilson score interval for k successes in n trials (z = 1.96 for 95%)::

    p = k / n,   centre = (p + z^2 / 2n) / (1 + z^2 / n),
    half = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / 4n^2)

Unlike p +- z sqrt(p(1-p)/n) it stays inside [0, 1] and is not zero-width at 0 or 1
(0 successes in 2000 flights still allows a rate up to 0.0019).
"""
from __future__ import annotations

import math
import multiprocessing as mp
import time
import warnings
from contextlib import nullcontext
from dataclasses import asdict, dataclass

import numpy as np

from .flights import Flights, FlightsConfig
from .policies import Policy


def wilson_interval(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% (z = 1.96) Wilson score interval of a binomial proportion k / n."""
    if n <= 0:
        raise ValueError(f"wilson_interval: n must be positive; got {n}")
    if not 0 <= k <= n:
        raise ValueError(f"wilson_interval: k must be in [0, n={n}]; got {k}")
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo = 0.0 if k == 0 else max(0.0, centre - half)     # exact ends (no rounding residue)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return lo, hi


@dataclass
class EvalResult:
    policy: str
    scenario: str
    depth: str
    flights: int
    successes: int
    rate: float
    ci_low: float
    ci_high: float
    mean_steps: float
    seconds: float
    seed: int
    world_set: str = "test"      # "validation": the model-selection range (Flights)

    def line(self) -> str:
        where = "" if self.world_set == "test" else ", validation worlds"
        return (f"{self.policy:<10} {self.scenario:<13} {self.rate:.3f} "
                f"[{self.ci_low:.3f}, {self.ci_high:.3f}]  ({self.successes}/{self.flights}, "
                f"mean steps {self.mean_steps:.1f}, {self.seconds:.0f} s{where})")

    def to_dict(self) -> dict:
        return asdict(self)


def run_flights(policy: Policy, flights: Flights, max_steps: int, record=None) -> np.ndarray:
    """Fly every flight of ``flights`` once (from ``reset``), return steps survived (n,).

    ``record(step, obs, actions, result)`` is called each step if given (for GIFs).
    """
    n = flights.n
    frames = flights.reset()
    policy.reset(n)
    alive = np.ones(n, bool)
    steps = np.zeros(n, dtype=np.int64)
    for t in range(max_steps):
        obs = {"frames": frames, "depth": flights.last_depth, "flights": flights,
               "active": alive}
        if record is not None:      # the recorder sees the view the action was chosen from
            obs = {**obs, "depth": flights.last_depth.copy(), "poses": flights.poses.copy(),
                   "rgb": None if flights.last_rgb is None else flights.last_rgb.copy()}
        actions = policy.act(obs)
        res = flights.step(actions, active=alive)
        if record is not None:
            record(t, obs, actions, res)
        alive &= ~res.terminated
        steps[alive] += 1                # actions completed without a collision
        frames = res.frames
        if not alive.any():
            break
    return steps


def _chunk_seeds(seed: int, n_flights: int, chunk: int) -> list[tuple[int, int]]:
    """(flights, world seed) of every chunk: chunk k's worlds come from the k-th child
    of ``SeedSequence(seed)``, so a chunk's flights do not depend on who flies them."""
    children = np.random.SeedSequence(seed).spawn(-(-n_flights // chunk))
    return [(min(chunk, n_flights - start), int(c.generate_state(1)[0]))
            for start, c in zip(range(0, n_flights, chunk), children)]


def _fly_chunk(policy: Policy, scenario: str, n: int, child: int, cfg: FlightsConfig,
               depth: str, depth_estimator, max_steps: int,
               flights_factory=Flights) -> np.ndarray:
    """Steps survived by the ``n`` flights of one chunk (world seed ``child``)."""
    # A policy with a random generator (Random, an epsilon-greedy Q-net) draws from one
    # seeded by the chunk: a chunk's result is the same in any process, in any order.
    # (A duck-typed policy without ``reseed`` keeps its own generator.)
    if hasattr(policy, "reseed"):
        policy.reseed((child, 0x5EED))
    flights = flights_factory(scenario, n, seed=child, config=cfg, depth=depth,
                              depth_estimator=depth_estimator, autoreset=False)
    return run_flights(policy, flights, max_steps)


_FORKED = None       # what the chunks are flown with (set for the length of one evaluation,
                     # so forked worker processes inherit it instead of unpickling it)


def _fly_chunk_forked(task):
    n, child = task
    return _fly_chunk(*_FORKED[:2], n, child, *_FORKED[2:])


def evaluate_policy(policy: Policy, scenario: str = "basic", n_flights: int = 2000,
                    seed: int = 12345, max_steps: int = 50, chunk: int = 500,
                    depth: str = "gt", depth_estimator=None,
                    flights_config: FlightsConfig | None = None,
                    progress: bool = True, workers: int = 1,
                    flights_factory=None, world_set: str = "test") -> EvalResult:
    """Success rate of ``policy`` over ``n_flights`` fresh flights (greedy, batched).

    The flights are flown ``chunk`` at a time, each chunk from its own seed
    (``_chunk_seeds``). ``workers`` > 1 flies the chunks in that many processes (one
    per core; forked, so the policy and the depth network are shared, not pickled):
    the result is the same as with one. ``flights_factory`` (default ``Flights``) makes
    each chunk's flights from ``Flights``'s arguments: a subclass that changes what the
    policy sees (``examples/07_which_depth_errors_matter.py``) is flown the same way.
    ``world_set``: "test" (the evaluation seed range, every reported rate) or "validation"
    (a third, disjoint range, for choosing between models without touching the test
    worlds).
    """
    if n_flights < 1:
        raise ValueError(f"evaluate_policy: n_flights must be >= 1; got {n_flights}")
    if chunk < 1:
        raise ValueError(f"evaluate_policy: chunk must be >= 1; got {chunk}")
    if workers < 1:
        raise ValueError(f"evaluate_policy: workers must be >= 1; got {workers}")
    if world_set not in ("test", "validation"):
        raise ValueError(f"evaluate_policy: world_set must be 'test' or 'validation'; got "
                         f"{world_set!r}")
    cfg = flights_config or FlightsConfig()
    cfg = FlightsConfig(**{**asdict(cfg), "max_steps": max_steps,
                           "test_worlds": world_set == "test",
                           "validation_worlds": world_set == "validation",
                           "n_worlds": min(cfg.n_worlds, chunk, n_flights)})
    tasks = _chunk_seeds(seed, n_flights, chunk)
    workers = min(workers, len(tasks))
    if workers > 1 and "fork" not in mp.get_all_start_methods():
        warnings.warn("evaluate_policy: this platform cannot fork; flying the chunks in "
                      "one process", RuntimeWarning, stacklevel=2)
        workers = 1
    t0 = time.time()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_flights, unit="flight", desc=f"eval {policy.name} {scenario}",
                   dynamic_ncols=True, leave=False)
    global _FORKED
    _FORKED = (policy, scenario, cfg, depth, depth_estimator, max_steps,
               flights_factory or Flights)
    survived = []
    try:
        with (mp.get_context("fork").Pool(workers) if workers > 1 else nullcontext()) as pool:
            # imap keeps the chunks' order, so the result is the one-process one
            runs = map(_fly_chunk_forked, tasks) if pool is None else \
                pool.imap(_fly_chunk_forked, tasks)
            for (n, _), steps in zip(tasks, runs):
                survived.append(steps)
                if bar is not None:
                    bar.update(n)
    finally:
        _FORKED = None
    if bar is not None:
        bar.close()
    survived = np.concatenate(survived)
    k = int((survived >= max_steps).sum())
    lo, hi = wilson_interval(k, n_flights)
    return EvalResult(policy.name, scenario, depth, n_flights, k, k / n_flights, lo, hi,
                      float(survived.mean()), time.time() - t0, seed, world_set)


__all__ = ["wilson_interval", "EvalResult", "run_flights", "evaluate_policy"]
