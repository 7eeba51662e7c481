"""The Q-learning commands: ``train-agent``, ``distil``, ``evaluate``, ``fly``, ``reproduce``,
``sweep``.

Each is a thin shell over a library function (``rl.train.train``, ``rl.distill.distil``,
``rl.evaluate.evaluate_spec``, ``rl.fly.fly``, ``rl.reproduce``, ``rl.sweep.sweep``); the
options come from
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

from ..config import (UsageError, add_arguments, add_existing_option, as_dict, flat_settings,
                      from_args)
from ..io import (WriteError, append_jsonl, check_log, check_output, claim_run_folder, hold,
                  read_metadata, whole)
from .models import (actions_and_camera, depth_estimator_for, ensemble_members, recorded_result,
                     recorded_text, unfinished_warning)

RUNS = Path("runs")


def _progress() -> bool:
    """A progress bar on a terminal; in a log file, one line per checkpoint instead."""
    return sys.stderr.isatty()


def _estimator(depth: str, depth_model, scenario: str, flip: bool = False,
               option: str = "--depth-model"):
    """The DispNet a command reads (None for GT depth); a depth model given for GT depth,
    where nothing would read it, is refused."""
    if depth == "gt" and depth_model:
        raise UsageError(f"{option}: only read with --depth pred; got {str(depth_model)!r} "
                         f"with --depth gt")
    try:
        return depth_estimator_for(depth, depth_model, scenario, flip)
    except (FileNotFoundError, ValueError) as e:
        raise UsageError(f"{option}: {str(e).removeprefix('DepthEstimator.load: ')}") from None


def _run_options(p: argparse.ArgumentParser, out: str) -> None:
    p = p.add_argument_group("files")
    p.add_argument("--depth-model", default=None,
                   help="DispNet .npz when the net reads predicted depth "
                        "(default: the shipped one)")
    p.add_argument("--out", default=None, help=f"run folder (default {out})")
    add_existing_option(p, grows="--steps")
    p.add_argument("--smoke", action="store_true", help="a few hundred steps (tests)")


def _depth_file(depth: str, depth_model, scenario: str) -> str:
    """The depth model a run reads, as its checkpoint records it ('' for GT depth)."""
    from .models import shipped_depth_model
    return "" if depth == "gt" else str(Path(depth_model or shipped_depth_model(scenario))
                                        .resolve())


def _resumes(args, out: Path) -> bool:
    return args.existing == "resume" and (out / "checkpoint.npz").is_file()


def _check_init_model(t, widen: bool = False) -> None:
    """--init-model: a finite Q-net file of the run's network (with ``widen``, its LSTM
    may be narrower: it is grown)."""
    if not t.init_model:
        return
    from ..config import changed_settings
    from ..world import ACTIONS, Camera
    from .policies import QNetPolicy
    if not Path(t.init_model).is_file():
        raise UsageError(f"--init-model: no file {t.init_model!r}")
    try:
        policy = QNetPolicy.load(t.init_model)
    except ValueError as e:
        raise UsageError(f"--init-model: {e}") from None
    warning = unfinished_warning(policy)
    if warning:                             # said, as evaluate and fly say it
        print(f"--init-model: {warning}", file=sys.stderr)
    theirs = policy.qnet.config.to_dict()
    cam = Camera(hfov_deg=t.hfov_deg)
    mine = t.qnet_config(len(ACTIONS if t.actions is None else t.actions),
                         (cam.height, cam.width)).to_dict()
    changed = changed_settings(theirs, mine, ("width",) if widen else ())
    if changed:
        raise UsageError(f"--init-model: {t.init_model!r} is another network than this run "
                         f"trains: {'; '.join(changed)}")


def _claim(out: Path, args, cfg, t, depth_file: str) -> str:
    """Check the run folder before any work (``io.claim_run_folder``); with --resume, that
    its checkpoint is of these settings. Returns "new", "resume", or "finished" (a run
    asked to resume that has nothing left to do; said on stderr)."""
    from .train import check_resume
    inputs = {"--init-model": [t.init_model], "--depth-model": [depth_file],
              "--teachers": ensemble_members(getattr(cfg, "teachers", ""))}
    if claim_run_folder(out, args.existing, "--out", inputs=inputs):
        settings = {**flat_settings(as_dict(cfg)), "depth_model": depth_file}
        try:
            meta = read_metadata(out / "checkpoint.npz")
            check_resume(meta, settings, out)
        except ValueError as e:
            raise UsageError(f"--resume: {str(e).removeprefix('resume: ')}") from None
        model = out / "model.npz"
        try:                             # a model file cut short is written anew
            finished = whole(model) and "command" in (read_metadata(model) or {})
        except ValueError:
            finished = False
        if meta["steps"] >= t.steps and finished:
            print(f"the run in {str(out)!r} has finished ({meta['steps']} of {t.steps} "
                  f"steps); nothing to do (--resume with more --steps trains it on)",
                  file=sys.stderr)
            return "finished"
        return "resume"
    return "new"


def _trained(run, command: str, depth_model, t0: float, **extra) -> int:
    from .models import save_trained
    model = save_trained(run, command, depth_model, time.time() - t0, **extra)
    if run.agent.updates == 0:      # e.g. --learning-starts beyond --steps: said, not silent
        print(f"warning: the run made no update in {run.steps} transitions (updates start "
              f"after --learning-starts {run.cfg.learning_starts}): {model} is untrained; "
              f"--resume with more --steps trains it", file=sys.stderr)
    print(json.dumps({"model": str(model), "steps": run.steps, "updates": run.agent.updates,
                      "last": run.curve[-1] if run.curve else {}}))
    return 0


# -- train-agent -----------------------------------------------------------------------------
def add_arguments_train_agent(p: argparse.ArgumentParser) -> None:
    from .train import TrainConfig
    add_arguments(p, TrainConfig)
    _run_options(p, "runs/agent/<variant>_<scenario>_<depth>_s<seed>")


def run_train_agent(args) -> int:
    from .train import SMOKE, TrainConfig, train
    cfg = from_args(TrainConfig, args, base=TrainConfig(**SMOKE) if args.smoke else None)
    name = f"{cfg.variant}_{cfg.scenario}_{cfg.depth}_s{cfg.seed}"
    out = Path(args.out) if args.out else RUNS / "agent" / (("smoke_" if args.smoke else "") + name)
    return _run_training(args, out, cfg, cfg, train)


def _run_training(args, out: Path, cfg, t, run_fn, widen: bool = False) -> int:
    """What train-agent and distil do once their config ``cfg`` (training settings ``t``)
    is read: the depth model loaded, ``--init-model`` checked (a fresh run only: a resumed
    run starts from its checkpoint), the run folder held and claimed, ``run_fn`` trained
    and the model written."""
    from .models import command_for
    est = _estimator(t.depth, args.depth_model, t.scenario)
    if not _resumes(args, out):
        _check_init_model(t, widen=widen)
    depth_file = _depth_file(t.depth, args.depth_model, t.scenario)
    with hold(check_output(out, "--out", folder=True), "--out"):
        how = _claim(out, args, cfg, t, depth_file)
        if how == "finished":
            return 0
        t0 = time.time()
        run = run_fn(cfg, out, est, progress=_progress(), resume=how == "resume",
                     settings={"depth_model": depth_file})
        return _trained(run, command_for(cfg, out, args.depth_model), args.depth_model, t0)


# -- distil ----------------------------------------------------------------------------------
def add_arguments_distil(p: argparse.ArgumentParser) -> None:
    from .distill import DISTIL_OPTIONS, DistilConfig
    add_arguments(p, DistilConfig, main=DISTIL_OPTIONS)
    _run_options(p, "runs/distil/<scenario>_<depth>_s<seed>")


def run_distil(args) -> int:
    from ..world import ACTIONS, Camera
    from .distill import DISTIL_OPTIONS, DistilConfig, distil, load_teacher, student
    from .train import SMOKE
    base = DistilConfig(teacher_mix_steps=64, train=replace(student(), **SMOKE)) \
        if args.smoke else None
    cfg = from_args(DistilConfig, args, base=base, main=DISTIL_OPTIONS)
    t = cfg.train
    cam, actions = Camera(hfov_deg=t.hfov_deg), ACTIONS if t.actions is None else t.actions
    try:                                 # a bad teacher: say so before any training
        teacher = load_teacher(cfg.teachers, (cam.height, cam.width), len(actions))
        flown, camera = actions_and_camera(teacher)
        if camera != cam or flown.shape != np.shape(actions) or not np.allclose(flown, actions):
            raise ValueError(f"{cfg.teachers!r} was trained with another action table or "
                             f"camera than the student (--set actions, --set hfov_deg)")
    except ValueError as e:
        message = str(e).removeprefix("teachers: ")
        raise UsageError(f"--teachers: {message}") from None
    out = Path(args.out) if args.out else \
        RUNS / "distil" / (("smoke_" if args.smoke else "") + f"{t.scenario}_{t.depth}_s{t.seed}")
    return _run_training(args, out, cfg, t, distil, widen=cfg.init_widen)


# -- evaluate --------------------------------------------------------------------------------
def add_arguments_evaluate(p: argparse.ArgumentParser) -> None:
    from .evaluate import EvalConfig
    from .models import BASELINES
    p.add_argument("policies", nargs="+",
                   help=f"baselines ({', '.join(BASELINES)}) and/or Q-net .npz files "
                        "(A.npz+B.npz+...: an ensemble, greedy on the members' mean Q-values; "
                        "a name that is an existing file is that one file, '+' or not)")
    add_arguments(p, EvalConfig)
    p.add_argument_group("files").add_argument(
        "--json", default=None, help="append results to this JSON-lines file")


def run_evaluate(args) -> int:
    from .evaluate import EvalConfig, evaluate_spec, own_training_worlds
    from .models import BASELINES, load_policy
    cfg = from_args(EvalConfig, args)
    if cfg.mirror and all(spec in BASELINES for spec in args.policies):
        raise UsageError(f"--mirror: mirrors Q-nets; the policies given are baselines only "
                         f"({', '.join(args.policies)})")
    if args.json:
        check_log(args.json, "--json")
    est = _estimator(cfg.depth, cfg.depth_model, cfg.scenario, cfg.flip_tta)
    for spec in args.policies:         # every policy readable before the first flies
        try:
            actions_and_camera(load_policy(spec))
            if cfg.worlds == "train":
                own_training_worlds(load_policy(spec), cfg.scenario)
        except ValueError as e:
            raise UsageError(str(e)) from None
    for spec in args.policies:
        try:
            _, record = evaluate_spec(spec, cfg, est, progress=_progress())
        except ValueError as e:
            raise UsageError(str(e)) from None
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
    parts = [str(SHIPPED_QNETS.get(part, part)) for part in ensemble_members(cfg.model)]
    for part in parts:
        if not Path(part).is_file():
            raise UsageError(f"--model: Q-net {part!r} not found (expected a shipped name, "
                             f"{' or '.join(SHIPPED_QNETS)}, or a .npz file, or several "
                             f"joined by '+')")
    if cfg.flip_tta and cfg.depth == "gt":
        raise UsageError("--flip-tta: averages the DispNet's disparity; only with --depth pred")
    check_output(cfg.gif, "--gif", suffix=".gif")
    try:
        policies = [load_qnet_policy(p) for p in parts]
        actions_and_camera(*policies)          # nets flown together fly one setting
    except ValueError as e:
        raise UsageError(f"--model: {e}") from None
    for policy in policies:
        warning = unfinished_warning(policy)
        if warning:
            print(warning, file=sys.stderr)
    depth = cfg.depth
    depth_model = shipped_depth_model(cfg.scenario) if depth == "pred" else None
    est = _estimator(depth, depth_model, cfg.scenario, cfg.flip_tta, option="--scenario")
    model = "+".join(parts)
    try:                                 # read before flying: a broken record is said
        recorded = recorded_result(model, cfg.scenario, depth, mirror=cfg.mirror,
                                   flip_tta=depth == "pred" and cfg.flip_tta)
    except ValueError as e:
        recorded = None
        print(f"note: {e}; its recorded results are not quoted", file=sys.stderr)
    with hold(cfg.gif, "--gif"):
        try:
            out = fly(policies, est, cfg.scenario, seed, cfg.flights, cfg.gif,
                      mirror=cfg.mirror, progress=_progress())
        except WriteError as e:          # what was measured is said before the error
            _flown(e.measured, depth, recorded, model)
            raise
    _flown(out, depth, recorded, model)
    return 0


def _flown(out: dict, depth: str, recorded, model: str) -> None:
    """What ``fly`` prints: its result as JSON, then in words (with the recorded result
    of a shipped model)."""
    print(json.dumps(out))
    by_world = "" if out["ci95_by_world"] is None else \
        f"; by world {out['ci95_by_world'][0]:.2f}-{out['ci95_by_world'][1]:.2f}, " \
        f"{out['worlds']} worlds"
    print(f"success {out['successes']}/{out['flights']} = {out['success_rate']:.2f} "
          f"(95% CI {out['ci95'][0]:.2f}-{out['ci95'][1]:.2f}{by_world}) on {depth} depth; "
          f"GIF: {out['gif'] or 'not written'}", file=sys.stderr)
    if recorded:
        print(f"note: {out['flights']} flights give a wide interval; this model's recorded "
              f"result here: {recorded_text(recorded)}. See "
              f"{Path(model).with_suffix('.json').name} beside it, docs/results.md and "
              "docs/beyond.md", file=sys.stderr)


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
    out = check_output(args.out, "--out", folder=True)
    try:            # the runs it finds in --out are continued (made with these settings)
        how = {"workers": cfg.workers, "executor": cfg.executor}
        with hold(out, "--out"):
            if cfg.quick:
                reproduce_quick(out, seed=cfg.seed, **how)
            elif cfg.recipe == "paper":
                reproduce(out, seed=cfg.seed, skip_depth=cfg.skip_depth, **how)
            else:
                reproduce_distilled(out, seed=cfg.seed, skip_depth=cfg.skip_depth,
                                    students=cfg.students, **how)
    except ValueError as e:
        raise UsageError(f"--out: {e}") from None
    return 0


# -- sweep -----------------------------------------------------------------------------------
def add_arguments_sweep(p: argparse.ArgumentParser) -> None:
    from .sweep import SweepConfig
    add_arguments(p, SweepConfig, hide=("seed",))
    g = p.add_argument_group("files")
    g.add_argument("--depth-model", default=None,
                   help="DispNet .npz when the nets read predicted depth "
                        "(default: the shipped one)")
    g.add_argument("--out", default=None, help="the sweep's folder, one run per seed "
                   "(default runs/sweep/<variant>_<scenario>_<depth>); a sweep started again "
                   "goes on from the runs it holds")
    g.add_argument("--smoke", action="store_true", help="a few hundred steps per seed (tests)")


def run_sweep(args) -> int:
    from .sweep import SweepConfig, sweep
    from .train import SMOKE, TrainConfig
    base = SweepConfig(train=TrainConfig(**SMOKE), flights=8) if args.smoke else None
    cfg = from_args(SweepConfig, args, base=base)
    t = cfg.train
    name = f"{t.variant}_{t.scenario}_{t.depth}"
    out = Path(args.out) if args.out else RUNS / "sweep" / (("smoke_" if args.smoke else "") + name)
    out = check_output(out, "--out", folder=True)
    _estimator(t.depth, args.depth_model, t.scenario)     # a missing DispNet: said now
    if t.init_model:
        _check_init_model(t)
    try:
        with hold(out, "--out"):
            sweep(cfg, out, args.depth_model, progress=_progress())
    except ValueError as e:
        raise UsageError(f"--out: {str(e).removeprefix('resume: ')}") from None
    return 0
