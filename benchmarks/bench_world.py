"""Speed of the world: rendering, ray casting against pymunk, env steps, batched steps.

Run (numbers in docs/world.md come from this command):

    OMP_NUM_THREADS=1 python benchmarks/bench_world.py --seed 0

It keeps freed memory for reuse, as ``python -m minid3rqn`` does (minid3rqn/allocator.py);
``--default-malloc`` leaves glibc's allocator at its defaults (to measure what keeping
freed memory is worth).

Each figure is the median CPU time (``time.thread_time``) of individually timed calls in
one process on one core: CPU time leaves out the time other processes hold the core, so
the figures stay comparable on a shared machine (a busy machine still slows them down
somewhat through shared caches).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pymunk

try:
    import resource                   # Unix only: the page-fault count below
except ImportError:
    resource = None

from minid3rqn.allocator import keep_freed_memory
from minid3rqn.world import (Camera, DroneEnv, make_scene, render, render_batch,
                             sample_start_pose)
from minid3rqn.world.renderer import cast_columns

from _timing import median_ms, positive_int


def clock() -> float:
    """CPU seconds used by this thread: unlike wall time it does not count the time other
    processes hold the core, so figures stay comparable on a shared machine."""
    return time.thread_time()


def best_time(fn, n: int, repeats: int) -> float:
    """CPU seconds per call: the median over ``n * repeats`` individually timed calls."""
    return median_ms(fn, n * repeats, warmup=0, clock=clock) / 1e3


def cast_faults(fn, n: int) -> tuple[float, float, float]:
    """Per call of ``fn`` (mean of n calls): pages the kernel had to fault in (memory the
    allocator had handed back and asked for again), and the user and kernel CPU ms."""
    before = resource.getrusage(resource.RUSAGE_SELF)
    for _ in range(n):
        fn()
    after = resource.getrusage(resource.RUSAGE_SELF)
    return ((after.ru_minflt - before.ru_minflt) / n,
            1e3 * (after.ru_utime - before.ru_utime) / n,
            1e3 * (after.ru_stime - before.ru_stime) / n)


def pymunk_depth_row(scene, pose, xn, reach=200.0):
    """The column depths of one frame by a Python loop of pymunk segment queries."""
    f = np.array([np.cos(pose[2]), np.sin(pose[2])])
    g = np.array([np.sin(pose[2]), -np.cos(pose[2])])
    start = (float(pose[0]), float(pose[1]))
    out = np.empty(len(xn))
    for u, x in enumerate(xn):
        end = pose[:2] + reach * (f + x * g)
        hit = scene.space.segment_query_first(start, (float(end[0]), float(end[1])), 0.0,
                                              pymunk.ShapeFilter())
        out[u] = hit.alpha * reach
    return out


def profile_vec_step(scenario: str, n: int, seed: int, steps: int = 40) -> None:
    """cProfile of ``steps`` DroneEnv.step calls of N flights, as the benchmark times them (the
    first 8 steps after a reset; resets are not profiled): each function's share of the
    time (cumulative, so nested shares overlap), the ones above 2 %."""
    import cProfile
    import pstats
    vec = DroneEnv(scenario, n, seed=seed, observation="rgb")
    act = np.random.default_rng(seed)
    prof = cProfile.Profile()
    for k in range(steps):
        if k % 8 == 0:
            vec.reset()
        prof.enable()
        vec.step(act.integers(0, 5, n))
        prof.disable()
    stats = pstats.Stats(prof).stats            # (file, line, name) -> (cc, nc, tt, ct, ..)
    total = max(ct for (_, _, _, ct, _) in stats.values())
    rows = sorted(((ct / total, name, f"{file.rsplit('/', 1)[-1]}:{line}")
                   for (file, line, name), (_, _, _, ct, _) in stats.items()), reverse=True)
    print(f"DroneEnv.step, {n} flights, {steps} steps, scenario {scenario!r}, seed {seed}:"
          f" cumulative share of the time\n")
    for share, name, where in rows:
        if share >= 0.02:
            print(f"{100 * share:5.1f} %  {name}  ({where})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenario", default="basic")
    parser.add_argument("--repeats", type=positive_int, default=5)
    parser.add_argument("--n-envs", type=int, default=100)
    parser.add_argument("--quick", action="store_true", help="fewer iterations (a smoke run)")
    parser.add_argument("--default-malloc", action="store_true",
                        help="leave glibc's allocator at its defaults instead of keeping "
                             "freed memory as python -m minid3rqn does (minid3rqn/allocator.py)")
    parser.add_argument("--profile", action="store_true",
                        help="instead: where a batched step's time goes (cProfile of 40 "
                             "DroneEnv.step calls, --n-envs flights)")
    args = parser.parse_args(argv)
    kept = False if args.default_malloc else keep_freed_memory()
    if args.profile:
        profile_vec_step(args.scenario, args.n_envs, args.seed)
        return
    k = 0.1 if args.quick else 1.0
    reps = 2 if args.quick else args.repeats
    rng = np.random.default_rng(args.seed)
    scene = make_scene(args.scenario, args.seed)
    poses = np.stack([sample_start_pose(scene, rng) for _ in range(16)])
    rows = []

    for cam in (Camera(32, 104), Camera(64, 208)):
        it = iter(range(10 ** 9))
        sec = best_time(lambda: render(scene, poses[next(it) % 16], cam), int(400 * k) or 5, reps)
        rows.append((f"render RGB + depth, 1 world, {cam.height}x{cam.width}", 1 / sec, sec))

    cam = Camera()
    xn = cam.column_rays()
    batch = scene.batch()
    it = iter(range(10 ** 9))
    sec_cast = best_time(lambda: cast_columns(batch, poses[next(it) % 16][None], xn),
                         int(400 * k) or 5, reps)
    rows.append(("ray cast only (104 column rays), NumPy", 1 / sec_cast, sec_cast))
    it = iter(range(10 ** 9))
    sec_pm = best_time(lambda: pymunk_depth_row(scene, poses[next(it) % 16], xn),
                       int(100 * k) or 5, reps)
    rows.append(("same 104 rays, Python loop of pymunk segment_query_first", 1 / sec_pm, sec_pm))
    sec_render = rows[0][2]
    many = np.stack([sample_start_pose(scene, rng) for _ in range(256)])
    sec_cast_b = best_time(lambda: cast_columns(batch, many, xn), max(2, int(10 * k)), reps) / 256
    rows.append(("ray cast only, 256 poses per call, NumPy (per frame)", 1 / sec_cast_b,
                 sec_cast_b))
    faults = cast_faults(lambda: cast_columns(batch, many, xn), 10) if resource else None
    sec_batch1 = best_time(lambda: render_batch(scene, many[:100], cam), max(2, int(10 * k)),
                           reps) / 100
    rows.append(("render_batch, 100 poses in 1 world, 32x104 (per frame)", 1 / sec_batch1,
                 sec_batch1))

    # Steps, resets excluded (world generation and start sampling are timed below): the
    # first 8 steps after a reset, a random action each, every flight still flying
    # rendered (RGB) every step.
    def time_steps(env, act_fn, episodes):
        times = []
        for _ in range(episodes):
            env.reset()
            for _ in range(8):
                start = clock()
                env.step(act_fn())
                times.append(clock() - start)
                if not env.active.any():
                    break
        return float(np.median(times))

    act = np.random.default_rng(args.seed)
    env = DroneEnv(args.scenario, 1, seed=args.seed, observation="rgb")
    sec_single = time_steps(env, lambda: act.integers(0, 5, 1), int(40 * k) or 3)
    rows.append(("DroneEnv.step (distances + render), 1 flight", 1 / sec_single,
                 sec_single))
    n = args.n_envs
    vec = DroneEnv(args.scenario, n, seed=args.seed, observation="rgb")
    vec.reset()
    sec_vec = time_steps(vec, lambda: act.integers(0, 5, n), max(1, int(3 * k))) / n
    rows.append((f"DroneEnv.step, {n} flights (per frame)", 1 / sec_vec, sec_vec))
    try:                             # the same batch through Gymnasium's vector form,
        import gymnasium             # which restarts finished flights within the step:
        import minid3rqn.gym         # against the env that does the same
        auto = DroneEnv(args.scenario, n, seed=args.seed, observation="rgb", autoreset=True)
        envs = gymnasium.make_vec(minid3rqn.gym.ENV_ID, num_envs=n, observation="rgb",
                                  vectorization_mode="vector_entry_point", seed=args.seed)
        for name, e in ((f"DroneEnv(autoreset=True).step, {n} flights", auto),
                        (f"gymnasium.make_vec(...).step, {n} flights", envs)):
            e.reset()
            sec = best_time(lambda: e.step(act.integers(0, 5, n)), max(8, int(24 * k)),
                            reps) / n
            rows.append((f"{name} (per frame, restarts included)", 1 / sec, sec))
    except ImportError:
        pass
    sec_start = best_time(lambda: sample_start_pose(scene, rng), int(20 * k) or 3, reps)
    rows.append(("sample_start_pose (a reset's start pose)", 1 / sec_start, sec_start))

    seeds = iter(range(10 ** 6))
    sec_gen = best_time(lambda: make_scene(args.scenario, next(seeds)), int(20 * k) or 3, reps)
    rows.append((f"make_scene({args.scenario!r}) (world generation)", 1 / sec_gen, sec_gen))

    print(f"scenario {args.scenario!r}, seed {args.seed}, median CPU time per call; "
          f"allocator: {'freed memory kept' if kept else 'glibc defaults'}\n")
    print("| measurement | frames/s | ms per frame |")
    print("|---|---:|---:|")
    for name, fps, sec in rows:
        print(f"| {name} | {fps:,.0f} | {1e3 * sec:.3f} |")
    print(f"\nrender vs pymunk ray loop: {sec_pm / sec_render:.1f}x faster "
          f"(ray casting alone: {sec_pm / sec_cast:.1f}x; batched ray casting: "
          f"{sec_pm / sec_cast_b:.1f}x; batched render: {sec_pm / sec_batch1:.1f}x)")
    print(f"batched step vs single steps, per frame: {sec_single / sec_vec:.1f}x faster")
    if faults:
        print("one 256-pose cast call: {:,.0f} pages faulted in, {:.2f} ms user, {:.2f} ms "
              "kernel time (mean of 10 calls)".format(*faults))


if __name__ == "__main__":
    main()
