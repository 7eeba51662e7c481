"""Command-line hooks: ``check`` and ``exercise``.

    python -m minid3rqn check reward                     # checks exercises/reward.py
    python -m minid3rqn check reward --file my.py        # checks another file
    python -m minid3rqn check all --file docs/solutions  # teachers: every reference solution
    python -m minid3rqn exercise reward                  # check, train, evaluate, compare
    python -m minid3rqn exercise reward --baseline       # the paper's setting, same budget
"""
from __future__ import annotations

import argparse
from pathlib import Path

from ..config import UsageError
from .checks import EXERCISES


def _names() -> str:
    return ", ".join(f"{e.number}/{e.name}" for e in EXERCISES.values())


def _find(name: str):
    from .checks import find
    try:
        return find(name)
    except ValueError as e:
        raise UsageError(str(e)) from None


# -- check ---------------------------------------------------------------------------------
def add_arguments_check(p: argparse.ArgumentParser) -> None:
    p.add_argument("exercise", help=f"which exercise: {_names()}, or 'all'")
    p.add_argument("--file", default=None,
                   help="the file to check, or a folder holding the exercise's file (e.g. "
                        "docs/solutions, the reference solutions); default: your copy "
                        "exercises/<the exercise's file>.py, made from the template if missing")


def run_check(args) -> int:
    from .student import check_in_child, working_copy
    chosen = list(EXERCISES.values()) if args.exercise.lower() == "all" else \
        [_find(args.exercise)]
    given = None if args.file is None else Path(args.file)
    if given is not None and not given.exists():
        raise UsageError(f"--file: {args.file!r} does not exist (expected your exercise file, "
                         f"or a folder of them)")
    if given is not None and not given.is_dir() and len(chosen) > 1:
        raise UsageError(f"--file: 'all' checks a folder of exercise files; got the file "
                         f"{args.file!r}")
    failed = 0
    for ex in chosen:
        path = working_copy(ex.filename) if given is None else \
            given / ex.filename if given.is_dir() else given
        report = check_in_child(ex.checker, path, f"{ex.number} ({ex.name})")
        nxt = f"python -m minid3rqn exercise {ex.name}" if ex.trains else None
        print(report.text(next_step=nxt) + ("\n" if len(chosen) > 1 else ""))
        failed += not report.passed
    if len(chosen) > 1:
        print(f"{len(chosen) - failed}/{len(chosen)} exercises pass")
    return 1 if failed else 0


# -- exercise ------------------------------------------------------------------------------
def add_arguments_exercise(p: argparse.ArgumentParser) -> None:
    from .runner import AGENT_BUDGETS
    p.add_argument("exercise", help=f"which exercise: {_names()}")
    p.add_argument("--file", default=None,
                   help="your file (default: exercises/<the exercise's file>.py); a run from "
                        "a file of another name is named after it")
    p.add_argument("--baseline", action="store_true",
                   help="run the paper's setting instead of your file, for comparison (trained "
                        "once per budget and seed, then reused)")
    p.add_argument("--budget", default="small", choices=sorted(AGENT_BUDGETS),
                   help="small: the exercise sheets' runs; tiny: a first look, too short to "
                        "learn much; smoke: seconds, for tests")
    p.add_argument("--variant", default=None, choices=["ddqn", "d3qn", "ddrqn", "d3rqn"],
                   help="Q-network (default d3rqn; the fov exercise compares d3rqn and d3qn)")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the training (the test flights stay the same); compare runs "
                        "of one seed, and repeat with others before concluding")


def run_exercise(args) -> int:
    import sys
    from .runner import run_exercise as run
    _find(args.exercise)
    if args.seed < 0:
        raise UsageError(f"--seed: expected a number >= 0; got {args.seed}")
    if args.file is not None and not Path(args.file).is_file():
        raise UsageError(f"--file: {args.file!r} is not a file (expected your exercise file)")
    result = run(args.exercise, file=args.file, baseline=args.baseline, budget=args.budget,
                 variant=args.variant, seed=args.seed, progress=sys.stderr.isatty())
    return 0 if result.get("passed", True) else 1
