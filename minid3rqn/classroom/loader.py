"""Loading a student's exercise file and calling into it without scary tracebacks.

A student's file is plain Python at a path (``exercises/reward.py`` by default). It is
imported under a private module name, so two versions (the template and a solution)
can be loaded side by side. Errors are turned into one readable sentence that names
the line of the student's file where things went wrong.
"""
from __future__ import annotations

import hashlib
import importlib.util
import sys
import traceback
from pathlib import Path

from .report import Report

REPO_ROOT = Path(__file__).resolve().parents[2]


def default_path(filename: str) -> Path:
    """``exercises/<filename>`` under the current folder if it exists, else in the repo."""
    here = Path("exercises") / filename
    return here if here.is_file() else REPO_ROOT / "exercises" / filename


def where_in(path, exc: BaseException) -> str:
    """' (your file, line N: <code>)' for the deepest frame inside ``path``, else ''."""
    target = str(Path(path).resolve()) if path else None
    found = ""
    for frame in traceback.extract_tb(exc.__traceback__):
        if target and str(Path(frame.filename).resolve()) == target:
            code = (frame.line or "").strip()
            found = f" (your file, line {frame.lineno}: {code})" if code else \
                f" (your file, line {frame.lineno})"
    return found


def describe(exc: BaseException, path=None) -> str:
    """'TypeError: message (your file, line 12: ...)'."""
    return f"{type(exc).__name__}: {exc}{where_in(path, exc)}"


def load_student_module(path, report: Report):
    """Import the file at ``path``; on any problem record a failure and raise ``Stop``."""
    path = Path(path)
    if not path.is_file():
        report.fail(f"file not found: {path}",
                    hint="run the check from the repository root, or pass the file with "
                         "--file path/to/your_file.py", stop=True)
    digest = hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:10]
    name = f"_minid3rqn_student_{path.stem}_{digest}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as e:
        report.fail(f"Python cannot read {path.name}: {e.msg} at line {e.lineno}"
                    + (f": {e.text.strip()}" if e.text else ""),
                    hint="look for a missing bracket, colon or a wrong indentation there",
                    stop=True)
    except Exception as e:  # noqa: BLE001 - anything the student's file raises on import
        report.fail(f"importing {path.name} raised {describe(e, path)}", stop=True)
    sys.modules.pop(name, None)
    report.ok(f"{path.name} loads")
    return module


def get_callable(module, name: str, report: Report, path=None):
    fn = getattr(module, name, None)
    if fn is None:
        report.fail(f"{Path(path).name if path else 'your file'} defines no `{name}`",
                    hint=f"keep the function name `{name}` from the template", stop=True)
    if not callable(fn):
        report.fail(f"`{name}` must be a function; got {type(fn).__name__}", stop=True)
    return fn


def get_value(module, name: str, report: Report, path=None):
    if not hasattr(module, name):
        report.fail(f"{Path(path).name if path else 'your file'} defines no `{name}`",
                    hint=f"keep the name `{name}` from the template", stop=True)
    return getattr(module, name)
