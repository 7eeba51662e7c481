"""How long the learning path's commands take: each example at its defaults, and the
classroom exercise runs (their paper settings, `--baseline`; the tiny budget; exercise
7's reference solution), timed one after the other on this machine, as a student runs
them.

    python benchmarks/bench_examples.py                      # all of them (about 30 min)
    python benchmarks/bench_examples.py --only 01 05 reward  # some
    python benchmarks/bench_examples.py --only 04-full       # example 04's full run, alone
    python benchmarks/bench_examples.py --only reproduce-quick   # Tables 5 and 6, quick

Run it from the repository's root. Each command runs with OMP_NUM_THREADS=1, this
tree's package, and a fresh temporary folder as its working directory (outputs, and the
exercises' shared paper-setting model, start empty there: nothing in the repository
changes, and no run reuses another's training). Printed and appended to ``--json``
(default ``runs/bench_examples.jsonl``), one line per command: the wall-clock seconds,
the CPU seconds of the command (what it takes on a free core), the machine's load
average when it started (the machine may be shared), its core count and the exit code.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the classroom exercises with a run (exercise 6, the autograd op, is its check)
EXERCISES = ("reward", "actions", "fov", "memory", "ablation", "depth-loss", "depth-errors")
# timed only when named in --only: example 04's full training (about 14 minutes) and the
# quick reproduction (two processes: it needs the machine's two cores to itself)
LONG = ("04-full", "reproduce-quick")


def commands() -> dict[str, list[str]]:
    """name -> argv, in the order of the learning path (docs/README.md)."""
    py = sys.executable
    ex = [str(p) for p in sorted((ROOT / "examples").glob("*.py"))]
    return {**{Path(p).name[:2]: [py, p] for p in ex},
            "04-full": [py, str(ROOT / "examples" / "04_train_d3rqn.py"), "--full"],
            "fly": [py, "-m", "minid3rqn", "fly", "--seed", "0"],
            "reproduce-quick": [py, "-m", "minid3rqn", "reproduce", "--quick", "--workers", "2"],
            **{name: [py, "-m", "minid3rqn", "exercise", name, "--baseline"]
               for name in EXERCISES},
            # the tiny budget, and exercise 7's reference solution (SSIM + L1) on the
            # frames its baseline collected (SETUP runs that baseline first, untimed)
            "reward-tiny": [py, "-m", "minid3rqn", "exercise", "reward", "--baseline",
                            "--budget", "tiny"],
            "depth-loss-tiny": [py, "-m", "minid3rqn", "exercise", "depth-loss", "--baseline",
                                "--budget", "tiny"],
            "depth-loss-ssim": [py, "-m", "minid3rqn", "exercise", "depth-loss", "--file",
                                str(ROOT / "docs" / "solutions" / "photometric.py")]}


# name -> the command run before it in the same folder, not timed
SETUP = {"depth-loss-ssim": "depth-loss"}


def timed(argv: list[str], setup: list[str] | None = None) -> dict:
    """Run ``argv`` in a fresh folder (after ``setup``, untimed, in the same folder); wall
    and CPU seconds, load average, exit code."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        if setup:
            subprocess.run(setup, cwd=tmp, env=env, capture_output=True, check=True)
        load = os.getloadavg()[0]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        done = subprocess.run(argv, cwd=tmp, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
        seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    row = {"seconds": round(seconds, 1), "cpu_seconds": round(cpu, 1),
           "load_before": round(load, 2), "returncode": done.returncode,
           "stdout_tail": done.stdout[-1500:]}
    if done.returncode:
        row["stderr_tail"] = done.stderr[-500:]
    return row


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", default=None, help="names to time (default: all)")
    p.add_argument("--json", default="runs/bench_examples.jsonl",
                   help="append one JSON line per command here")
    args = p.parse_args()
    table = commands()
    unknown = sorted(set(args.only or []) - set(table))
    if unknown:
        raise SystemExit(f"bench_examples --only: unknown names {unknown}; expected some of "
                         f"{sorted(table)}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    for name, argv in table.items():
        if (name not in args.only) if args.only else name in LONG:
            continue
        row = {"name": name, "command": " ".join(argv[1:]), **timed(argv, table.get(SETUP.get(name))),
               "cores": os.cpu_count(), "machine": platform.processor() or platform.machine(),
               "date": time.strftime("%Y-%m-%d %H:%M")}
        print(f"{name:12s} {row['seconds']:8.1f} s wall {row['cpu_seconds']:8.1f} s CPU  "
              f"(load {row['load_before']:.2f}, exit {row['returncode']})", flush=True)
        with open(args.json, "a") as f:
            f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
