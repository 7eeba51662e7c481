"""Settings as dataclasses: one place defines, documents and checks each value.

A config is a dataclass whose fields are declared with ``setting``::

    @dataclass
    class TrainConfig:
        batch_size: int = setting(32, "replay windows per update", source="paper",
                                  check=at_least(1))
        def __post_init__(self):
            validate(self)

``validate`` checks every field (its type, then its ``check``) and raises a
``ConfigError`` naming the field, what was expected and what came. The command line is
generated from the same fields (``add_arguments``, ``from_args``), so a value is
defined, explained and validated once, in its dataclass.

Command-line options. A field becomes ``--field-name``. The fields a student meets
first (``source`` "paper" and "budget", and the ones marked ``cli="main"``) are listed
first in ``--help``; the others (``cli="more"``) are set with ``--set NAME=VALUE`` and
listed, with their defaults, at the end of ``--help``. A field of a nested config
(``agent: AgentConfig``) is named by its own name (``--lr``).
"""
from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
import types
import typing
from dataclasses import MISSING, field, fields, is_dataclass

SOURCES = ("paper", "budget", "ours", "run")
GROUP_TITLES = {"paper": "the paper's settings", "budget": "budget (scaled to a laptop)",
                "ours": "our additions", "run": "the run"}


class ConfigError(ValueError):
    """A setting with a bad value: ``name`` (the field), ``value``, ``expected`` (words)."""

    def __init__(self, name: str, value, expected: str):
        self.name, self.value, self.expected = name, value, expected
        super().__init__(f"{name}: expected {expected}; got {value!r}")


class UsageError(Exception):
    """A bad command-line input: the CLI prints its message as one line, exit status 2."""


def setting(default=MISSING, help: str = "", *, source: str = "ours", check=None,
            choices=None, cli: str | None = None, default_factory=MISSING, metavar=None):
    """A config field with its help text, where its value comes from (``source``: the
    paper, the budget, ours, or how the run is done), a ``check`` (value -> None if
    good, else the expectation in words), ``choices`` and whether it is a main
    command-line option (``cli="main"``, the default for paper and budget fields) or
    set with ``--set`` (``cli="more"``)."""
    if source not in SOURCES:
        raise ValueError(f"setting: source must be one of {SOURCES}; got {source!r}")
    if cli is None:
        cli = "main" if source in ("paper", "budget", "run") else "more"
    meta = {"help": help, "source": source, "check": check, "choices": choices, "cli": cli,
            "metavar": metavar}
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


# -- checks: value -> None when good, else what was expected --------------------------
def at_least(lo):
    return lambda v: None if v >= lo else f"a number >= {lo}"


def between(lo, hi):
    return lambda v: None if lo <= v <= hi else f"a number in [{lo}, {hi}]"


def up_to(lo, hi, why: str):
    """A check: a count from ``lo`` to ``hi``, ``why`` saying where the upper limit comes
    from."""
    return lambda v: None if lo <= v <= hi else f"a number >= {lo}" if v < lo else \
        f"at most {hi:,} ({why})"


def positive(v):
    return None if v > 0 else "a number > 0"


def memory_bytes() -> int:
    """This machine's physical memory in bytes (8 GB where it cannot be asked)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        return 8 << 30


def fits_memory(lo: int, each: float, what: str):
    """A check: a count >= ``lo`` whose ``what`` (``each`` bytes apiece) fit in half this
    machine's memory."""
    def check(v):
        most = max(lo, int(memory_bytes() / 2 // each))
        if lo <= v <= most:
            return None
        return (f"a number >= {lo}" if v < lo else
                f"at most {most:,} ({what} take about {each / 1e3:,.0f} KB each; half this "
                f"machine's {memory_bytes() / 2 ** 30:.1f} GB memory)")
    return check


def cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def capped_workers(cfg, name: str = "workers") -> None:
    """``cfg.<name>`` (worker processes) above the cores this process may use is set to
    their number, with a note on stderr: more processes than cores only share them."""
    n = cores()
    if getattr(cfg, name) > n:
        print(f"note: {option_name(type(cfg), name)} {getattr(cfg, name)} is more than the "
              f"{n} cores of this machine; using {n}", file=sys.stderr)
        object.__setattr__(cfg, name, n)


# Flights last at most this many steps (the paper's success: 50 steps without a collision,
# ``DroneEnv``'s ``max_steps``): a replay window or a frame stack longer than a
# flight holds only padding.
FLIGHT_STEPS = 50
# Flights stepped together (a chunk of evaluate, fly's flights, a training's flights): the
# peak memory of evaluate grows by about 0.2 MB a flight with the DispNet's depth (--chunk
# 50 -> 250: 114 -> 153 MB) and 0.15 MB on GT depth (--chunk 100 -> 1000: 70 -> 206 MB),
# measured with /usr/bin/time; 0.25 MB leaves room.
FLIGHT_BYTES = 250e3


def check_seed(seed, name: str = "seed") -> int:
    """``seed`` as the integer >= 0 that seeds NumPy; a ValueError naming ``name``, in
    one line, for anything else (a negative, fractional or text seed): where a seed
    enters the library, before NumPy sees it."""
    if isinstance(seed, (bool, float, str)) or not isinstance(seed, (int, np_integer())) \
            or seed < 0:
        raise ValueError(f"{name}: expected an integer >= 0; got {seed!r}")
    return int(seed)


def np_integer():
    import numpy as np
    return np.integer


# -- types ------------------------------------------------------------------------------
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _base_type(hint):
    """(type, optional): int | None -> (int, True); list[int] -> (list, False)."""
    args = typing.get_args(hint)
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        rest = [a for a in args if a is not type(None)]
        return _base_type(rest[0])[0], type(None) in args
    if origin in (list, tuple):
        return list, False
    return hint, False


def _check_type(name: str, value, hint):
    kind, optional = _base_type(hint)
    if value is None:
        if optional:
            return None
        raise ConfigError(name, value, f"a {kind.__name__}")
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(name, value, "true or false")
    elif kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(name, value, "an integer")
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise ConfigError(name, value, "a finite number")
        return float(value)
    elif kind is str:
        if not isinstance(value, str):
            raise ConfigError(name, value, "a string")
    elif kind is list:          # numbers, or rows of numbers (a table)
        def number(x):
            return not isinstance(x, bool) and isinstance(x, (int, float))
        if not isinstance(value, (list, tuple)) or not all(
                number(x) or (isinstance(x, (list, tuple)) and all(map(number, x)))
                for x in value):
            raise ConfigError(name, value, "a list of numbers")
        return [list(x) if isinstance(x, (list, tuple)) else x for x in value]
    return value


def validate(cfg) -> None:
    """Check every field of ``cfg`` (its type, its choices, its ``check``); nested
    configs (built from dicts when given as dicts) validate themselves."""
    hints = _hints(type(cfg))
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        hint = hints[f.name]
        if is_dataclass(hint):
            if isinstance(value, dict):
                value = hint(**value)
                object.__setattr__(cfg, f.name, value)
            elif not isinstance(value, hint):
                raise ConfigError(f.name, value, f"a {hint.__name__}")
            continue
        value = _check_type(f.name, value, hint)
        object.__setattr__(cfg, f.name, value)
        if value is None:
            continue
        choices = f.metadata.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(f.name, value, f"one of {', '.join(map(str, choices))}")
        check = f.metadata.get("check")
        problem = check(value) if check is not None else None
        if problem:
            raise ConfigError(f.name, value, problem)


# -- the command line -------------------------------------------------------------------
def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _leaves(cls, path=()):
    """(path, field, hint) of every setting of ``cls``, nested configs flattened."""
    hints = _hints(cls)
    for f in fields(cls):
        if is_dataclass(hints[f.name]):
            yield from _leaves(hints[f.name], path + (f.name,))
        else:
            yield path + (f.name,), f, hints[f.name]


def _parse_text(name: str, text: str, hint, option: str | None = None):
    """A command-line string -> a value of the field's type (UsageError naming
    ``option``, default ``--name``, if it is not)."""
    kind, optional = _base_type(hint)
    if optional and text.lower() == "none":
        return None
    try:
        if kind is bool:
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return text.lower() in ("true", "1", "yes")
        if kind is int:
            return int(text)
        if kind is float:
            return float(text)
        if kind is list:    # numbers joined by ',', or a table: rows joined by ';'
            rows = [[int(x) if x.strip().lstrip("-").isdigit() else float(x)
                     for x in row.split(",")] for row in text.split(";")]
            return rows if ";" in text else rows[0]
    except ValueError:
        words = {bool: "true or false", int: "an integer", float: "a number",
                 list: "numbers joined by ',' (a table: rows joined by ';')"}[kind]
        raise UsageError(f"{option or flag(name)}: expected {words}; got {text!r}") from None
    return text


def _is_main(f, name: str, main) -> bool:
    return name in main if main is not None else f.metadata.get("cli", "more") == "main"


def add_arguments(parser: argparse.ArgumentParser, cls, hide: tuple = (),
                  main: tuple | None = None) -> None:
    """Options for every setting of config class ``cls``: main ones as ``--name``, in
    groups by source; the rest through ``--set NAME=VALUE`` (listed in ``--help``, with
    the defaults of ``cls()``). ``hide``: fields the command sets itself; ``main``: the
    names of the main options, if not the fields' own choice (``cli``)."""
    defaults = cls()
    groups, more = {}, []
    order = {s: i for i, s in enumerate(SOURCES)}
    leaves = sorted(_leaves(cls), key=lambda leaf: order[leaf[1].metadata.get("source", "ours")])
    for path, f, hint in leaves:
        name = path[-1]
        if name in hide:
            continue
        value = _get(defaults, path)
        if not _is_main(f, name, main):
            more.append(f"  {name}={value}: {f.metadata.get('help', '')}")
            continue
        source = f.metadata.get("source", "ours")
        if source not in groups:            # one group per source, also across configs
            groups[source] = next((g for g in parser._action_groups
                                   if g.title == GROUP_TITLES[source]), None) \
                or parser.add_argument_group(GROUP_TITLES[source])
        help_text = f.metadata.get("help", "")
        if source == "paper":
            help_text = f"paper: {help_text}" if help_text else "paper"
        kind, _ = _base_type(hint)
        kwargs = dict(dest=f"cfg__{'__'.join(path)}", default=argparse.SUPPRESS,
                      help=f"{help_text} (default: {'none' if value in ('', None) else value})"
                      .replace("%", "%%"))
        if kind is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        else:
            kwargs["metavar"] = f.metadata.get("metavar") or name.upper()
            kwargs["type"] = str
            if f.metadata.get("choices"):
                kwargs["choices"] = list(f.metadata["choices"])
                kwargs["metavar"] = "{" + ",".join(map(str, f.metadata["choices"])) + "}"
        groups[source].add_argument(flag(name), **kwargs)
    if more:
        if "--set" not in parser._option_string_actions:    # one --set for all configs
            others = parser.add_argument_group("other settings")
            others.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                                dest="cfg_set", help="change any other setting (listed "
                                                     "below); repeatable")
            parser.epilog = ((parser.epilog + "\n\n" if parser.epilog else "")
                             + "other settings (--set NAME=VALUE), with their defaults:")
        parser.epilog += "\n" + "\n".join(more)
        parser.formatter_class = argparse.RawDescriptionHelpFormatter


def setting_names(cls) -> set[str]:
    """The names of every setting of ``cls``, nested configs' included."""
    return {path[-1] for path, _, _ in _leaves(cls)}


def _get(cfg, path):
    for p in path:
        cfg = getattr(cfg, p)
    return cfg


def from_args(cls, args: argparse.Namespace, base=None, main: tuple | None = None, **fixed):
    """The config of ``cls`` given by parsed ``args`` (options not given keep ``base``'s
    values, default ``cls()``; ``fixed`` fields are set by the command). A bad value is a
    UsageError naming its option."""
    leaves = {path[-1]: (path, hint) for path, _, hint in _leaves(cls)}
    values = {}
    for key, text in vars(args).items():
        if key.startswith("cfg__"):
            path = tuple(key[5:].split("__"))
            values[path] = (text if isinstance(text, bool)
                            else _parse_text(path[-1], text, leaves[path[-1]][1]))
    for item in getattr(args, "cfg_set", None) or []:
        name, eq, text = item.partition("=")
        if not eq or name not in leaves:
            raise UsageError(f"--set: expected NAME=VALUE with NAME one of "
                             f"{', '.join(sorted(leaves))}; got {item!r}")
        path, hint = leaves[name]
        values[path] = _parse_text(name, text, hint, f"--set {name}")
    for name, value in fixed.items():
        values[leaves[name][0]] = value
    return build(cls, values, base, main)


def build(cls, values: dict, base=None, main: tuple | None = None):
    """``cls`` with the settings ``values`` ({path: value}) over ``base``'s (default
    ``cls()``); a ConfigError becomes a UsageError naming the option."""
    base = base if base is not None else cls()
    data = as_dict(base)
    for path, value in values.items():
        d = data
        for p in path[:-1]:
            d = d[p]
        d[path[-1]] = value
    try:
        return cls(**data)
    except ConfigError as e:
        raise UsageError(f"{option_name(cls, e.name, main)}: expected {e.expected}; got "
                         f"{e.value!r}") from None


def option_name(cls, name: str, main: tuple | None = None) -> str:
    """How the command line spells setting ``name`` of ``cls``: ``--name`` or
    ``--set name``."""
    for path, f, _ in _leaves(cls):
        if path[-1] == name:
            return flag(name) if _is_main(f, name, main) else f"--set {name}"
    return flag(name)


def as_dict(cfg) -> dict:
    """A config as a plain dict (nested configs as dicts), for JSON and ``cls(**d)``."""
    out = {}
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = as_dict(v) if is_dataclass(v) else (list(v) if isinstance(v, tuple)
                                                           else v)
    return out


def flat_settings(values: dict) -> dict:
    """A config's settings, as ``as_dict`` gives them (nested configs as dicts), by their
    own names: {name: value} (a name is unique across nested configs, as ``--set`` needs)."""
    out = {}
    for name, value in values.items():
        out.update(flat_settings(value) if isinstance(value, dict) else {name: value})
    return out


def _list_text(value: list) -> str:
    """A list as the command line writes it: 1,2,3; a table 2,-0.5;2,0;2,0.5."""
    if value and isinstance(value[0], list):
        return ";".join(",".join(map(str, row)) for row in value)
    return ",".join(map(str, value))


def _shown(value) -> str:
    if isinstance(value, list):
        return _list_text(value)
    return "''" if value == "" else str(value).lower() if value is None else str(value)


def changed_settings(saved: dict, now: dict, may_change=()) -> list[str]:
    """The settings that ``now`` gives another value than ``saved`` (both flat, as
    ``flat_settings`` gives), but those named in ``may_change``: "name SAVED (now NOW)"
    each. A setting one of them lacks (made before it existed) is not compared."""
    return [f"{name} {_shown(saved[name])} (now {_shown(value)})"
            for name, value in now.items()
            if name in saved and name not in may_change and saved[name] != value]


class _Existing(argparse.Action):
    """--resume or --overwrite: ``args.existing`` is "resume" or "overwrite" (one only)."""

    def __call__(self, parser, namespace, values, option_string=None):
        chosen = option_string.lstrip("-")
        if getattr(namespace, self.dest) not in (None, chosen):
            parser.error("--resume and --overwrite: give one of them")
        setattr(namespace, self.dest, chosen)


def add_existing_option(parser: argparse.ArgumentParser, grows: str | None = None) -> None:
    """The option of a command that writes a run folder (a file, without ``grows``)
    saying what to do if it holds a run already: ``--resume`` it (with the same settings
    but ``grows``, which may be larger, and how often it logs and checkpoints) or
    ``--overwrite`` it: one option, two spellings. Without it such a folder (file) is
    refused (``io.claim_run_folder``). ``args.existing``: None, "resume" or "overwrite"."""
    if grows is None:
        parser.add_argument("--overwrite", dest="existing", action="store_const",
                            const="overwrite", default=None,
                            help="replace the file if it exists (else it is refused)")
        return
    parser.add_argument("--resume", "--overwrite", dest="existing", action=_Existing, nargs=0,
                        default=None, help="if the folder holds a run: continue it from its "
                        f"checkpoint with its settings ({grows} may grow) (--resume), or "
                        "delete it and start afresh (--overwrite); without either, such a "
                        "folder is refused")


def shell_command(words: list[str]) -> str:
    """``python -m minid3rqn`` and ``words``, quoted for a shell where they need it."""
    return "python -m minid3rqn " + shlex.join(map(str, words))


def command_line(cls, cfg, main: tuple | None = None) -> list[str]:
    """The options that give ``cfg`` from the defaults ``cls()``: what a model file
    records, so its command reproduces it."""
    base = cls()
    out = []
    for path, f, hint in _leaves(cls):
        value, default = _get(cfg, path), _get(base, path)
        if value == default:
            continue
        name = path[-1]
        text = _list_text(value) if isinstance(value, list) else str(value)
        if _is_main(f, name, main):
            if isinstance(value, bool):
                out.append(flag(name) if value else "--no-" + flag(name)[2:])
            else:
                out += [flag(name), text]
        else:
            out += ["--set", f"{name}={text}"]
    return out
