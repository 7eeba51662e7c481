"""One command line: ``python -m minid3rqn <command> [options]``.

Each command lives in the module that does the work; this file only wires them up,
importing a command's module when that command runs (so ``--help`` is instant).
"""
from __future__ import annotations

import argparse
import importlib
import sys

# command name -> (module, one-line help). Each module defines add_arguments(parser)
# and run(args) -> int for its command (named ``cli_<command>`` with dashes -> _).
COMMANDS: dict[str, tuple[str, str]] = {}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m minid3rqn",
        description="D3RQN obstacle avoidance from monocular depth, in pure NumPy.")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module, _name=name)
        _hook(module, name, "add_arguments")(p)
    return parser


def _hook(module: str, name: str, kind: str):
    suffix = name.replace("-", "_")
    mod = importlib.import_module(module)
    return getattr(mod, f"{kind}_{suffix}", None) or getattr(mod, kind)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return int(_hook(args._module, args._name, "run")(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
