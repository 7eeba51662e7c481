"""A checker's findings, as a list of lines a student can read.

Every check adds one line: ``ok`` (passed), ``fail`` (must be fixed, with a hint on how)
or ``note`` (worth knowing, not an error). A check that cannot go on (the file does not
load, the function is missing) raises ``Stop`` after recording its failure, so that the
later checks do not pile up confusing errors on top of the first one.
"""
from __future__ import annotations

import textwrap


class Stop(Exception):
    """Raised inside a checker to end it early; the failure is already recorded."""


class Report:
    """What a checker found. ``passed`` is True when no line failed."""

    def __init__(self, exercise: str, path=None):
        self.exercise = exercise
        self.path = None if path is None else str(path)
        self.lines: list[tuple[str, str]] = []
        self.summary: dict = {}

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
        return not any(kind == "FAIL" for kind, _ in self.lines)

    @property
    def failures(self) -> list[str]:
        return [text for kind, text in self.lines if kind == "FAIL"]

    @property
    def messages(self) -> str:
        """All lines as one string (handy in tests: ``"still the paper's" in r.messages``)."""
        return "\n".join(text for _, text in self.lines)

    def text(self, next_step: str | None = None) -> str:
        head = f"Exercise {self.exercise}" + (f": checking {self.path}" if self.path else "")
        out = [head]
        for kind, text in self.lines:
            tag = {"ok": "[ok]  ", "note": "[note]", "FAIL": "[FAIL]"}[kind]
            body = textwrap.indent(text, " " * 9).lstrip()
            out.append(f"  {tag} {body}")
        n_fail = len(self.failures)
        if n_fail:
            out.append(f"NOT YET: {n_fail} problem{'s' if n_fail > 1 else ''} to fix (see [FAIL] "
                       f"above), then run the check again.")
        else:
            out.append("PASSED." + (f" Next: {next_step}" if next_step else ""))
        return "\n".join(out)

    def __repr__(self) -> str:
        return f"Report({self.exercise!r}, passed={self.passed}, lines={len(self.lines)})"
