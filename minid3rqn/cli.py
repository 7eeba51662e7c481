"""One command line: ``python -m minid3rqn <command> [options]``.

Each command lives in the module that does the work; this file only wires them up,
importing a command's module when that command runs (so ``--help`` is instant).

A bad input is one line on stderr naming the option or the file (exit status 2), never a
traceback; Ctrl-C in a training loop saves the run's checkpoint and prints the command
that continues it (exit status 130), also in every worker of a command that trains
several runs at once. SIGTERM (``kill``, ``timeout``, a scheduler) is Ctrl-C.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from .allocator import keep_freed_memory
from .config import UsageError, shell_command
from .executor import WorkerLost, sigterm_as_ctrl_c
from .io import DamagedCheckpoint, RunStopped

# command name -> (module, one-line help). Each module defines add_arguments(parser)
# and run(args) -> int for its command (named ``cli_<command>`` with dashes -> _).
COMMANDS: dict[str, tuple[str, str]] = {
    # the main job and the decision module (D3RQN)
    "fly": ("minid3rqn.rl.commands", "fly the shipped model: GIF + success rate (the main job)"),
    "train-agent": ("minid3rqn.rl.commands", "train a Q-network (DDQN, D3QN, DDRQN, D3RQN)"),
    "distil": ("minid3rqn.rl.commands",
               "ours: train a student Q-net from a GT-depth teacher's Q-values"),
    "evaluate": ("minid3rqn.rl.commands", "success rate over many flights, with a 95%% CI"),
    "reproduce": ("minid3rqn.rl.commands", "rerun Tables 5 and 6 end to end (--quick)"),
    "sweep": ("minid3rqn.rl.commands",
              "train one configuration with several seeds: the spread of their success rates"),
    "pool": ("minid3rqn.rl.pool", "pool evaluate --json records by world; A against B"),
    # sensing (unsupervised depth)
    "collect": ("minid3rqn.depth.commands", "fly a scripted pilot and save image sequences"),
    "train-depth": ("minid3rqn.depth.commands", "train DispNet + PoseNet by view synthesis"),
    "eval-depth": ("minid3rqn.depth.commands", "depth and pose error against ground truth"),
    # the classroom
    "check": ("minid3rqn.classroom.commands", "check your solution to an exercise"),
    "exercise": ("minid3rqn.classroom.commands", "run an exercise's small experiment"),
}


class Parser(argparse.ArgumentParser):
    """argparse's parser, but a refused command line is one line (no usage block): the
    command, what was wrong, and where to look."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {message} (see --help)\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m minid3rqn",
        description="D3RQN obstacle avoidance from monocular depth, in pure NumPy.")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text.replace("%%", "%"))
        p.set_defaults(_module=module, _name=name)
        if only is None or name == only:  # import a command's module only when it runs
            _hook(module, name, "add_arguments")(p)
    return parser


def _hook(module: str, name: str, kind: str):
    suffix = name.replace("-", "_")
    mod = importlib.import_module(module)
    return getattr(mod, f"{kind}_{suffix}", None) or getattr(mod, kind)


def _command_parser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    return next(a for a in parser._actions if a.dest == "command").choices[name]


def continue_command(argv: list[str], sub: argparse.ArgumentParser) -> str:
    """The command that continues a run stopped by Ctrl-C: the same one, with --resume
    in place of --overwrite if the command has it (reproduce continues by itself)."""
    words = list(argv)
    if "--resume" in sub._option_string_actions:
        choice = [w for w in words if len(w) > 2 and ("--resume".startswith(w)
                                                      or "--overwrite".startswith(w))]
        words = [w for w in words if w not in choice] + ["--resume"]
    return shell_command(words)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    chosen = next((a for a in argv if a in COMMANDS), None)
    parser = build_parser(only=chosen)
    args, rest = parser.parse_known_args(argv)
    if args.command is None:
        if rest:
            parser.error(f"unrecognized arguments: {' '.join(rest)}")
        parser.print_help()
        return 0
    sub = _command_parser(parser, args.command)
    if rest:
        sub.error(f"unrecognized arguments: {' '.join(rest)}")
    keep_freed_memory()    # speed only: NumPy's temporaries reuse memory (allocator.py)
    name = f"{parser.prog} {args.command}"
    sigterm_as_ctrl_c()
    try:
        return int(_hook(args._module, args._name, "run")(args) or 0)
    except (UsageError, DamagedCheckpoint) as e:   # a bad input: one line, no traceback
        print(f"{name}: {e}", file=sys.stderr)
        return 2
    except RunStopped as e:    # Ctrl-C in a training loop: its checkpoint is saved
        print(f"{name}: {e}; continue with: {continue_command(argv, sub)}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"{name}: interrupted (Ctrl-C); files already written are whole",
              file=sys.stderr)
        return 130
    except WorkerLost as e:    # a task whose worker kept dying (e.g. out of memory)
        print(f"{name}: {e}", file=sys.stderr)
        return 1
    except FloatingPointError as e:   # a training diverged (e.g. a learning rate too large)
        print(f"{name}: the training diverged ({e}); nothing more was saved", file=sys.stderr)
        return 1
    except MemoryError as e:   # e.g. a replay larger than the machine's memory
        print(f"{name}: not enough memory: {e}", file=sys.stderr)
        return 1
    except OSError as e:       # the disk or the file system refused (full, read-only...)
        print(f"{name}: {e.strerror or e}: {e.filename or ''}".rstrip(": "),
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
