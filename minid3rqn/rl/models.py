"""Model files: the shipped ones, and what a Q-net file says about how to fly it.

A Q-net file (``.npz``, written by ``rl.train``) holds the weights and, as metadata, the
network's shape (``qnet_config``) and the run's settings (``train_config``): among them
the action table and the camera's field of view it was trained with. A net is flown
with those, or it reads frames and picks actions it never learned.

    load_policy("straight" | "random" | "reactive" | "oracle" | "A.npz" | "A.npz+B.npz")
    trained_actions(meta), trained_camera(meta)   the action table and camera of a file
    shipped_depth_model("basic")                  minid3rqn/models/depth_basic.npz
    load_depth_estimator(path, flip=False)        a DispNet to fly on predicted depth
    ship(model, name, records)                    a finished, evaluated model into models/
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io import MODELS
from .evaluate import TEST_WORLDS
from .policies import _trained, trained_actions, trained_camera

SHIPPED_QNET = MODELS / "d3rqn_basic.npz"
# The shipped Q-nets by name (fly --model NAME): the paper's training (the default), and
# our distilled student (reproduce --recipe distil; docs/beyond.md).
SHIPPED_QNETS = {"paper": SHIPPED_QNET, "distil": MODELS / "d3rqn_distil.npz"}
BASELINES = ("straight", "random", "reactive", "oracle")
VARIANT_NAMES = {"ddqn": "DDQN", "d3qn": "D3QN", "ddrqn": "DDRQN", "d3rqn": "D3RQN"}


def shipped_depth_model(scenario: str = "basic") -> Path:
    """The shipped DispNet of ``scenario``: minid3rqn/models/depth_<scenario>.npz."""
    return MODELS / f"depth_{scenario}.npz"


def load_depth_estimator(path, flip: bool = False):
    """The DispNet at ``path`` as a depth estimator; ``flip``: also on the mirrored frame,
    the two disparities averaged (ours)."""
    from ..depth.evaluate import DepthEstimator
    from ..depth.flip import FlipAveraged
    estimator = DepthEstimator.load(path)
    return FlipAveraged(estimator) if flip else estimator


def depth_estimator_for(depth: str, depth_model=None, scenario: str = "basic",
                        flip: bool = False):
    """None for ``depth="gt"``; for "pred" the DispNet ``depth_model`` (default: the
    shipped one of ``scenario``). FileNotFoundError if there is none."""
    if depth != "pred":
        return None
    path = Path(depth_model) if depth_model else shipped_depth_model(scenario)
    if not path.is_file():
        raise FileNotFoundError(f"depth model {str(path)!r} not found; train one with "
                                f"`python -m minid3rqn train-depth --scenario {scenario}` or "
                                f"fly on --depth gt")
    return load_depth_estimator(path, flip)


# -- what a Q-net file records ------------------------------------------------------------
def unfinished_warning(policy) -> str | None:
    """A warning if a Q-net file is a snapshot of a run that had not finished (a run
    rewrites model.npz at every checkpoint)."""
    for m in getattr(policy, "members", [policy]):
        meta = getattr(m, "meta", None) or {}
        trained = _trained(meta)
        done, total = meta.get("steps"), trained.get("steps", trained.get("total_steps"))
        if done is not None and total is not None and done < total:
            return (f"warning: Q-net {m.name!r} is a snapshot at {done} of its run's {total} "
                    f"transitions (its training had not finished when it was saved)")
    return None


# -- policies by name ----------------------------------------------------------------------
def ensemble_members(spec: str) -> list[str]:
    """The Q-net files a spec names. The rule for '+': a spec that is an existing file is
    that one file, '+' in its name or not; any other spec is files joined by '+' (an
    ensemble). So ``a+b.npz`` flies alone when that file exists, and a file with '+' in
    its name joins an ensemble under another name (a copy or a symbolic link)."""
    spec = str(spec)
    return [spec] if Path(spec).is_file() else spec.split("+")


def load_qnet_policy(path):
    """A Q-net file as a greedy ``QNetPolicy`` named by its variant (D3RQN, D3QN-stack5...)."""
    from ..nets.qnet import variant_name
    from .policies import QNetPolicy
    pol = QNetPolicy.load(path)
    cfg = pol.qnet.config
    pol.name = VARIANT_NAMES[variant_name(cfg)] + (f"-stack{cfg.in_channels}"
                                                   if cfg.in_channels > 1 else "")
    return pol


def load_policy(spec: str, seed: int = 0, mirror: bool = False):
    """'straight' | 'random' | 'reactive' | 'oracle' | a Q-net .npz | Q-net files joined by
    '+' (an ensemble, greedy on their mean Q-values; ours). ``mirror`` (ours): every Q-net
    also flies the mirrored view (``rl.mirror``), and the policy is the ensemble of all.
    The baselines fly the world's action table. ValueError for a bad spec."""
    from ..world import ACTIONS
    from .mirror import MirroredPolicy
    from .policies import (EnsemblePolicy, OraclePolicy, RandomPolicy, ReactivePolicy,
                           StraightPolicy)
    baselines = {"straight": StraightPolicy, "oracle": OraclePolicy,
                 "random": lambda: RandomPolicy(len(ACTIONS), seed=seed),
                 "reactive": lambda: ReactivePolicy(ACTIONS)}
    if spec in baselines:
        return baselines[spec]()
    parts = ensemble_members(spec)
    for part in parts:
        if part in BASELINES or not Path(part).is_file():
            what = "is a baseline (only Q-nets join with '+')" if part in BASELINES else \
                "is a folder" if part and Path(part).is_dir() else "not found"
            shipped = ", ".join(str(p.relative_to(MODELS.parent.parent)) for p in
                                SHIPPED_QNETS.values())
            raise ValueError(f"{spec!r}: expected a baseline ({', '.join(BASELINES)}), a "
                             f"Q-net .npz file (shipped: {shipped}), or Q-net files joined "
                             f"by '+'; {part!r} {what}")
    members = [load_qnet_policy(p) for p in parts]
    if not mirror:
        return members[0] if len(members) == 1 else EnsemblePolicy(members)
    names = "+".join(sorted({m.name for m in members}))
    suffix = f"-ens{len(parts)}-mirror" if len(parts) > 1 else "-mirror"
    return EnsemblePolicy(members + [MirroredPolicy(m) for m in members], name=names + suffix)


def actions_and_camera(*policies):
    """The action table and camera policies fly with: their Q-nets' (they must agree;
    ValueError if not), else the world's."""
    from ..world import ACTIONS, Camera
    nets = [m for p in policies for m in getattr(p, "members", [p]) if hasattr(m, "meta")]
    if not nets:
        return ACTIONS.copy(), Camera()
    actions, camera = trained_actions(nets[0].meta), trained_camera(nets[0].meta)
    for m in nets[1:]:
        a, c = trained_actions(m.meta), trained_camera(m.meta)
        if a.shape != actions.shape or not np.allclose(a, actions) or c != camera:
            raise ValueError(f"{m.name!r} was trained with another action table or camera "
                             f"than {nets[0].name!r}; fly nets of one setting together")
    return actions, camera


# -- writing a trained Q-net ------------------------------------------------------------------
def command_for(cfg, out, depth_model=None) -> str:
    """The command that trains ``cfg`` (a TrainConfig: train-agent; a DistilConfig:
    distil) into the folder ``out``: what a model file records."""
    from ..config import command_line, shell_command
    from .distill import DISTIL_OPTIONS, DistilConfig
    from .train import TrainConfig
    if isinstance(cfg, DistilConfig):
        words = ["distil", *command_line(DistilConfig, cfg, main=DISTIL_OPTIONS)]
    else:
        words = ["train-agent", *command_line(TrainConfig, cfg)]
    if depth_model:
        words += ["--depth-model", str(depth_model)]
    return shell_command(words + ["--out", out])


def save_trained(run, command: str, depth_model=None, seconds: float | None = None,
                 **extra) -> Path:
    """The run's model.npz, recording the command that makes it, its seed, the depth
    model it read and the machine it ran on."""
    from ..io import machine
    meta = {"command": command, "seed": run.cfg.seed, "depth_model": str(depth_model or ""),
            "machine": machine(), **extra}
    if seconds is not None:
        meta["train_seconds"] = round(seconds, 1)
    return run.save_model(run.out / "model.npz", meta)


# -- shipping a model ------------------------------------------------------------------------
def ship(model, name: str, records=()) -> Path:
    """Copy a finished, evaluated model into minid3rqn/models as ``<name>.npz``, with
    ``<name>.json`` beside it (how it was made and how it flies: what ``fly``, the docs
    and ``recorded_result`` read); returns the new .npz. The only way a command-line run
    reaches minid3rqn/models (``io.check_output`` keeps every other output out of it).

    ``model``: a Q-net file of a finished ``train-agent`` or ``distil`` run (not a
    checkpoint's snapshot), with ``records`` the ``evaluate --json`` records of it (at
    least one); or a depth model file of ``train-depth``, which holds its held-out
    evaluation. ValueError, before anything is written, otherwise."""
    import re

    from ..io import load_npz, save_npz, write_json
    model = Path(model)
    if not re.fullmatch(r"[a-z0-9_]+", name):
        raise ValueError(f"ship: name must be lowercase letters, digits and '_' (the file "
                         f"name in minid3rqn/models); got {name!r}")
    arrays, meta = load_npz(model)
    meta = meta or {}
    if "dispnet" in meta:
        if "results" not in meta or "command" not in meta:
            raise ValueError(f"ship: {str(model)!r} holds no held-out evaluation; ship the "
                             f"model.npz a finished train-depth run writes")
        about = {k: v for k, v in meta.items() if k not in ("dispnet", "scale", "height",
                                                             "width")}
    else:
        about = {**_finished_qnet(model, meta), "evaluations": _evaluations(model, records)}
    path = save_npz(MODELS / f"{name}.npz", arrays, meta)
    write_json(path.with_suffix(".json"), about)
    return path


def _finished_qnet(model: Path, meta: dict) -> dict:
    """What the JSON beside a shipped Q-net says of its making; ValueError for a file
    that is no Q-net of a finished run."""
    if "qnet_config" not in meta:
        raise ValueError(f"ship: {str(model)!r} is neither a Q-net nor a depth model file")
    total = _trained(meta).get("steps")
    if "command" not in meta or total is None or meta.get("steps", 0) < total:
        raise ValueError(f"ship: {str(model)!r} is not the model of a finished run (at "
                         f"{meta.get('steps')} of {total} steps); finish it with --resume")
    keys = ("kind", "qnet_config", "command", "depth_model", "seed", "machine",
            "train_seconds")
    return {k: meta[k] for k in keys if k in meta}


def _evaluations(model: Path, records) -> list[dict]:
    """The ``evaluate --json`` records of ``model`` as the rows of a shipped JSON;
    ValueError if there is none."""
    rows = []
    for r in records:
        if len(ensemble_members(r.get("spec", "+"))) > 1 or r.get("unfinished"):
            continue
        if Path(r["spec"]).resolve() != model.resolve():
            continue
        rows.append({"scenario": r["scenario"], "depth": r["depth"], "flights": r["flights"],
                     "seed": r["seed"], "rate": r["rate"],
                     "ci95": [r["ci_low"], r["ci_high"]], "command": r["command"],
                     "worlds": r["worlds"], "ci95_by_world": [r["ci_low_worlds"],
                                                              r["ci_high_worlds"]],
                     "design_effect": r["design_effect"], "worlds_set":
                         "train" if r.get("worlds_set") == "train" else
                         "test" if r["seed"] == TEST_WORLDS else "validation",
                     "mirror": r["mirror"], "flip_tta": r["depth_flip"]})
    if not rows:
        raise ValueError(f"ship: no recorded evaluation of {str(model)!r}; give the records "
                         f"of `python -m minid3rqn evaluate {model} --json FILE`")
    return rows


# -- recorded results (the JSON beside a shipped model) --------------------------------------
def recorded_result(model, scenario: str, depth: str, mirror: bool = False,
                    flip_tta: bool = False) -> dict | None:
    """The largest evaluation of ``scenario`` on ``depth`` depth recorded in the JSON beside
    a model file (its ``evaluations``), flown as asked: with the mirror image and the
    DispNet's flip or without (a row without those keys was flown without them).
    ValueError if that JSON is not such a record."""
    path = Path(model).with_suffix(".json")
    if not path.is_file():
        return None
    try:
        rows = [r for r in json.loads(path.read_text()).get("evaluations", [])
                if r.get("scenario") == scenario and r.get("depth") == depth
                and r.get("mirror", False) == mirror and r.get("flip_tta", False) == flip_tta]
        row = max(rows, key=lambda r: r["flights"]) if rows else None
        if row is not None:
            recorded_text(row)
    except (AttributeError, KeyError, TypeError, ValueError, IndexError):
        raise ValueError(f"{path.name} beside the model is not a readable record of its "
                         f"evaluations") from None
    return row


def recorded_text(row: dict) -> str:
    """One recorded evaluation in words: the rate, Wilson's interval by flight, and the
    interval by world when the row has it."""
    text = f"{row['rate']:.3f}, 95% CI [{row['ci95'][0]:.3f}, {row['ci95'][1]:.3f}] by flight"
    if row.get("ci95_by_world"):
        lo, hi = row["ci95_by_world"]
        text += f", [{lo:.3f}, {hi:.3f}] by world ({row['worlds']} worlds)"
    return text + f", over {row['flights']} flights (seed {row['seed']})"
