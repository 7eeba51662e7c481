"""Classroom exercises: checkers for a student's change, and a runner that trains with it.

Eight exercises (docs/exercises/README.md). Each has a template in ``templates/``, which
the first check copies to ``exercises/<file>.py`` for the student to edit, a checker, and
a classroom-budget run:

    python -m minid3rqn check <exercise> [--file path]
    python -m minid3rqn exercise <exercise> [--baseline] [--budget small|tiny] [--seed N]

``checks.check_<exercise>(path) -> Report`` can also be called from Python (and from
tests). Reference solutions for teachers live in docs/solutions/, outside the package.
"""
from .checks import EXERCISES, Exercise, find
from .student import Report

__all__ = ["EXERCISES", "Exercise", "find", "Report"]
