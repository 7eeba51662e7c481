"""Success rate over many test flights, batched, with a 95% Wilson interval.

A flight succeeds if it flies ``max_steps`` (50, the paper's test) actions without a
collision. All flights of a chunk are stepped together (one render call, one network
forward for the whole chunk); a flight that has crashed stops being simulated.

Wilson score interval for k successes in n trials (z = 1.96 for 95%)::

    p = k / n,   centre = (p + z^2 / 2n) / (1 + z^2 / n),
    half = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / 4n^2)

Unlike p +- z sqrt(p(1-p)/n) it stays inside [0, 1] and is not zero-width at 0 or 1
(0 successes in 2000 flights still allows a rate up to 0.0019).

**Flights share worlds.** The Wilson interval treats the n flights as independent trials.
They are not quite: 2000 test flights fly in 128 worlds (4 chunks of 500 flights, each
with a pool of 32 scenes), about 16 flights per world, and a world with a hard spot
fails several of its flights. So each evaluation also gives an interval *by world*
(``clustered_interval``), the one to read when the question is "how well does this
policy fly this scenario's worlds", not "these 2000 flights". With y_c successes in the
m_c flights of world c (C worlds, n = sum m_c, p = sum y_c / n), the variance of p as the
mean of a sample of worlds (the ratio estimator of cluster sampling) is

    var_w = C / (C - 1) * sum_c (y_c - p m_c)^2 / n^2

and the *design effect* deff = var_w / (p (1 - p) / n) says how many times the
independent-flights variance it is. The interval is Wilson's with the effective number
of flights n / deff in place of n (Korn and Graubard, 1998), deff taken as at least 1: we
never claim more precision than independent flights give. With one flight per world it
is Wilson's interval (up to C / (C - 1)); with every world all-success or all-failure it
is Wilson's over the C worlds.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..config import (FLIGHT_BYTES, ConfigError, at_least, capped_workers, check_seed,
                      fits_memory, setting, shell_command, up_to, validate)
from ..executor import EXECUTORS, get_executor
from ..world import DroneEnv
from .policies import Policy

TEST_WORLDS = 271828            # the evaluation seed of the test worlds (docs/results.md)


def _wilson(p: float, n: float, z: float) -> tuple[float, float]:
    """Wilson's interval for an observed proportion p over n (possibly effective,
    non-integer) trials."""
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo = 0.0 if p == 0 else max(0.0, centre - half)     # exact ends (no rounding residue)
    hi = 1.0 if p == 1 else min(1.0, centre + half)
    return lo, hi


def wilson_interval(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% (z = 1.96) Wilson score interval of a binomial proportion k / n."""
    if n <= 0:
        raise ValueError(f"wilson_interval: n must be positive; got {n}")
    if not 0 <= k <= n:
        raise ValueError(f"wilson_interval: k must be in [0, n={n}]; got {k}")
    return _wilson(k / n, n, z)


def clustered_interval(world_successes, world_flights,
                       z: float = 1.96) -> tuple[float, float, float]:
    """95% interval of the success rate *by world*, and the design effect (module
    docstring): ``world_successes`` and ``world_flights`` are the successes and flights
    of each world, (C,) integers with 0 <= successes <= flights and C >= 2 worlds.
    Returns (low, high, deff)."""
    y = np.asarray(world_successes)
    m = np.asarray(world_flights)
    for name, a in (("world_successes", y), ("world_flights", m)):
        if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"clustered_interval: {name} must be a 1-D array of integers "
                             f"(one per world); got shape {a.shape}, dtype {a.dtype}")
    if y.shape != m.shape:
        raise ValueError(f"clustered_interval: world_successes and world_flights must have "
                         f"one entry per world each; got {y.shape[0]} and {m.shape[0]}")
    if len(m) < 2:
        raise ValueError(f"clustered_interval: needs at least 2 worlds to measure how they "
                         f"differ; got {len(m)}")
    if (m < 1).any() or (y < 0).any() or (y > m).any():
        raise ValueError("clustered_interval: every world needs world_flights >= 1 and "
                         "0 <= world_successes <= world_flights; got flights "
                         f"{m.min()}..{m.max()}, successes {y.min()}..{y.max()}, "
                         f"{int((y > m).sum())} worlds with more successes than flights")
    n = int(m.sum())
    p, var_w = world_variance(y, m)
    if p in (0.0, 1.0):                 # every flight alike: nothing varies between worlds
        return (*_wilson(p, n, z), 1.0)
    deff = var_w / (p * (1 - p) / n)
    return (*_wilson(p, n / max(deff, 1.0), z), deff)


def world_variance(world_successes, world_flights) -> tuple[float, float]:
    """The rate p = sum y_c / n and its variance as a mean over C >= 2 worlds,
    var_w = C / (C - 1) sum_c (y_c - p m_c)^2 / n^2 (module docstring)."""
    y = np.asarray(world_successes, dtype=np.float64)
    m = np.asarray(world_flights, dtype=np.float64)
    n, c = m.sum(), len(m)
    p = float(y.sum() / n)
    return p, c / (c - 1) * float(((y - p * m) ** 2).sum()) / (n * n)


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
    # By world (module docstring): the interval over the worlds flown, the design effect,
    # and each world's seed, successes and flights (what pools evaluations by world:
    # ``pool``; with the scenario, a world's seed names the world).
    worlds: int = 0
    ci_low_worlds: float = float("nan")
    ci_high_worlds: float = float("nan")
    design_effect: float = float("nan")
    world_seeds: list = field(default_factory=list)
    world_successes: list = field(default_factory=list)
    world_flights: list = field(default_factory=list)

    def line(self) -> str:
        by_world = ""
        if self.worlds >= 2:
            by_world = (f"; by world [{self.ci_low_worlds:.3f}, {self.ci_high_worlds:.3f}], "
                        f"{self.worlds} worlds, deff {self.design_effect:.2f}")
        return (f"{self.policy:<10} {self.scenario:<13} {self.rate:.3f} "
                f"[{self.ci_low:.3f}, {self.ci_high:.3f}]  ({self.successes}/{self.flights}, "
                f"mean steps {self.mean_steps:.1f}, {self.seconds:.0f} s{by_world})")

    def to_dict(self) -> dict:
        """The fields as a dict for JSON: a NaN (no interval by world from fewer than two
        worlds) becomes None, so the files written are strict JSON."""
        return {k: None if isinstance(v, float) and math.isnan(v) else v
                for k, v in asdict(self).items()}


@dataclass
class ByWorld:
    """Each world's successes and flights, and the interval by world (``by_world``)."""
    seeds: np.ndarray          # (C,) the worlds flown, sorted
    successes: np.ndarray      # (C,) successes in each
    flights: np.ndarray        # (C,) flights in each
    ci_low: float              # clustered_interval; NaN with fewer than 2 worlds
    ci_high: float
    design_effect: float


def by_world(success, world_seed) -> ByWorld:
    """Group flights by world: ``success`` (n,) bools, ``world_seed`` (n,) the seed of
    the world each flight flew in (the same seed is the same world)."""
    success = np.asarray(success, dtype=bool)
    world_seed = np.asarray(world_seed)
    if success.ndim != 1 or world_seed.shape != success.shape:
        raise ValueError(f"by_world: success and world_seed must be (n,) arrays of one "
                         f"length; got shapes {success.shape} and {world_seed.shape}")
    seeds, world = np.unique(world_seed, return_inverse=True)
    m = np.bincount(world, minlength=len(seeds))
    y = np.bincount(world, weights=success, minlength=len(seeds)).astype(np.int64)
    lo, hi, deff = (clustered_interval(y, m) if len(m) >= 2
                    else (float("nan"), float("nan"), float("nan")))
    return ByWorld(seeds, y, m, lo, hi, deff)


def run_flights(policy: Policy, env: DroneEnv, max_steps: int, record=None) -> np.ndarray:
    """Fly every flight of ``env`` once (from ``reset``), return steps survived (n,).

    ``record(step, seen, actions, terminated)`` is called after each step if given (for
    GIFs): ``seen`` holds the observation the actions were chosen from ("obs"), the poses
    they were flown from ("poses") and the RGB frames ("rgb": None unless rendered).
    """
    obs, _ = env.reset()
    policy.reset(env)
    alive = np.ones(env.n_envs, bool)
    steps = np.zeros(env.n_envs, dtype=np.int64)
    for t in range(max_steps):
        if record is not None:      # the recorder sees the view the action was chosen from
            seen = {"obs": obs, "poses": env.poses.copy(),
                    "rgb": None if env.last_rgb is None else env.last_rgb.copy()}
        actions = policy.act(obs)
        obs, _, terminated, _, _ = env.step(actions)
        if record is not None:
            record(t, seen, actions, terminated)
        alive &= ~terminated
        steps[alive] += 1                # actions completed without a collision
        if not alive.any():
            break
    return steps


def _chunk_seeds(seed: int, n_flights: int, chunk: int) -> list[tuple[int, int]]:
    """(flights, world seed) of every chunk: chunk k's worlds come from the k-th child
    of ``SeedSequence(seed)``, so a chunk's flights do not depend on who flies them."""
    children = np.random.SeedSequence(seed).spawn(-(-n_flights // chunk))
    return [(min(chunk, n_flights - start), int(c.generate_state(1)[0]))
            for start, c in zip(range(0, n_flights, chunk), children)]


def _fly_chunk(policy: Policy, scenario: str, n: int, child: int, worlds, n_worlds: int,
               observation: str, depth_model, max_steps: int, env_factory=DroneEnv,
               actions=None, camera=None) -> tuple[np.ndarray, np.ndarray]:
    """Steps survived by the ``n`` flights of one chunk (seed ``child``), and the seed of
    the world each flew in (its identity: the same seed is the same world)."""
    # A policy with a random generator (Random, an epsilon-greedy Q-net) draws from one
    # seeded by the chunk: a chunk's result is the same in any process, in any order.
    # (A duck-typed policy without ``reseed`` keeps its own generator.)
    if hasattr(policy, "reseed"):
        policy.reseed((child, 0x5EED))
    env = env_factory(scenario, n, seed=child, worlds=worlds, n_worlds=n_worlds,
                      observation=observation, depth_model=depth_model, max_steps=max_steps,
                      actions=actions, camera=camera)
    steps = run_flights(policy, env, max_steps)
    return steps, env.scene_seeds.copy()


def _fly_task(shared, task):
    """``_fly_chunk`` of one task (n, child), the rest of its arguments ``shared``."""
    n, child = task
    return _fly_chunk(*shared[:2], n, child, *shared[2:])


def evaluate_policy(policy: Policy, scenario: str = "basic", n_flights: int = 2000,
                    seed: int = 12345, max_steps: int = 50, chunk: int = 500,
                    depth: str = "gt", depth_estimator=None, n_worlds: int = 32,
                    progress: bool = True, workers: int = 1, env_factory=None,
                    actions=None, camera=None, worlds="test",
                    executor=None) -> EvalResult:
    """Success rate of ``policy`` over ``n_flights`` fresh flights (greedy, batched).

    The flights are flown ``chunk`` at a time, each chunk from its own seed
    (``_chunk_seeds``) with its own pool of ``n_worlds`` worlds: the worlds flown depend
    on ``chunk`` as on ``seed`` (``evaluate --json`` records both). ``worlds``: "test"
    (the evaluation seed range), or a sequence of world seeds every chunk flies (the
    paper's protocol: a model's own training worlds, ``training_worlds``). ``depth``:
    "gt" or "pred" (the DispNet ``depth_estimator``). ``workers`` > 1 flies the chunks
    in that many processes (one per core; forked, so the policy and the depth network
    are shared, not pickled); ``executor`` (``executor.get_executor``; default the local
    pool of ``workers``) flies them elsewhere, e.g. on Ray: the result is the same as
    with one process. ``env_factory``
    (default ``DroneEnv``) makes each chunk's env from ``DroneEnv``'s arguments: a
    subclass that changes what the policy sees
    (``examples/07_which_depth_errors_matter.py``) is flown the same way. ``actions``,
    ``camera``: the flights' (default: those the policy's Q-nets were trained with,
    recorded in their files; else the world's).
    """
    seed = check_seed(seed, "evaluate_policy: seed")
    if n_flights < 1:
        raise ValueError(f"evaluate_policy: n_flights must be >= 1; got {n_flights}")
    if chunk < 1:
        raise ValueError(f"evaluate_policy: chunk must be >= 1; got {chunk}")
    if workers < 1:
        raise ValueError(f"evaluate_policy: workers must be >= 1; got {workers}")
    if actions is None and camera is None:
        from .models import actions_and_camera
        actions, camera = actions_and_camera(policy)
    n_worlds = min(n_worlds, chunk, n_flights)
    observation = {"gt": "depth", "pred": "pred"}[depth]
    tasks = _chunk_seeds(seed, n_flights, chunk)
    if executor is None:
        executor = get_executor("local", workers)
    t0 = time.time()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=n_flights, unit="flight", desc=f"eval {policy.name} {scenario}",
                   dynamic_ncols=True, leave=False)
    shared = (policy, scenario, worlds, n_worlds, observation, depth_estimator, max_steps,
              env_factory or DroneEnv, actions, camera)
    try:
        runs = executor.run(_fly_task, tasks, shared, on_result=None if bar is None else
                            lambda i, _: bar.update(tasks[i][0]))
    finally:
        if bar is not None:
            bar.close()
    survived = np.concatenate([steps for steps, _ in runs])
    world = [world_seed for _, world_seed in runs]
    success = survived >= max_steps
    k = int(success.sum())
    lo, hi = wilson_interval(k, n_flights)
    w = by_world(success, np.concatenate(world))
    return EvalResult(policy.name, scenario, depth, n_flights, k, k / n_flights, lo, hi,
                      float(survived.mean()), time.time() - t0, seed,
                      len(w.flights), w.ci_low, w.ci_high, w.design_effect, w.seeds.tolist(),
                      w.successes.tolist(), w.flights.tolist())


@dataclass
class EvalConfig:
    """How ``evaluate`` flies a policy (``evaluate_spec``)."""
    flights: int = setting(2000, "test flights", source="paper",
                           check=up_to(1, 10 ** 6, "a million flights give a 95% interval "
                                                   "about 0.001 wide"))
    steps: int = setting(50, "steps without a collision for a success", source="paper",
                         check=up_to(1, 10 ** 4, "the paper's flights last 50"))
    scenario: str = setting("basic", "the test worlds", source="run",
                            choices=("basic", "channel", "intersections", "corners"))
    seed: int = setting(12345, "the test worlds' seed", source="run",
                        check=at_least(0))
    worlds: str = setting("test", "test: fresh worlds, unseen in training; train: the Q-net's "
                                  "own training worlds (the paper's protocol: it tests in "
                                  "the world it trained in)", source="run",
                          choices=("test", "train"))
    depth: str = setting("gt", "what the policies read: GT depth or the DispNet's",
                         source="run", choices=("gt", "pred"))
    depth_model: str = setting("", "DispNet .npz for --depth pred (empty: the shipped one "
                                   "of the scenario)", source="run")
    chunk: int = setting(500, "flights stepped together; each chunk flies its own pool of "
                              "worlds, so the chunk is part of which worlds the seed draws "
                              "(the record gives it)", source="run",
                         check=fits_memory(1, FLIGHT_BYTES, "flights stepped together"))
    workers: int = setting(1, "processes flying the chunks, one per core (the same "
                              "result; run with OMP_NUM_THREADS=1; with the local "
                              "executor at most the cores)", source="run",
                           check=at_least(1))
    executor: str = setting("local", "where the chunks fly: processes of this machine "
                                     "(--workers), or Ray tasks on the cluster ray.init() "
                                     "finds (RAY_ADDRESS; the same result)", source="run",
                            choices=EXECUTORS)
    mirror: bool = setting(False, "each Q-net also flies the mirrored view; greedy on the "
                                  "mean Q-values (docs/d3rqn.md section 10)", cli="main")
    flip_tta: bool = setting(False, "the DispNet's disparity averaged with its disparity on "
                                    "the mirrored frame (docs/depth.md section 7)", cli="main")

    def __post_init__(self):
        validate(self)
        if self.executor == "local":    # a cluster has cores of its own
            capped_workers(self)
        if self.depth == "gt":          # the DispNet's settings, where no DispNet reads
            if self.depth_model:
                raise ConfigError("depth_model", self.depth_model, "none with --depth gt "
                                  "(the DispNet reads only with --depth pred)")
            if self.flip_tta:
                raise ConfigError("flip_tta", True, "false with --depth gt (it averages "
                                  "the DispNet's disparity)")


def own_training_worlds(policy, scenario: str) -> np.ndarray:
    """The world seeds a Q-net policy trained in (``train.training_worlds`` of its file's
    ``train_config``: the run that wrote it, not the one it started from). ValueError
    for a baseline, for nets of different worlds, or for another scenario than theirs."""
    from .train import training_worlds
    trained = [m.meta.get("train_config") or {} for m in getattr(policy, "members", [policy])
               if hasattr(m, "meta")]
    pools = {tuple(training_worlds(t.get("seed", 0), t.get("n_worlds") or 32).tolist())
             for t in trained}
    where = {t.get("scenario", "basic") for t in trained}
    if not pools:
        why = "a baseline has none"
    elif len(pools) > 1:
        why = "these nets trained in different ones"
    elif where != {scenario}:
        why = f"it trained in {where.pop()!r} worlds, not {scenario!r}"
    else:
        return np.array(pools.pop(), np.int64)
    raise ValueError(f"--worlds train: flies a Q-net's own training worlds; {why}")


def evaluate_spec(spec: str, cfg: EvalConfig, depth_estimator=None,
                  progress: bool = True) -> tuple[EvalResult, dict]:
    """What ``evaluate SPEC`` does: fly the policy ``spec`` (``models.load_policy``;
    ValueError for a bad one), print its line, and return the result and the record
    ``--json`` appends (the command that gives it, included)."""
    from ..config import command_line
    from .models import BASELINES, load_policy, unfinished_warning
    pol = load_policy(spec, cfg.seed, mirror=cfg.mirror)
    worlds = "test" if cfg.worlds == "test" else own_training_worlds(pol, cfg.scenario)
    warning = unfinished_warning(pol)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    res = evaluate_policy(pol, cfg.scenario, cfg.flights, cfg.seed, cfg.steps, cfg.chunk,
                          cfg.depth, depth_estimator, progress=progress, workers=cfg.workers,
                          worlds=worlds, executor=get_executor(cfg.executor, cfg.workers))
    flip = depth_estimator is not None and cfg.flip_tta
    how = [f"{cfg.depth} depth"] + (["flip"] if flip else []) + \
        (["its training worlds"] if cfg.worlds == "train" else [])
    if spec not in BASELINES:
        what = f"  {spec} ({', '.join(how + (['mirror'] if cfg.mirror else []))})"
    else:                                     # of these only the reactive rule reads depth
        what = f"  ({', '.join(how)})" if spec == "reactive" else ""
    print(res.line() + what, flush=True)
    command = shell_command(["evaluate", spec, *command_line(EvalConfig, cfg)])
    record = {**res.to_dict(), "spec": spec, "depth_flip": bool(flip),
              "mirror": bool(cfg.mirror and spec not in BASELINES), "chunk": cfg.chunk,
              "worlds_set": cfg.worlds,
              "unfinished": warning is not None, "command": command}
    return res, record
