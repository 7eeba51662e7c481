"""A student's file: where it is, loading it, calling into it, and what the checks found.

A student edits ``exercises/<file>.py``, a copy of the template in
``minid3rqn/classroom/templates/`` made by the first ``check`` or ``exercise`` (the
templates themselves stay as shipped: the tests check the checkers against them). The
file is imported under a private module name, so two versions (the template and a
solution) can be loaded side by side. Every call into it goes through ``call``: a time
limit, and whatever goes wrong (an exception, an endless loop, ``sys.exit()``, a Ctrl-C)
becomes one readable line naming the line of the student's file, never a traceback.
A whole check runs in a process of its own (``check_in_child``), so that code which
hangs past the time limit, kills its process or forks cannot stop the checker.

A ``Report`` collects one line per check: ``ok`` (passed), ``fail`` (must be fixed, with
a hint on how) or ``note`` (worth knowing, not an error). A check that cannot go on (the
file does not load, the function is missing) raises ``Stop`` after recording its
failure, so that later checks do not pile confusing errors on the first one.
"""
from __future__ import annotations

import hashlib
import importlib.util
import inspect
import json
import os
import select
import shutil
import signal
import sys
import textwrap
import threading
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

from ..autograd import GradcheckError

TEMPLATES = Path(__file__).resolve().parent / "templates"
TIME_LIMIT = 10.0          # seconds for any one call into the student's code


class Stop(Exception):
    """Raised inside a checker to end it early; the failure is already recorded."""


class TooSlow(BaseException):
    """The time limit ran out (a BaseException: a student's ``except Exception`` must
    not swallow it)."""


class Report:
    """What a checker found. ``passed`` is True when no line failed."""

    def __init__(self, exercise: str, path=None, template: Path | None = None):
        self.exercise, self.template = exercise, template
        self.path = None if path is None else str(path)
        self.lines: list[tuple[str, str]] = []
        self.summary: dict = {}           # what the check found out, for the runner
        self.module = None                # the student's module, once loaded

    def ok(self, text: str) -> None:
        self.lines.append(("ok", text))

    def note(self, text: str) -> None:
        self.lines.append(("note", text))

    def fail(self, text: str, hint: str | None = None, stop: bool = False) -> None:
        self.lines.append(("FAIL", text if hint is None else f"{text}\nHint: {hint}"))
        if stop:
            raise Stop(text)

    @property
    def passed(self) -> bool:
        return not self.failures

    @property
    def failures(self) -> list[str]:
        return [text for kind, text in self.lines if kind == "FAIL"]

    @property
    def messages(self) -> str:
        """All lines as one string (handy in tests: ``"still the paper's" in r.messages``)."""
        return "\n".join(text for _, text in self.lines)

    def text(self, next_step: str | None = None) -> str:
        out = [f"Exercise {self.exercise}" + (f": checking {self.path}" if self.path else "")]
        for kind, text in self.lines:
            tag = {"ok": "[ok]  ", "note": "[note]", "FAIL": "[FAIL]"}[kind]
            out.append(f"  {tag} " + textwrap.indent(text, " " * 9).lstrip())
        n = len(self.failures)
        out.append(f"NOT YET: {n} problem{'s' if n > 1 else ''} to fix (see [FAIL] above), "
                   f"then run the check again." if n else
                   "PASSED." + (f" Next: {next_step}" if next_step else ""))
        return "\n".join(out)

    def __repr__(self) -> str:
        return f"Report({self.exercise!r}, passed={self.passed}, lines={len(self.lines)})"


def exercises_folder() -> Path:
    """Where the students' copies live: ``exercises/`` at the repository's root when the
    package runs from a checkout (whatever the current folder), else under the current
    folder."""
    root = Path(__file__).resolve().parents[2]
    return root / "exercises" if (root / "pyproject.toml").is_file() else Path("exercises")


def working_copy(filename: str) -> Path:
    """``exercises/<filename>`` (``exercises_folder``), copied from the template first if it
    is not there yet (delete it to start over); as a path from the current folder if it
    lies below it."""
    path = exercises_folder() / filename
    if path.is_absolute() and path.is_relative_to(Path.cwd()):
        path = path.relative_to(Path.cwd())
    if not path.is_file():
        path.parent.mkdir(exist_ok=True)
        shutil.copyfile(TEMPLATES / filename, path)
        print(f"{path}: a fresh copy of the template, yours to edit")
    return path


def line_in(path, exc: BaseException) -> tuple[int, str] | None:
    """(line number, code) of the deepest frame of ``exc``'s traceback inside the file
    ``path``, or None."""
    target = str(Path(path).resolve()) if path else None
    found = None
    for frame in traceback.extract_tb(exc.__traceback__):
        if target and str(Path(frame.filename).resolve()) == target:
            found = frame.lineno, (frame.line or "").strip()
    return found


def where_in(path, exc: BaseException) -> str:
    """' (your file, line N: <code>)' for the deepest frame inside ``path``, else ''."""
    found = line_in(path, exc)
    if found is None:
        return ""
    return f" (your file, line {found[0]}" + (f": {found[1]})" if found[1] else ")")


def describe(exc: BaseException, path=None) -> str:
    """'TypeError: message (your file, line 12: ...)'."""
    return f"{type(exc).__name__}: {exc}{where_in(path, exc)}"


@contextmanager
def time_limit(seconds: float):
    """Raise ``TooSlow`` after ``seconds`` (with SIGALRM, in the main thread; where
    there is none, such as on Windows, without a limit)."""
    if not hasattr(signal, "setitimer") or threading.current_thread() is not \
            threading.main_thread():
        yield
        return

    def expire(signum, frame):
        raise TooSlow()

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# -- the check in a process of its own ------------------------------------------------
CHECK_SECONDS = 60.0       # wall-clock limit of a whole check, in its own process
CHECK_CPU_SECONDS = 30     # CPU-time limit of that process (RLIMIT_CPU; all its threads)


def _jsonable(value):
    """numpy scalars and arrays in a check's summary, as JSON can hold them."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def _stopped(status: int, seconds: float | None, cpu_seconds: int) -> str:
    """Why the check's process ended without a report, in one line."""
    if seconds is not None:
        return (f"your code stopped the checker: it was still running after {seconds:g} s "
                f"(an infinite loop that ignores the time limit?) and was killed")
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else ""
        why = f" ({name}: more than {cpu_seconds} s of CPU time)" \
            if sig == getattr(signal, "SIGXCPU", None) else f" ({name})" if name else ""
        return f"your code stopped the checker: killed by signal {sig}{why}"
    return (f"your code stopped the checker: it ended the process (exit status "
            f"{os.waitstatus_to_exitcode(status)}) before the check was done")


def check_in_child(checker, path, label: str | None = None, seconds: float = CHECK_SECONDS,
              cpu_seconds: int = CHECK_CPU_SECONDS) -> Report:
    """``checker(path)`` (a ``Report``) in a child process started with ``os.setsid``,
    limited to ``seconds`` of wall-clock time and ``cpu_seconds`` of CPU time (``RLIMIT_CPU``), its
    whole process group killed when it ends: student code that hangs, ignores the
    per-call limit, kills its process or forks cannot stop or outlive the check. The
    report comes back without the module (``report.module`` is None); a child that ends
    without one gives (``label``: the exercise it names) a report of one failure ("your code stopped the checker: killed by
    signal 9"). Where processes cannot fork (Windows) the check runs in this process.

    What it protects against: mistakes (an endless loop, a crash, an ``exit()``, a stray
    ``os.kill``). What it does not: code written to do harm. The child runs as the same
    user, with the same files: it can delete or change them, and a process it starts
    that calls ``os.setsid`` itself is beyond the group's reach."""
    if not hasattr(os, "fork"):
        return checker(path)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:                                          # the child: check, say, end
        code = 0
        try:
            os.close(read)
            os.setsid()
            import resource
            resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds + 5))
            report = checker(path)
            data = json.dumps({"exercise": report.exercise, "lines": report.lines,
                               "template": report.template and str(report.template),
                               "summary": report.summary}, default=_jsonable).encode()
            with os.fdopen(write, "wb") as f:
                f.write(data)
        except BaseException:                           # noqa: BLE001 - told by the status
            traceback.print_exc()
            code = 1
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    os.close(write)
    chunks, deadline, late, status = [], time.monotonic() + seconds, None, None
    try:
        while status is None:             # until the child ends (what it forked may keep
            left = deadline - time.monotonic()          # the pipe open), or time is up
            if left <= 0:
                late = seconds
                break
            if select.select([read], [], [], min(left, 0.05))[0]:
                chunks.append(os.read(read, 1 << 16))
            done, code = os.waitpid(pid, os.WNOHANG)
            status = code if done else None
        while status is not None and select.select([read], [], [], 0)[0]:
            chunk = os.read(read, 1 << 16)           # what it wrote before it ended
            if not chunk:
                break
            chunks.append(chunk)
    finally:                              # Ctrl-C here too: nothing of the check lives on
        os.close(read)
        _kill_group(pid)                  # the child if still running, and what it forked
        if status is None:
            status = os.waitpid(pid, 0)[1]
    try:
        data = json.loads(b"".join(chunks)) if late is None else None
    except ValueError:
        data = None
    if data is None:
        report = Report(label or Path(path).stem, path)
        report.fail(_stopped(status, late, cpu_seconds))
        return report
    report = Report(data["exercise"], path, data["template"] and Path(data["template"]))
    report.lines = [tuple(line) for line in data["lines"]]
    report.summary = data["summary"]
    return report


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def call(report: Report, what: str, fn, *args, hint: str | None = None, **kwargs):
    """``fn(*args, **kwargs)`` under the time limit. If it does not return normally, record
    a failure naming ``what`` (with ``hint``, or one that fits the error) and ``Stop``."""
    _check_arguments(report, what, fn, args, kwargs)
    path = report.path
    try:
        with time_limit(TIME_LIMIT):
            return fn(*args, **kwargs)
    except Stop:
        raise
    except TooSlow:
        report.fail(f"{what} took longer than {TIME_LIMIT:g} s: an infinite loop?", stop=True)
    except SystemExit as e:
        report.fail(f"{what} called exit() (SystemExit: {e.code}){where_in(path, e)}",
                    hint="remove sys.exit() / exit() / quit(): return a value instead",
                    stop=True)
    except KeyboardInterrupt as e:
        report.fail(f"{what} was interrupted (Ctrl-C){where_in(path, e)}", stop=True)
    except GradcheckError as e:
        report.fail(f"gradcheck failed on {what}: {e}", hint=hint, stop=True)
    except NotImplementedError as e:
        report.fail(f"not written yet: {what} raised {describe(e, path)}",
                    hint="this part is yours to write: replace the `raise "
                         "NotImplementedError(...)` line by your code", stop=True)
    except BaseException as e:  # noqa: BLE001 - anything the student's code raises
        if isinstance(e, ValueError) and "truth value of an array" in str(e):
            hint = ("the code is called with arrays (one entry per flight): replace `if x:` / "
                    "`and` / `or` by np.where(...), np.logical_and(...), ...")
        report.fail(f"{what} raised {describe(e, path)}", hint=hint, stop=True)


def _check_arguments(report: Report, what: str, fn, args, kwargs) -> None:
    """If ``fn`` is defined in the student's file, fail unless it accepts ``args``."""
    code = getattr(fn, "__code__", None)
    if code is None or report.path is None or \
            Path(code.co_filename).resolve() != Path(report.path).resolve():
        return
    try:
        inspect.signature(fn).bind(*args, **kwargs)
    except TypeError as e:
        lines = report.template.read_text().splitlines() if report.template else []
        line = next((s.rstrip(":") for s in lines if s.startswith(f"def {fn.__name__}(")), None)
        report.fail(f"{what}: your {fn.__name__}{inspect.signature(fn)} cannot be called "
                    f"this way ({e})",
                    hint=line and f"keep the template's arguments: {line}", stop=True)


def load(path, report: Report):
    """Import the file at ``path``; on any problem record a failure and ``Stop``."""
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
        compile(path.read_text(), str(path), "exec")
    except UnicodeDecodeError as e:
        report.fail(f"Python cannot read {path.name}: byte {e.start} is not UTF-8 text",
                    hint="save the file as UTF-8 (plain text) in your editor", stop=True)
    except SyntaxError as e:
        report.fail(f"Python cannot read {path.name}: {e.msg}"
                    + (f" at line {e.lineno}" if e.lineno else "")
                    + (f": {e.text.strip()}" if e.text else ""),
                    hint="look for a missing bracket, colon or a wrong indentation there",
                    stop=True)
    call(report, f"importing {path.name}", spec.loader.exec_module, module)
    sys.modules.pop(name, None)
    report.ok(f"{path.name} loads")
    return module


def get(report: Report, module, name: str, function: bool = False):
    """``module.name``; a failure and ``Stop`` if it is missing (or not a function)."""
    if not hasattr(module, name):
        report.fail(f"{Path(report.path).name} defines no `{name}`",
                    hint=f"keep the name `{name}` from the template", stop=True)
    value = getattr(module, name)
    if function and not callable(value):
        report.fail(f"`{name}` must be a function; got {type(value).__name__}", stop=True)
    return value
