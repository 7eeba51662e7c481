"""Classroom exercises: checkers for a student's change, and a runner that trains with it.

Eight exercises (docs/exercises/README.md), each with one file to edit in
``exercises/`` at the repository root, a checker and a classroom-budget run:

    python -m minid3rqn check <exercise> [--file path]
    python -m minid3rqn exercise <exercise> [--baseline] [--budget small|tiny]

``check_<exercise>(path) -> Report`` can also be called from Python (and from tests).
Reference solutions for teachers live in docs/solutions/, outside the package.
"""
from .registry import EXERCISES, Exercise, find
from .report import Report

__all__ = ["EXERCISES", "Exercise", "find", "Report"]
