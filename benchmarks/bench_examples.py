"""How long the learning path's commands take: each example, and the classroom exercise
runs (their paper settings, `--baseline`: the templates are unfilled until a student
edits them), timed one after the other on this machine (wall clock), as a student runs them.

    python benchmarks/bench_examples.py                      # all of them (about 30 min)
    python benchmarks/bench_examples.py --only 01 05 reward  # some
    python benchmarks/bench_examples.py --only 04            # example 04's full run, alone

Run it from the repository's root on an otherwise idle machine. Outputs go to a
temporary folder (nothing in the repository changes); one JSON line per command is
appended to ``--json`` (default ``runs/bench_examples.jsonl``), with the machine's
core count and the command's exit code. The figures are in docs/README.md.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the classroom exercises with a run (exercise 6, the autograd op, is its check)
EXERCISES = ("reward", "actions", "fov", "memory", "ablation", "depth-loss", "depth-errors")
# timed only when named in --only: example 04's full training (tens of minutes)
LONG = ("04",)


def commands(tmp: Path) -> dict[str, list[str]]:
    """name -> argv, in the order of the learning path (docs/README.md)."""
    py = sys.executable
    return {
        "01": [py, "examples/01_autograd_tour.py"],
        "02": [py, "examples/02_world_and_camera.py", "--out", str(tmp / "02")],
        "03": [py, "examples/03_train_depth.py", "--out", str(tmp / "03")],
        "04-smoke": [py, "examples/04_train_d3rqn.py", "--smoke", "--out", str(tmp / "04")],
        "04": [py, "examples/04_train_d3rqn.py", "--out", str(tmp / "04-full")],
        "05": [py, "examples/05_evaluate.py"],
        "06": [py, "examples/06_wall_ahead.py", "--out", str(tmp / "06")],
        "07": [py, "examples/07_which_depth_errors_matter.py"],
        "08": [py, "examples/08_where_flights_crash.py"],
        "fly": [py, "-m", "minid3rqn", "fly", "--gif", str(tmp / "fly.gif"), "--seed", "0"],
        **{name: [py, "-m", "minid3rqn", "exercise", name, "--baseline", "--out", str(tmp / name)]
           for name in EXERCISES},
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", default=None, help="names to time (default: all)")
    p.add_argument("--json", default="runs/bench_examples.jsonl")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        table = commands(Path(tmp))
        unknown = sorted(set(args.only or []) - set(table))
        if unknown:
            raise SystemExit(f"bench_examples --only: unknown names {unknown}; expected some of "
                             f"{sorted(table)}")
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        for name, argv in table.items():
            if (name not in args.only) if args.only else name in LONG:
                continue
            t0 = time.perf_counter()
            done = subprocess.run(argv, cwd=ROOT, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True)
            seconds = time.perf_counter() - t0
            row = {"name": name, "command": " ".join(argv[1:]), "seconds": round(seconds, 1),
                   "returncode": done.returncode, "cores": os.cpu_count(),
                   "machine": platform.processor() or platform.machine(),
                   "date": time.strftime("%Y-%m-%d %H:%M")}
            if done.returncode:
                row["stderr_tail"] = done.stderr[-500:]
            print(f"{name:12s} {seconds:8.1f} s  (exit {done.returncode})", flush=True)
            with open(args.json, "a") as f:
                f.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
