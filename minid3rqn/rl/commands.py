"""The Q-learning commands: ``train-agent``, ``distil``, ``evaluate``, ``fly``, ``reproduce``.

Each is a thin shell over a library function (``rl.train.train``, ``rl.distill.distil``,
``rl.evaluate.evaluate_spec``, ``rl.fly.fly``, ``rl.reproduce``); the options come from
the config dataclasses (``minid3rqn/config.py``). ``minid3rqn/cli.py`` registers them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..config import UsageError, add_arguments, from_args
from ..io import append_jsonl
from .models import depth_estimator_for, recorded_result, recorded_text

RUNS = Path("runs")


def _progress() -> bool:
    """A progress bar on a terminal; in a log file, one line per checkpoint instead."""
    return sys.stderr.isatty()


def _estimator(depth: str, depth_model, scenario: str, flip: bool = False):
    try:
        return depth_estimator_for(depth, depth_model, scenario, flip)
    except (FileNotFoundError, ValueError) as e:
        raise UsageError(f"--depth-model: {e}") from None


def _run_options(p: argparse.ArgumentParser, out: str) -> None:
    p = p.add_argument_group("files")
    p.add_argument("--depth-model", default=None,
                   help="DispNet .npz for --depth pred (default: the shipped one)")
    p.add_argument("--out", default=None, help=f"run folder (default {out})")
    p.add_argument("--resume", action="store_true", help="continue from its checkpoint")
    p.add_argument("--smoke", action="store_true", help="a few hundred steps (tests)")


def _trained(run, command: str, depth_model, t0: float, **extra) -> int:
    from .models import save_trained
    model = save_trained(run, command, depth_model, time.time() - t0, **extra)
    print(json.dumps({"model": str(model), "steps": run.steps, "updates": run.agent.updates,
                      "last": run.curve[-1] if run.curve else {}}))
    return 0


# -- train-agent -----------------------------------------------------------------------------
def add_arguments_train_agent(p: argparse.ArgumentParser) -> None:
    from .train import TrainConfig
    add_arguments(p, TrainConfig, hide=("actions",))
    _run_options(p, "runs/agent/<variant>_<scenario>_<depth>_s<seed>")


def run_train_agent(args) -> int:
    from .models import command_for
    from .train import SMOKE, TrainConfig, train
    cfg = from_args(TrainConfig, args, base=TrainConfig(**SMOKE) if args.smoke else None)
    name = f"{cfg.variant}_{cfg.scenario}_{cfg.depth}_s{cfg.seed}"
    out = Path(args.out) if args.out else RUNS / "agent" / (("smoke_" if args.smoke else "") + name)
    est = _estimator(cfg.depth, args.depth_model, cfg.scenario)
    t0 = time.time()
    try:
        run = train(cfg, out, est, progress=_progress(), resume=args.resume)
    except (ValueError, FileNotFoundError) as e:
        raise UsageError(str(e)) from None
    return _trained(run, command_for(cfg, out, args.depth_model), args.depth_model, t0)


# -- distil ----------------------------------------------------------------------------------
def add_arguments_distil(p: argparse.ArgumentParser) -> None:
    from .distill import DISTIL_OPTIONS, DistilConfig
    add_arguments(p, DistilConfig, hide=("actions",), main=DISTIL_OPTIONS)
    _run_options(p, "runs/distil/<scenario>_<depth>_s<seed>")


def run_distil(args) -> int:
    from ..world import ACTIONS, Camera
    from .distill import DISTIL_OPTIONS, DistilConfig, distil, load_teacher, student
    from .models import command_for
    from .train import SMOKE
    base = DistilConfig(teacher_mix_steps=64, train=replace(student(), **SMOKE)) \
        if args.smoke else None
    cfg = from_args(DistilConfig, args, base=base, main=DISTIL_OPTIONS)
    t = cfg.train
    if cfg.init_widen and not t.init_model:
        raise UsageError("--set init_widen=true: grows the --init-model's LSTM; give "
                         "--init-model")
    cam, actions = Camera(hfov_deg=t.hfov_deg), ACTIONS if t.actions is None else t.actions
    try:                                 # a bad teacher: say so before any training
        load_teacher(cfg.teachers, (cam.height, cam.width), len(actions))
    except ValueError as e:
        raise UsageError(f"--{e}") from None
    out = Path(args.out) if args.out else \
        RUNS / "distil" / (("smoke_" if args.smoke else "") + f"{t.scenario}_{t.depth}_s{t.seed}")
    est = _estimator(t.depth, args.depth_model, t.scenario)
    t0 = time.time()
    try:
        run = distil(cfg, out, est, progress=_progress(), resume=args.resume)
    except (ValueError, FileNotFoundError) as e:
        raise UsageError(str(e)) from None
    return _trained(run, command_for(cfg, out, args.depth_model), args.depth_model, t0)


# -- evaluate --------------------------------------------------------------------------------
def add_arguments_evaluate(p: argparse.ArgumentParser) -> None:
    from .evaluate import EvalConfig
    from .models import BASELINES
    p.add_argument("policies", nargs="+",
                   help=f"baselines ({', '.join(BASELINES)}) and/or Q-net .npz files "
                        "(A.npz+B.npz+...: an ensemble, greedy on the members' mean Q-values)")
    add_arguments(p, EvalConfig)
    p.add_argument_group("files").add_argument(
        "--json", default=None, help="append results to this JSON-lines file")


def run_evaluate(args) -> int:
    from .evaluate import EvalConfig, evaluate_spec
    cfg = from_args(EvalConfig, args)
    est = _estimator(cfg.depth, cfg.depth_model, cfg.scenario, cfg.flip_tta)
    for spec in args.policies:
        try:
            _, record = evaluate_spec(spec, cfg, est, progress=_progress())
        except ValueError as e:
            raise UsageError(f"evaluate {e}") from None
        if args.json:
            append_jsonl(args.json, record)
    return 0


# -- fly -------------------------------------------------------------------------------------
def add_arguments_fly(p: argparse.ArgumentParser) -> None:
    from .fly import FlyConfig
    add_arguments(p, FlyConfig)


def run_fly(args) -> int:
    from .fly import FlyConfig, fly
    from .models import SHIPPED_QNETS, load_qnet_policy, shipped_depth_model
    cfg = from_args(FlyConfig, args)
    seed = cfg.seed if cfg.seed is not None else int(np.random.SeedSequence().entropy % 10**6)
    parts = [str(SHIPPED_QNETS.get(part, part)) for part in cfg.model.split("+")]
    for part in parts:
        if not Path(part).is_file():
            raise UsageError(f"--model: Q-net {part!r} not found (expected a shipped name, "
                             f"{' or '.join(SHIPPED_QNETS)}, or a .npz file, or several "
                             f"joined by '+')")
    depth, depth_model = cfg.depth, shipped_depth_model(cfg.scenario)
    if depth == "pred" and not depth_model.is_file():
        print(f"fly: no depth model at {depth_model}; flying on GT depth", file=sys.stderr)
        depth = "gt"
    est = _estimator(depth, depth_model, cfg.scenario, cfg.flip_tta)
    out = fly([load_qnet_policy(p) for p in parts], est, cfg.scenario, seed, cfg.flights,
              cfg.gif, mirror=cfg.mirror)
    print(json.dumps(out))
    by_world = "" if out["ci95_by_world"] is None else \
        f"; by world {out['ci95_by_world'][0]:.2f}-{out['ci95_by_world'][1]:.2f}, " \
        f"{out['worlds']} worlds"
    print(f"success {out['successes']}/{out['flights']} = {out['success_rate']:.2f} "
          f"(95% CI {out['ci95'][0]:.2f}-{out['ci95'][1]:.2f}{by_world}) on {depth} depth; "
          f"GIF: {out['gif']}", file=sys.stderr)
    model = "+".join(parts)
    recorded = recorded_result(model, cfg.scenario, depth, mirror=cfg.mirror,
                               flip_tta=depth == "pred" and cfg.flip_tta)
    if recorded:
        print(f"note: {out['flights']} flights give a wide interval; this model's recorded "
              f"result here: {recorded_text(recorded)}. See "
              f"{Path(model).with_suffix('.json').name} beside it, docs/results.md and "
              "docs/beyond.md", file=sys.stderr)
    return 0


# -- reproduce -------------------------------------------------------------------------------
def add_arguments_reproduce(p: argparse.ArgumentParser) -> None:
    from .reproduce import ReproduceConfig
    add_arguments(p, ReproduceConfig)
    p.add_argument("--out", default="runs/reproduce", help="where every run lands")


def run_reproduce(args) -> int:
    from .reproduce import ReproduceConfig, reproduce, reproduce_distilled, reproduce_quick
    cfg = from_args(ReproduceConfig, args)
    if cfg.students != 1 and cfg.recipe != "distil":
        raise UsageError(f"--students {cfg.students}: only for --recipe distil")
    if cfg.quick and (cfg.recipe != "paper" or cfg.skip_depth):
        raise UsageError("--quick: the paper's recipe on the shipped DispNets; it takes "
                         "neither --recipe distil nor --skip-depth")
    if cfg.quick:
        reproduce_quick(Path(args.out), workers=cfg.workers)
    elif cfg.recipe == "paper":
        reproduce(Path(args.out), skip_depth=cfg.skip_depth, workers=cfg.workers)
    else:
        reproduce_distilled(Path(args.out), skip_depth=cfg.skip_depth,
                            workers=cfg.workers, students=cfg.students)
    return 0


__all__ = ["add_arguments_train_agent", "run_train_agent", "add_arguments_distil",
           "run_distil", "add_arguments_evaluate", "run_evaluate", "add_arguments_fly",
           "run_fly", "add_arguments_reproduce", "run_reproduce"]
