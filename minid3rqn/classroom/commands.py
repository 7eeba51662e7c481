"""Command-line hooks: ``check`` and ``exercise``.

    python -m minid3rqn check reward                  # checks exercises/reward.py
    python -m minid3rqn check reward --file my.py     # checks another file
    python -m minid3rqn check all --solutions         # teachers: every reference solution
    python -m minid3rqn exercise reward               # check, train, evaluate, compare
    python -m minid3rqn exercise reward --baseline    # the paper's setting, same budget
"""
from __future__ import annotations

import argparse
from pathlib import Path

from ..config import UsageError
from .registry import EXERCISES


def _names() -> str:
    return ", ".join(f"{e.number}/{e.name}" for e in EXERCISES.values())


# -- check ---------------------------------------------------------------------------------
def add_arguments_check(p: argparse.ArgumentParser) -> None:
    p.add_argument("exercise", help=f"which exercise: {_names()}, or 'all'")
    p.add_argument("--file", default=None,
                   help="the file to check (default: exercises/<the exercise's file>.py)")
    p.add_argument("--solutions", action="store_true",
                   help="check the reference solutions in docs/solutions/ (teachers)")


def run_check(args) -> int:
    from .loader import default_path
    from .registry import find
    from .runner import solution_path
    if args.exercise.lower() == "all":
        if args.file:
            raise UsageError("--file: checks one exercise, not 'all'")
        chosen = list(EXERCISES.values())
    else:
        try:
            chosen = [find(args.exercise)]
        except ValueError as e:
            raise UsageError(str(e)) from None
    failed = 0
    for ex in chosen:
        path = Path(args.file) if args.file else (solution_path(ex) if args.solutions
                                                  else default_path(ex.filename))
        report = ex.checker(path)
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
                   help="your file (default: exercises/<the exercise's file>.py)")
    p.add_argument("--baseline", action="store_true",
                   help="run the paper's setting instead of your file, for comparison")
    p.add_argument("--budget", default="small", choices=sorted(AGENT_BUDGETS),
                   help="small: the exercise sheets' runs (<= 10 min on a 2-core laptop); "
                        "tiny: a 2-minute first look; smoke: seconds, for tests")
    p.add_argument("--variant", default=None, choices=["ddqn", "d3qn", "ddrqn", "d3rqn"],
                   help="Q-network (default d3rqn; the fov exercise compares d3rqn and d3qn)")


def run_exercise(args) -> int:
    import sys
    from .runner import run_exercise as run
    try:
        result = run(args.exercise, file=args.file, baseline=args.baseline,
                     budget=args.budget, variant=args.variant,
                     progress=sys.stderr.isatty())
    except ValueError as e:
        raise UsageError(str(e)) from None
    return 0 if result.get("passed", True) else 1


__all__ = ["add_arguments_check", "run_check", "add_arguments_exercise", "run_exercise"]
