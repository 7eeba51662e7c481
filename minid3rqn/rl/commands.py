"""Command-line hooks: ``train-agent``, ``evaluate``, ``fly``, ``reproduce``.

Each command has ``add_arguments_<name>(parser)`` and ``run_<name>(args) -> int``;
``minid3rqn/cli.py`` registers them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ..io import machine

MODELS = Path(__file__).resolve().parent.parent / "models"
RUNS = Path("runs")
SHIPPED_QNET = MODELS / "d3rqn_basic.npz"
# The shipped Q-nets by name (fly --model NAME): the paper's training (the default), and
# our distilled student of `basic` (reproduce --recipe distil; docs/experiments.md).
SHIPPED_QNETS = {"paper": SHIPPED_QNET, "distil": MODELS / "d3rqn_distil.npz"}
VARIANT_NAMES = {"ddqn": "DDQN", "d3qn": "D3QN", "ddrqn": "DDRQN", "d3rqn": "D3RQN"}


def _command_line() -> str:
    return "python -m minid3rqn " + " ".join(sys.argv[1:])


def shipped_depth_model(scenario: str = "basic") -> Path:
    return MODELS / f"depth_{scenario}.npz"


def load_depth_estimator(path, flip: bool = False):
    from ..depth.evaluate import DepthEstimator
    return DepthEstimator.load(path, flip=flip)


HORIZON_DEFAULT = "the depth model's, else the Q-nets', else the middle row"


def add_argument_horizon_row(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--horizon-row", type=float, default=None,
                   help=f"image row of the horizon (default: {default})")


def _q_nets(policies) -> list:
    """The Q-net policies in ``policies`` (an ensemble's members; baselines left out)."""
    return [m for p in policies for m in getattr(p, "members", [p]) if hasattr(m, "qnet")]


def model_horizon(meta: dict | None) -> float | None:
    """The horizon row a Q-net was trained with (None: the default camera)."""
    return ((meta or {}).get("train_config") or {}).get("horizon_row")


def horizon_for(command: str, given, est, policies=()) -> float | None:
    """The horizon row a command flies with: ``--horizon-row`` if given, else the depth
    model's (a DispNet reads frames like the ones it was trained on), else the Q-nets'.
    Every Q-net and the depth model must agree with it: a net trained with one camera
    flown with another sees the floor where it never saw it, and says nothing."""
    from ..world import Camera
    default = Camera().cy            # the camera every DispNet is trained with
    nets = _q_nets(policies)
    row = given
    if row is None and est is not None:
        row = default
    if row is None:
        rows = {model_horizon(getattr(m, "meta", None)) for m in nets}
        row = rows.pop() if len(rows) == 1 else None
    try:
        cy = Camera(horizon_row=row).cy
    except ValueError as e:
        raise SystemExit(f"{command} --horizon-row: {e}")
    if est is not None and abs(default - cy) > 1e-6:
        raise SystemExit(f"{command}: the depth model was trained with the horizon at row "
                         f"{default:g}, but --horizon-row is {cy:g}")
    for m in nets:
        trained = model_horizon(getattr(m, "meta", None))
        trained = default if trained is None else trained
        if abs(trained - cy) > 1e-6:
            raise SystemExit(f"{command}: Q-net {m.name!r} was trained with the horizon at row "
                             f"{trained:g}, but these flights have it at row {cy:g} "
                             f"(--horizon-row, or the depth model's)")
    return None if cy == default else cy


def unfinished_warning(policy) -> str | None:
    """A warning if a Q-net file is a snapshot of a training run that had not finished:
    train-agent rewrites model.npz at every checkpoint, so a run in progress has one."""
    for m in getattr(policy, "members", [policy]):
        meta = getattr(m, "meta", None) or {}
        done, total = meta.get("steps"), (meta.get("train_config") or {}).get("total_steps")
        if done is not None and total is not None and done < total:
            return (f"warning: Q-net {m.name!r} is a snapshot at {done} of its run's {total} "
                    f"transitions (its training had not finished when it was saved)")
    return None


FLIP_HELP = ("depth: average the DispNet's disparity with its disparity on the mirrored "
             "frame (test-time flip; twice the inference cost; docs/depth.md section 7)")


def _estimator_for(depth: str, depth_model, scenario: str, flip: bool = False):
    if depth != "pred":
        return None
    path = Path(depth_model) if depth_model else shipped_depth_model(scenario)
    if not path.exists():
        raise SystemExit(f"depth model {str(path)!r} not found; train one with "
                         f"`python -m minid3rqn train-depth --scenario {scenario} --ship` "
                         f"or pass --depth gt")
    return load_depth_estimator(path, flip)


# -- train-agent --------------------------------------------------------------------------
SMOKE = dict(total_steps=128, learning_starts=64, n_envs=8, log_every=64, checkpoint_every=1000,
             hidden=16, replay_capacity=2000, eps_decay_steps=200)


def add_arguments_train_agent(p: argparse.ArgumentParser) -> None:
    from .train import TrainConfig
    d = TrainConfig()
    p.add_argument("--variant", default=d.variant, choices=["ddqn", "d3qn", "ddrqn", "d3rqn"])
    p.add_argument("--stack", type=int, default=None,
                   help="frames per observation (default 1; 5 = the window as channels)")
    p.add_argument("--seq-len", type=int, default=None,
                   help="replay window (default 5 for recurrent variants, 1 otherwise)")
    p.add_argument("--batch-size", type=int, default=d.batch_size,
                   help="replay windows per update (paper: 32)")
    p.add_argument("--scenario", default=d.scenario)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--steps", type=int, default=d.total_steps, help="environment transitions")
    p.add_argument("--n-envs", type=int, default=d.n_envs)
    p.add_argument("--updates-per-step", type=float, default=d.updates_per_step)
    p.add_argument("--learning-starts", type=int, default=d.learning_starts)
    p.add_argument("--eps-decay", type=int, default=d.eps_decay_steps)
    p.add_argument("--replay", type=int, default=d.replay_capacity)
    p.add_argument("--hidden", type=int, default=d.hidden)
    p.add_argument("--conv-channels", default=None,
                   help="out channels of the three conv layers, e.g. 16,32,32 (ours; "
                        "default 4,8,8: nets/qnet.py)")
    p.add_argument("--worlds", type=int, default=d.flights.n_worlds,
                   help="scenes in the training pool (each flight starts in one of them)")
    p.add_argument("--depth", default=d.depth, choices=["gt", "pred"])
    p.add_argument("--depth-model", default=None, help="DepthEstimator .npz (--depth pred)")
    p.add_argument("--flip-tta", action="store_true", help=FLIP_HELP)
    add_argument_horizon_row(p, HORIZON_DEFAULT)
    p.add_argument("--init-model", default="", help="start from this Q-net .npz (fine-tune)")
    p.add_argument("--init-widen", action="store_true",
                   help="the --init-model's LSTM is narrower than --hidden: grow it, the new "
                        "units closed to the heads, so the net starts with the same Q-values "
                        "(ours; nets/qnet.py, widen_recurrent_state)")
    p.add_argument("--eps-start", type=float, default=d.eps_start)
    p.add_argument("--lr", type=float, default=d.agent.lr, help="Adam step size (paper: 3e-4)")
    p.add_argument("--teachers", default="",
                   help="distil instead of Q-learning (ours; rl/distill.py): the teacher's "
                        "Q-net .npz, or several joined by '+', flown on GT depth")
    p.add_argument("--teacher-mix", type=float, default=d.teacher_mix,
                   help="probability of flying the teacher's action at the start (--teachers)")
    p.add_argument("--teacher-mix-steps", type=int, default=d.teacher_mix_steps,
                   help="transitions over which that probability falls to 0 (--teachers)")
    p.add_argument("--teacher-mirror", action="store_true",
                   help="each teacher net also flies the mirrored view: the teacher is the "
                        "ensemble of the nets and their mirror images (--teachers; ours)")
    p.add_argument("--teacher-depth", choices=["gt", "pred"], default=d.teacher_depth,
                   help="what the teacher reads: gt, the privileged GT depth (default), or "
                        "pred, the student's own predicted-depth frames (for a teacher of "
                        "nets that fly on predicted depth; needs --depth pred; ours)")
    p.add_argument("--distil-kl", type=float, default=d.distil_kl, metavar="W",
                   help="add W times a KL term on the teacher's action preferences, "
                        "softmax(Q / --distil-temperature), to the Huber loss (--teachers; "
                        "ours; 0, the default: Huber only)")
    p.add_argument("--distil-temperature", type=float, default=d.distil_temperature,
                   metavar="T", help="temperature of --distil-kl, in Q-value units")
    p.add_argument("--mirror-augment", action="store_true",
                   help="training augmentation (ours): learn from each sampled window "
                        "mirrored left-right with probability 1/2 (frames flipped, actions "
                        "and teacher labels mapped to their mirror images)")
    p.add_argument("--average-last", type=int, default=d.average_last, metavar="N",
                   help="weight averaging (ours): model.npz holds the mean of the weights "
                        "after every update of the last N transitions, model_last.npz the "
                        "last weights (0, the default: no averaging)")
    p.add_argument("--out", default=None, help="run folder (default runs/agent/<name>)")
    p.add_argument("--resume", action="store_true")
    p.add_argument("--ship", default=None, help="also copy the model to minid3rqn/models/NAME.npz")
    p.add_argument("--smoke", action="store_true", help="a few hundred steps (tests)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar: one line per checkpoint instead (for log files "
                        "and parallel runs)")


def config_from_args(args):
    from .train import TrainConfig
    recurrent = args.variant in ("ddrqn", "d3rqn")
    seq_len = args.seq_len if args.seq_len is not None else (5 if recurrent else 1)
    cfg = TrainConfig(variant=args.variant, stack=args.stack or 1, seq_len=seq_len,
                      batch_size=args.batch_size,
                      scenario=args.scenario, seed=args.seed, n_envs=args.n_envs,
                      total_steps=args.steps, learning_starts=args.learning_starts,
                      updates_per_step=args.updates_per_step, eps_decay_steps=args.eps_decay,
                      replay_capacity=args.replay, hidden=args.hidden, depth=args.depth,
                      init_model=args.init_model, init_widen=args.init_widen,
                      eps_start=args.eps_start,
                      teachers=args.teachers, teacher_mix=args.teacher_mix,
                      teacher_mix_steps=args.teacher_mix_steps,
                      teacher_mirror=args.teacher_mirror, teacher_depth=args.teacher_depth,
                      distil_kl=args.distil_kl, distil_temperature=args.distil_temperature,
                      mirror_augment=args.mirror_augment)
    if args.conv_channels is not None:
        try:
            cfg.conv_channels = [int(c) for c in str(args.conv_channels).split(",")]
        except ValueError:
            raise SystemExit(f"train-agent --conv-channels: expected ints joined by ',' "
                             f"(e.g. 16,32,32); got {args.conv_channels!r}")
        try:
            cfg.qnet_config(5, (32, 104))
        except ValueError as e:
            raise SystemExit(f"train-agent --conv-channels: {e}")
    cfg.agent.lr = args.lr
    cfg.flights.n_worlds = args.worlds
    if args.smoke:
        from .flights import FlightsConfig
        for k, v in SMOKE.items():
            setattr(cfg, k, v)
        cfg.flights = FlightsConfig(n_worlds=2)
    for flag, value in (("--seq-len", cfg.seq_len), ("--batch-size", cfg.batch_size)):
        if value < 1:
            raise SystemExit(f"train-agent {flag}: expected an int >= 1; got {value}")
    if not 0 <= args.average_last <= cfg.total_steps:
        raise SystemExit(f"train-agent --average-last: expected a number of transitions in "
                         f"[0, --steps = {cfg.total_steps}]; got {args.average_last}")
    cfg.average_last = args.average_last
    if cfg.init_widen and not cfg.init_model:
        raise SystemExit("train-agent --init-widen: widens the --init-model's LSTM, so it needs "
                         "--init-model")
    if args.distil_kl != 0.0 and not cfg.teachers:
        raise SystemExit(f"train-agent --distil-kl {args.distil_kl:g}: a term of the "
                         f"distillation loss, so it needs --teachers")
    if not (np.isfinite(args.distil_kl) and args.distil_kl >= 0):
        raise SystemExit(f"train-agent --distil-kl: expected a weight >= 0; got {args.distil_kl!r}")
    if not (np.isfinite(args.distil_temperature) and args.distil_temperature > 0):
        raise SystemExit(f"train-agent --distil-temperature: expected a temperature > 0 (Q-value "
                         f"units); got {args.distil_temperature!r}")
    if cfg.teacher_depth == "pred" and not (cfg.teachers and cfg.depth == "pred"):
        raise SystemExit(f"train-agent --teacher-depth pred: the teacher reads the student's "
                         f"predicted depth, so it needs --teachers and --depth pred; got "
                         f"--teachers {cfg.teachers or '(none)'!r} --depth {cfg.depth}")
    return cfg


def run_name(cfg) -> str:
    stack = f"_stack{cfg.stack}" if cfg.stack > 1 else ""
    distil = "_distil" if cfg.teachers else ""
    return f"{cfg.variant}{stack}{distil}_{cfg.scenario}_{cfg.depth}_s{cfg.seed}"


def run_train_agent(args, command: str | None = None) -> int:
    """``command``: the command line to record in the model file (default: this
    process's; ``reproduce`` passes the equivalent ``train-agent`` one)."""
    from .train import train
    cfg = config_from_args(args)
    if cfg.teachers:                      # a bad teacher spec: say so before any training
        from ..world import ACTIONS, Camera
        from .distill import load_teacher
        cam = Camera()
        for flag, spec in (("--teachers", cfg.teachers), ("--base-teachers", cfg.base_teachers)):
            if not spec:
                continue
            try:
                load_teacher(spec, (cam.height, cam.width), len(ACTIONS))
            except ValueError as e:
                raise SystemExit(f"train-agent {flag}: {e}")
    if cfg.init_widen:                    # a net that cannot be widened: say so first
        from ..io import load_npz
        from ..nets.qnet import QNet, widen_recurrent_state
        from ..world import ACTIONS, Camera
        cam = Camera()
        try:
            old, _ = load_npz(cfg.init_model)
            fresh = QNet(cfg.qnet_config(len(ACTIONS), (cam.height, cam.width)), rng=0)
            widen_recurrent_state(old, fresh.state_dict())
        except (ValueError, OSError) as e:
            raise SystemExit(f"train-agent --init-widen --init-model {cfg.init_model}: {e}")
    out = Path(args.out) if args.out else RUNS / "agent" / (("smoke_" if args.smoke else "")
                                                           + run_name(cfg))
    est = _estimator_for(cfg.depth, args.depth_model, cfg.scenario, args.flip_tta)
    from .policies import QNetPolicy
    known = [p for p in [cfg.init_model, *cfg.teachers.split("+"),
                         *cfg.base_teachers.split("+")] if p]
    known = [QNetPolicy.load(p) for p in known if Path(p).is_file()]
    cfg.horizon_row = horizon_for("train-agent", args.horizon_row, est, known)
    t0 = time.time()
    tr = train(cfg, out, depth_estimator=est, progress=not args.quiet, resume=args.resume)
    extra = {"command": command or _command_line(), "seed": cfg.seed,
             "train_seconds": round(time.time() - t0, 1),
             "depth_model": str(args.depth_model or (shipped_depth_model(cfg.scenario)
                                                     if cfg.depth == "pred" else "")),
             "depth_flip": bool(est is not None and est.flip), "machine": machine()}
    model = tr.save_model(out / "model.npz", extra)
    print(json.dumps({"model": str(model), "steps": tr.steps, "updates": tr.agent.updates,
                      "last": tr.curve[-1] if tr.curve else {}}))
    if args.ship:
        ship_model(model, args.ship)
    return 0


def ship_model(model_path, name: str, results: dict | None = None) -> Path:
    """Copy a trained Q-net into the package (models/NAME.npz + NAME.json)."""
    from ..io import load_npz, save_npz
    arrays, meta = load_npz(model_path)
    meta = dict(meta or {})
    if results:
        meta["results"] = results
    MODELS.mkdir(exist_ok=True)
    dst = MODELS / f"{name}.npz"
    save_npz(dst, arrays, meta)
    (MODELS / f"{name}.json").write_text(json.dumps(meta, indent=2))
    return dst


# -- evaluate -----------------------------------------------------------------------------
BASELINES = ("straight", "random", "reactive", "oracle")


def make_policy(spec: str, seed: int = 0, window: int | None = None, mirror: bool = False):
    """'straight' | 'random' | 'reactive' | 'oracle' | path to a Q-net .npz | several
    Q-net paths joined by '+' (an ensemble: greedy on their mean Q-values).

    ``window`` (recurrent Q-nets): act from a zero state over the last ``window`` frames
    at every step, as in training, instead of carrying the state through the flight.
    ``mirror``: every Q-net also flies the mirrored view (``QNetPolicy.mirrored``), and
    the policy is the ensemble of all of them (one net: a two-member ensemble)."""
    from ..world import ACTIONS
    from .policies import (EnsemblePolicy, OraclePolicy, QNetPolicy, RandomPolicy,
                           ReactivePolicy, StraightPolicy)
    if "+" in spec:
        parts = spec.split("+")
        if any(p in BASELINES or not p for p in parts):
            raise SystemExit(f"evaluate: an ensemble joins Q-net .npz files with '+'; got "
                             f"{spec!r}")
        members = [make_policy(p, seed, window) for p in parts]
        if not mirror:
            return EnsemblePolicy(members)
        names = "+".join(sorted({m.name for m in members}))
        return EnsemblePolicy(members + [m.mirrored() for m in members],
                              name=f"{names}-ens{len(parts)}-mirror")
    if mirror and spec not in BASELINES:
        pol = make_policy(spec, seed, window)
        return EnsemblePolicy([pol, pol.mirrored()], name=pol.name + "-mirror")
    if spec == "straight":
        return StraightPolicy()
    if spec == "random":
        return RandomPolicy(len(ACTIONS), seed=seed)
    if spec == "reactive":
        return ReactivePolicy(ACTIONS)
    if spec == "oracle":
        return OraclePolicy()
    path = Path(spec)
    if not path.exists():
        raise SystemExit(f"evaluate: {spec!r} is neither a baseline {BASELINES} nor a model "
                         f"file")
    pol = QNetPolicy.load(path)
    from ..nets.qnet import variant_name
    name = VARIANT_NAMES[variant_name(pol.qnet.config)]
    if pol.qnet.config.in_channels > 1:
        name += f"-stack{pol.qnet.config.in_channels}"
    pol.name = name
    if window:
        if not pol.qnet.recurrent:
            raise SystemExit(f"evaluate: --window needs a recurrent Q-net; {spec!r} is {name}")
        pol.window = int(window)
        pol.name += f"-win{window}"
    return pol


def add_arguments_evaluate(p: argparse.ArgumentParser) -> None:
    p.add_argument("policies", nargs="+",
                   help=f"baselines {', '.join(BASELINES)} and/or Q-net .npz files (A.npz+B.npz+...: "
                        "an ensemble, greedy on the members' mean Q-values)")
    p.add_argument("--scenario", default="basic")
    p.add_argument("--flights", type=int, default=2000, help="test flights (paper: 2000)")
    p.add_argument("--steps", type=int, default=50, help="steps for a success (paper: 50)")
    p.add_argument("--seed", type=int, default=12345)
    p.add_argument("--depth", default="gt", choices=["gt", "pred"])
    p.add_argument("--depth-model", default=None)
    p.add_argument("--flip-tta", action="store_true", help=FLIP_HELP)
    p.add_argument("--chunk", type=int, default=500, help="flights stepped together")
    p.add_argument("--workers", type=int, default=1,
                   help="processes flying chunks in parallel, one per core (same result; "
                        "run with OMP_NUM_THREADS=1)")
    p.add_argument("--window", type=int, default=None,
                   help="recurrent Q-nets: act from a zero state over the last N frames at "
                        "every step (as trained) instead of carrying the state through "
                        "the flight")
    p.add_argument("--mirror", action="store_true",
                   help="Q-nets: each also flies the left-right mirrored view, and the "
                        "policy is greedy on the mean Q-values of all (a free two-member "
                        "ensemble per net; docs/d3rqn.md section 10)")
    add_argument_horizon_row(p, HORIZON_DEFAULT)
    p.add_argument("--validation", action="store_true",
                   help="fly the validation worlds instead of the test worlds (a disjoint "
                        "seed range, for choosing between models without the test worlds)")
    p.add_argument("--json", default=None, help="append results to this JSON-lines file")
    p.add_argument("--quiet", action="store_true")


def _what_flew(spec: str, depth: str, est, mirror: bool) -> str:
    """The tail of an evaluation's printed line: which model files flew, on which depth.

    Two evaluations that append to one log can then be told apart (the JSON lines of
    ``--json`` carry the same and more)."""
    how = [f"{depth} depth"] + (["flip"] if est is not None and est.flip else [])
    if spec in BASELINES:                # of these only the reactive rule reads depth
        return f"  ({', '.join(how)})" if spec == "reactive" else ""
    return f"  {spec} ({', '.join(how + (['mirror'] if mirror else []))})"


def evaluate_one(spec: str, args, est) -> tuple:
    """Fly one policy of an ``evaluate`` command (``args`` as parsed, ``est`` its depth
    estimator): print its line, and return the result and the record ``--json`` appends
    (``reproduce`` calls this too, so its figures are the ``evaluate`` command's)."""
    from functools import partial
    from ..world import Camera
    from .evaluate import evaluate_policy
    from .flights import Flights
    from .policies import ReactivePolicy
    pol = make_policy(spec, args.seed, window=args.window if spec not in BASELINES else None,
                      mirror=args.mirror)
    row = horizon_for("evaluate", args.horizon_row, est, [pol])
    warning = unfinished_warning(pol)
    if warning:
        print(warning, file=sys.stderr, flush=True)
    if isinstance(pol, ReactivePolicy):      # it reads the rows around the horizon
        pol.horizon_row = row
    res = evaluate_policy(pol, args.scenario, args.flights, args.seed, args.steps,
                          args.chunk, args.depth, est, progress=not args.quiet,
                          workers=args.workers,
                          flights_factory=partial(Flights, camera=Camera(horizon_row=row)),
                          world_set="validation" if args.validation else "test")
    print(res.line() + _what_flew(spec, args.depth, est, args.mirror), flush=True)
    record = {**res.to_dict(), "spec": spec,
              "depth_flip": bool(est is not None and est.flip),
              "mirror": bool(args.mirror and spec not in BASELINES),
              "horizon_row": row,
              "unfinished": warning is not None, "command": _command_line()}
    return res, record


def run_evaluate(args) -> int:
    est = _estimator_for(args.depth, args.depth_model, args.scenario, args.flip_tta)
    for spec in args.policies:
        _, record = evaluate_one(spec, args, est)
        if args.json:
            with open(args.json, "a") as f:
                f.write(json.dumps(record) + "\n")
    return 0


# -- fly ----------------------------------------------------------------------------------
def add_arguments_fly(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default="paper",
                   help="a shipped Q-net by name: paper (the default: trained as the paper "
                        "trains it) or distil (our distilled student of basic); or a Q-net "
                        ".npz (A.npz+B.npz+...: an ensemble on their mean Q-values)")
    p.add_argument("--depth-model", default=None,
                   help="DepthEstimator .npz (default: the shipped depth_<scenario>.npz)")
    p.add_argument("--depth", default="pred", choices=["gt", "pred"])
    p.add_argument("--flip-tta", action="store_true", help=FLIP_HELP)
    p.add_argument("--mirror", action="store_true",
                   help="each Q-net also flies the mirrored view (a free two-member ensemble)")
    add_argument_horizon_row(p, HORIZON_DEFAULT)
    p.add_argument("--scenario", default="basic")
    p.add_argument("--flights", type=int, default=32,
                   help="flights for the success rate (DispNet runs on every frame: keep it small)")
    p.add_argument("--seed", type=int, default=None, help="world seed (default: random)")
    p.add_argument("--gif", default="fly.gif")
    p.add_argument("--steps", type=int, default=50)


def run_fly(args) -> int:
    from .fly import fly
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().entropy % 10**6)
    depth = args.depth
    parts = [str(SHIPPED_QNETS.get(part, part)) for part in args.model.split("+")]
    for part in parts:
        if not Path(part).is_file():
            raise SystemExit(f"fly: --model: Q-net {part!r} not found (expected a shipped "
                             f"name, {' or '.join(SHIPPED_QNETS)}, or a .npz file, or several "
                             f"joined by '+')")
    model = "+".join(parts)
    depth_model = args.depth_model or shipped_depth_model(args.scenario)
    if depth == "pred" and not Path(depth_model).exists():
        if args.depth_model is None and shipped_depth_model("basic").exists():
            depth_model = shipped_depth_model("basic")
        else:
            print(f"fly: no depth model at {depth_model}; flying on GT depth", file=sys.stderr)
            depth = "gt"
    est = load_depth_estimator(depth_model, args.flip_tta) if depth == "pred" else None
    from .policies import QNetPolicy
    nets = [QNetPolicy.load(part, "D3RQN") for part in model.split("+")]
    row = horizon_for("fly", args.horizon_row, est, nets)
    out = fly(nets, est, args.scenario, seed, args.flights, args.gif, args.steps,
              mirror=args.mirror, horizon_row=row)
    print(json.dumps(out))
    by_world = "" if out["ci95_by_world"] is None else \
        f"; by world {out['ci95_by_world'][0]:.2f}-{out['ci95_by_world'][1]:.2f}, " \
        f"{out['worlds']} worlds"
    print(f"success {out['successes']}/{out['flights']} = {out['success_rate']:.2f} "
          f"(95% CI {out['ci95'][0]:.2f}-{out['ci95'][1]:.2f}{by_world}) on {depth} depth; "
          f"GIF: {out['gif']}", file=sys.stderr)
    recorded = recorded_result(model, args.scenario, depth, mirror=args.mirror,
                               flip_tta=depth == "pred" and args.flip_tta)
    if recorded:
        print(f"note: {out['flights']} flights give a wide interval; this model's recorded "
              f"result here: {recorded_text(recorded)}. See "
              f"{Path(model).with_suffix('.json').name} beside it, docs/results.md and "
              "docs/experiments.md", file=sys.stderr)
    return 0


def recorded_text(row: dict) -> str:
    """One recorded evaluation in words: the rate, Wilson's interval by flight, and the
    interval by world when the row has it (rows written before it was measured do not)."""
    text = f"{row['rate']:.3f}, 95% CI [{row['ci95'][0]:.3f}, {row['ci95'][1]:.3f}] by flight"
    if row.get("ci95_by_world"):
        lo, hi = row["ci95_by_world"]
        text += f", [{lo:.3f}, {hi:.3f}] by world ({row['worlds']} worlds)"
    return text + f", over {row['flights']} flights (seed {row['seed']})"


def recorded_result(model, scenario: str, depth: str, mirror: bool = False,
                    flip_tta: bool = False) -> dict | None:
    """The largest evaluation of ``scenario`` on ``depth`` depth recorded in the JSON beside
    a model file (``evaluations``: what the shipped models' commands measured), if any,
    flown as asked: with the mirror image (``mirror``) and the DispNet's test-time flip
    (``flip_tta``) or without; a row without those keys was flown without them."""
    path = Path(model).with_suffix(".json")
    if not path.is_file():
        return None
    rows = [r for r in json.loads(path.read_text()).get("evaluations", [])
            if r.get("scenario") == scenario and r.get("depth") == depth
            and r.get("mirror", False) == mirror and r.get("flip_tta", False) == flip_tta]
    return max(rows, key=lambda r: r["flights"]) if rows else None


# -- reproduce ----------------------------------------------------------------------------
def add_arguments_reproduce(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true",
                   help="classroom preset: short trainings, 200 test flights (minutes)")
    p.add_argument("--out", default="runs/reproduce")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--depth", default="pred", choices=["gt", "pred"])
    p.add_argument("--skip-depth", action="store_true",
                   help="reuse depth models in minid3rqn/models instead of retraining them")
    p.add_argument("--table", choices=["5", "6", "both"], default="both")
    p.add_argument("--train-depth", default="gt", choices=["gt", "pred"],
                   help="depth the Q-nets are trained on (default gt; tested on --depth)")
    p.add_argument("--workers", type=int, default=1,
                   help="processes for the evaluations (evaluate --workers); --recipe distil: "
                        "also trains its parents and students that many at a time (one per "
                        "core; run with OMP_NUM_THREADS=1)")
    p.add_argument("--recipe", choices=["paper", "distil", "distil-short"], default="paper",
                   help="paper: Tables 5 and 6 as above; distil (ours): the distilled D3RQN "
                        "that flies basic at 0.95 on predicted depth (four GT parents, two "
                        "distillation stages; docs/experiments.md); distil-short (ours): the same "
                        "with only the two wide parents, 120k transitions each")
    p.add_argument("--students", type=int, default=1,
                   help="--recipe distil or distil-short: students of the second stage "
                        "(seeds --seed, --seed + 1, ...)")
    p.add_argument("--parent-steps", type=int, default=None,
                   help="--recipe distil or distil-short: transitions of each GT parent "
                        "(default 240000 and 120000), epsilon falling over the first 5/12 "
                        "of them as in both presets")
    p.add_argument("--wide-parents", type=int, default=2, metavar="K",
                   help="--recipe distil or distil-short: K wide GT parents (seeds 0 to K-1; "
                        "default 2, as in both presets), trained --workers at a time; all of "
                        "them join the teacher")
    p.add_argument("--skip-stage1", action="store_true",
                   help="--recipe distil or distil-short: no stage 1; stage 2 starts from the "
                        "wide parent, its LSTM grown to 256 units (ours; docs/experiments.md, "
                        "'More parents or longer ones')")
    p.add_argument("--start", choices=["first", "best"], default="first",
                   help="--recipe distil or distil-short: the wide parent stage 1 grows: "
                        "first (seed --seed, as run until now) or best (the higher success "
                        "on GT depth over 500 flights, 100 with --quick, in the validation "
                        "worlds)")
    p.add_argument("--student-seq-len", type=int, default=5, metavar="L",
                   help="--recipe distil or distil-short: the students' replay windows, L "
                        "steps each (train-agent --seq-len; default the paper's 5)")
    p.add_argument("--student-batch-size", type=int, default=32, metavar="B",
                   help="--recipe distil or distil-short: the students' replay windows per "
                        "update (train-agent --batch-size; default the paper's 32); "
                        "--student-seq-len 10 --student-batch-size 16 keeps the frames per "
                        "update (docs/experiments.md, 'Longer replay windows')")


def run_reproduce(args) -> int:
    from .reproduce import reproduce, reproduce_distilled
    if args.workers < 1:
        raise SystemExit(f"reproduce --workers: expected a number of processes >= 1; got "
                         f"{args.workers}")
    if args.students < 1:
        raise SystemExit(f"reproduce --students: expected a number of students >= 1; got "
                         f"{args.students}")
    if args.start != "first" and args.recipe == "paper":
        raise SystemExit(f"reproduce --start {args.start}: only for --recipe distil and "
                         f"distil-short")
    if args.skip_stage1 and args.recipe == "paper":
        raise SystemExit("reproduce --skip-stage1: only for --recipe distil and distil-short")
    if args.wide_parents != 2 and args.recipe == "paper":
        raise SystemExit(f"reproduce --wide-parents {args.wide_parents}: only for --recipe "
                         f"distil and distil-short")
    if args.wide_parents < 1:
        raise SystemExit(f"reproduce --wide-parents: expected a number of parents >= 1; got "
                         f"{args.wide_parents}")
    for flag, value, paper in (("--student-seq-len", args.student_seq_len, 5),
                               ("--student-batch-size", args.student_batch_size, 32)):
        if value < 1:
            raise SystemExit(f"reproduce {flag}: expected an integer >= 1; got {value}")
        if value != paper and args.recipe == "paper":
            raise SystemExit(f"reproduce {flag} {value}: only for --recipe distil and "
                             f"distil-short")
    if args.parent_steps is not None:
        from .reproduce import FULL, QUICK
        starts = (QUICK if args.quick else FULL)["learning_starts"]
        if args.recipe == "paper":
            raise SystemExit(f"reproduce --parent-steps {args.parent_steps}: only for --recipe "
                             f"distil and distil-short")
        if args.parent_steps <= starts:
            raise SystemExit(f"reproduce --parent-steps: expected more transitions than the "
                             f"parents' learning start ({starts}); got {args.parent_steps}")
    if args.recipe in ("distil", "distil-short"):
        if args.depth != "pred" or args.train_depth != "gt":
            raise SystemExit(f"reproduce --recipe {args.recipe}: its stages are fixed (GT depth, "
                             f"then predicted depth) and its students fly on predicted depth; got "
                             f"--depth {args.depth} --train-depth {args.train_depth}")
        reproduce_distilled(out=Path(args.out), quick=args.quick, seed=args.seed,
                            students=args.students, skip_depth=args.skip_depth,
                            tables=args.table, workers=args.workers,
                            short=args.recipe == "distil-short",
                            parent_steps=args.parent_steps, start=args.start,
                            wide_parents=args.wide_parents, stage1=not args.skip_stage1,
                            student_seq_len=args.student_seq_len,
                            student_batch_size=args.student_batch_size)
        return 0
    if args.students != 1:
        raise SystemExit(f"reproduce --students {args.students}: only for --recipe distil "
                         f"and distil-short")
    reproduce(out=Path(args.out), quick=args.quick, seed=args.seed, depth=args.depth,
              skip_depth=args.skip_depth, tables=args.table, train_depth=args.train_depth,
              workers=args.workers)
    return 0


__all__ = ["add_arguments_train_agent", "run_train_agent", "add_arguments_evaluate", "run_evaluate",
           "add_arguments_fly", "run_fly", "add_arguments_reproduce", "run_reproduce",
           "make_policy", "ship_model", "config_from_args", "run_name"]
