"""One command line: ``python -m minid3rqn <command> [options]``.

Each command lives in the module that does the work; this file only wires them up,
importing a command's module when that command runs (so ``--help`` is instant).
"""
from __future__ import annotations

import argparse
import importlib
import sys

from .allocator import keep_freed_memory
from .config import UsageError

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
    "pool": ("minid3rqn.rl.pool", "pool evaluate --json records by world; A against B"),
    # sensing (unsupervised depth)
    "collect": ("minid3rqn.depth.commands", "fly a scripted pilot and save image sequences"),
    "train-depth": ("minid3rqn.depth.commands", "train DispNet + PoseNet by view synthesis"),
    "eval-depth": ("minid3rqn.depth.commands", "depth and pose error against ground truth"),
    # the world (2.5D)
    "calibrate": ("minid3rqn.world.calibration",
                  "oracle / straight / random success in every scenario"),
    # the classroom
    "check": ("minid3rqn.classroom.commands", "check your solution to an exercise"),
    "exercise": ("minid3rqn.classroom.commands", "run an exercise's small experiment"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    chosen = next((a for a in argv if a in COMMANDS), None)
    parser = build_parser(only=chosen)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    keep_freed_memory()    # speed only: NumPy's temporaries reuse memory (allocator.py)
    try:
        return int(_hook(args._module, args._name, "run")(args) or 0)
    except UsageError as e:    # a bad input: one line naming the option, no traceback
        print(f"{parser.prog} {args.command}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
