"""Command-line hooks: ``collect``, ``train-depth``, ``eval-depth``.

    python -m minid3rqn collect --scenario basic --frames 5000 --seed 0
    python -m minid3rqn train-depth --scenario basic --seed 0
    python -m minid3rqn eval-depth --model minid3rqn/models/depth_basic.npz --scenario basic

The options come from the configs: ``data.CollectConfig`` (the frames) and
``train.TrainConfig`` (the training, with ``losses.LossConfig``). Files, unless given:
``runs/depth/<scenario>/train.npz`` and ``test.npz`` (held-out flights in other worlds,
seed + 1000), ``checkpoint.npz``, ``model.npz``, ``results.json`` and ``pictures.png``
in the same folder. ``train-depth`` collects the frames it needs when the files are
missing, so one command reproduces a result, and ``--scenario channel`` (or
intersections, corners) is the scenario transfer: the same command retrains the depth
network on that scenario's frames.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import fields
from pathlib import Path

from ..config import (UsageError, add_arguments, add_existing_option, as_dict, flat_settings,
                      from_args, setting_names)
from ..io import (MODELS, WriteError, check_new_file, check_output, claim_run_folder, hold,
                  holding, load_npz, read_metadata, reason, whole, write_json)
from .data import CollectConfig, Sequence, collect_sequence, held_out, load_sequence
from .train import TrainConfig, check_resume, other_frames, recorded_data, train_depth

RUNS = Path("runs/depth")


def _options(args: argparse.Namespace, cls, other=None) -> argparse.Namespace:
    """The parsed options of config ``cls`` alone (one parser may hold two configs, ``cls``
    and ``other``: each ``--set NAME=VALUE`` goes to the one that has NAME)."""
    names = {f.name for f in fields(cls)}
    kept = {k: v for k, v in vars(args).items()
            if k.startswith("cfg__") and k.split("__")[1] in names}
    own = setting_names(cls)
    sets = [item for item in getattr(args, "cfg_set", None) or []
            if item.partition("=")[0] in own
            or other is None or item.partition("=")[0] not in setting_names(other)]
    return argparse.Namespace(**kept, cfg_set=sets)


# -- collect -----------------------------------------------------------------------------
def _frames_file(path, option: str, scenario: str | None = None, role: str = "test",
                 pose: bool = False) -> Sequence:
    """An existing file given as frames: one written by ``collect`` (of ``scenario``, if
    given: the one the command is about) that can serve as training frames (``role``
    "train": triplets; the poses too, with ``pose``) or held-out ones ("test": finite
    ground-truth depth); UsageError if not. Returns the frames."""
    import zipfile

    import numpy as np
    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        names = None
    if names is None or not {"rgb", "flight", "K"} <= names:
        what = "is not a readable .npz file" if names is None else "holds no frames"
        raise UsageError(f"{option}: {str(path)!r} {what} (expected a file written by "
                         f"collect)")
    try:                            # shapes, types and lengths that agree (Sequence)
        seq = load_sequence(path)
    except (KeyError, TypeError, ValueError) as e:
        raise UsageError(f"{option}: {str(path)!r} {reason(e).removeprefix('Sequence: ')}") \
            from None
    if role == "test" and (seq.depth is None or not np.isfinite(seq.depth).all()):
        raise UsageError(f"{option}: {str(path)!r} holds no finite ground-truth depth to "
                         f"score against")
    if role == "train" and not len(seq.triplet_indices()):
        raise UsageError(f"{option}: {str(path)!r} holds no triplet (three consecutive frames "
                         f"of one flight); collect longer flights")
    if role == "train" and pose and seq.pose is None:
        raise UsageError(f"{option}: {str(path)!r} records no poses, which gyro_yaw reads")
    filmed = seq.meta.get("scenario") if isinstance(seq.meta, dict) else None
    if scenario and filmed and filmed != scenario:
        raise UsageError(f"{option}: {str(path)!r} holds frames of {filmed}, not {scenario}; "
                         f"give --scenario {filmed}")
    return seq


def add_arguments_collect(p: argparse.ArgumentParser) -> None:
    add_arguments(p, CollectConfig)
    p.add_argument("--out", default=None,
                   help="output .npz (default runs/depth/<scenario>/train.npz)")
    add_existing_option(p)


def run_collect(args) -> int:
    cfg = from_args(CollectConfig, args)
    out = check_output(args.out or RUNS / cfg.scenario / "train.npz", "--out", suffix=".npz")
    with hold(out, "--out"):
        check_new_file(out, "--out", ".npz", args.existing)
        t0 = time.time()
        seq = collect_sequence(cfg, out)
    print(f"collect: {len(seq)} frames in {int(seq.flight.max()) + 1} flights -> {out} "
          f"({time.time() - t0:.1f} s)")
    return 0


# -- train-depth ---------------------------------------------------------------------------
# The frames of a train-depth run come from collect's settings; their seed is the run's.
TRAIN_DATA_HIDDEN = ("seed", "frames_per_flight")


def add_arguments_train_depth(p: argparse.ArgumentParser) -> None:
    add_arguments(p, CollectConfig, hide=TRAIN_DATA_HIDDEN)
    add_arguments(p, TrainConfig)
    p.add_argument("--dir", default=None, help="run folder (default runs/depth/<scenario>)")
    p.add_argument("--data", default=None, help="training .npz (collected there if missing; "
                                                "default <dir>/train.npz)")
    p.add_argument("--test-data", default=None, help="held-out .npz (collected there if "
                                                     "missing; default <dir>/test.npz)")
    p.add_argument("--init-from", default=None,
                   help="fine-tune: start from this checkpoint or model file's DispNet "
                        "(e.g. minid3rqn/models/depth_basic.npz)")
    add_existing_option(p, grows="--iterations")


# What a train-depth run writes in its folder (--overwrite deletes them; the frames stay)
DEPTH_OUTPUTS = ("checkpoint.npz", "model.npz", "results.json", "pictures.png", "curve.csv",
                 "curve.png")
FINISHED = ("model.npz", "results.json", "pictures.png")    # a finished run's files


def _check_init_from(path) -> None:
    """--init-from: a depth model file or a train-depth checkpoint."""
    if not Path(path).is_file():
        raise UsageError(f"--init-from: no file {path!r}")
    try:
        meta = read_metadata(path) or {}
    except ValueError as e:
        raise UsageError(f"--init-from: {e}") from None
    if "dispnet" not in meta and not ("config" in meta and "iteration" in meta):
        raise UsageError(f"--init-from: {path!r} is neither a depth model nor a train-depth "
                         f"checkpoint")
    from ..nets.module import check_finite
    from .evaluate import DepthEstimator
    try:                    # before any frame is collected: weights that can start a run
        if "dispnet" in meta:
            DepthEstimator.load(path)
        else:
            check_finite({k: v for k, v in load_npz(path)[0].items()
                          if k.startswith(("disp.", "pose."))}, path)
    except ValueError as e:
        raise UsageError(f"--init-from: {str(e).removeprefix('DepthEstimator.load: ')}") \
            from None


def _check_frames(args, cfg: TrainConfig, data: CollectConfig, run_dir: Path) -> list:
    """The frames a run reads: given files hold frames, or can be made there; the run's
    own files (in --dir) hold the frames of these settings, or (with --overwrite) are
    returned, to be deleted and collected anew."""
    if args.data and args.test_data and Path(args.data).resolve() == Path(args.test_data).resolve():
        raise UsageError(f"--test-data: {args.test_data!r} is the --data file; the held-out "
                         f"frames must be other frames")
    stale = []
    for option, given, default, want, role in (
            ("--data", args.data, run_dir / "train.npz", data, "train"),
            ("--test-data", args.test_data, run_dir / "test.npz",
             held_out(data, cfg.test_frames), "test")):
        path = Path(given or default)
        if not path.is_file():
            check_output(path, option, suffix=".npz")
            continue
        _frames_file(path, option if given else "--dir", data.scenario, role, cfg.gyro_yaw)
        problem = None if given else other_frames(path, want)
        if problem and args.existing != "overwrite":
            raise UsageError(f"--dir: {problem}; give --overwrite to collect them anew, or "
                             f"{option} FILE")
        stale += [path] if problem else []
    return stale


def _claim_depth_run(args, cfg: TrainConfig, run_dir: Path) -> str:
    """``io.claim_run_folder`` for --dir; with --resume, the checkpoint must be of these
    settings. Returns "new", "resume" or "finished" (nothing to do; said on stderr)."""
    inputs = {"--init-from": [args.init_from], "--data": [args.data],
              "--test-data": [args.test_data]}
    if not claim_run_folder(run_dir, args.existing, "--dir", DEPTH_OUTPUTS, inputs=inputs):
        return "new"
    train = recorded_data(args.data or run_dir / "train.npz", run_dir)
    settings = {**flat_settings(as_dict(cfg)), "data": train}
    try:
        meta = read_metadata(run_dir / "checkpoint.npz")
        check_resume(meta, settings, run_dir / "checkpoint.npz")
    except ValueError as e:
        raise UsageError(f"--resume: {str(e).removeprefix('resume: ')}") from None
    if meta["iteration"] >= cfg.iterations and all(whole(run_dir / name)
                                                   for name in FINISHED):
        print(f"the run in {str(run_dir)!r} has finished ({meta['iteration']} of "
              f"{cfg.iterations} iterations); nothing to do (--resume with more "
              f"--iterations trains it on)", file=sys.stderr)
        return "finished"
    return "resume"


def run_train_depth(args) -> int:
    cfg = from_args(TrainConfig, _options(args, TrainConfig, CollectConfig))
    data = from_args(CollectConfig, _options(args, CollectConfig, TrainConfig), seed=cfg.seed)
    if args.init_from:
        _check_init_from(args.init_from)
    run_dir = Path(args.dir or RUNS / data.scenario)
    check_output(run_dir, "--dir", folder=True)
    collected = [(p, o) for p, o in ((args.data, "--data"), (args.test_data, "--test-data"))
                 if p and not Path(p).is_file()]          # frames this run collects there
    for path, option in collected:
        check_output(path, option, suffix=".npz")
    with holding((run_dir, "--dir"), *collected):
        stale = _check_frames(args, cfg, data, run_dir)
        how = _claim_depth_run(args, cfg, run_dir)
        if how == "finished":
            return 0
        for path in stale:                   # --overwrite: frames of other settings go
            path.unlink()
        try:
            train_depth(cfg, data, run_dir, args.data, args.test_data, args.init_from,
                        resume=how == "resume", progress=sys.stderr.isatty())
        except WriteError as e:          # what was measured is said before the error
            if getattr(e, "measured", None):
                _trained_depth(e.measured)
            raise
    _trained_depth(json.loads((run_dir / "results.json").read_text()))
    return 0


def _trained_depth(meta: dict) -> None:
    """What train-depth prints: its held-out results, as one JSON line."""
    print(json.dumps({"scenario": meta["scenario"], "seed": meta["seed"],
                      "train_seconds": meta["train_seconds"],
                      **{k: round(v, 4) for k, v in meta["results"].items()}}))


# -- eval-depth ------------------------------------------------------------------------------
def add_arguments_eval_depth(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default=str(MODELS / "depth_basic.npz"),
                   help="depth model file (default: the shipped basic DispNet, "
                        "minid3rqn/models/depth_basic.npz, found from any directory)")
    add_arguments(p, CollectConfig, hide=tuple(f.name for f in fields(CollectConfig)
                                               if f.name != "scenario"))
    p.add_argument("--test-data", default=None,
                   help="held-out .npz (default runs/depth/<scenario>/test.npz, collected "
                        "there if missing: the held-out frames of train-depth --seed 0)")
    p.add_argument("--flip-tta", action="store_true",
                   help="average the disparity with its value on the mirrored frame, "
                        "mirrored back (test-time flip)")
    p.add_argument("--pictures", default=None, help="PNG: RGB | predicted | GT rows")
    p.add_argument("--json", default=None, help="write the metrics to this .json file")
    add_existing_option(p)


def run_eval_depth(args) -> int:
    if not Path(args.model).is_file():
        raise UsageError(f"--model: no file {args.model!r}")
    data = from_args(CollectConfig, _options(args, CollectConfig))
    outputs = [(out, option) for option, out, suffix in (("--json", args.json, ".json"),
                                                        ("--pictures", args.pictures, ".png"))
               if out and check_output(out, option, suffix=suffix)]
    path = Path(args.test_data or RUNS / data.scenario / "test.npz")
    if not path.is_file():
        check_output(path, "--test-data", suffix=".npz")
    with holding(*outputs, (None if path.is_file() else path, "--test-data")):
        for out, option in outputs:
            check_new_file(out, option, Path(out).suffix, args.existing)
        return _eval_depth(args, data, path)


def _eval_depth(args, data: CollectConfig, path: Path) -> int:
    import numpy as np

    from .evaluate import DepthEstimator, comparison_picture, errors_by_depth, evaluate
    from .flip import FlipAveraged
    test = None
    if path.is_file():              # of the --scenario asked for, if one is
        test = _frames_file(path, "--test-data", getattr(args, "cfg__scenario", None))
        problem = None if args.test_data else other_frames(path, held_out(data))
        if problem:                 # the default file: train-depth --seed 0's held-out
            raise UsageError(f"--test-data: {problem}; give --test-data FILE")
    else:
        check_output(path, "--test-data", suffix=".npz")
    try:
        estimator = DepthEstimator.load(args.model)
    except ValueError as e:
        raise UsageError(f"--model: {str(e).removeprefix('DepthEstimator.load: ')}") from None
    if args.flip_tta:
        estimator = FlipAveraged(estimator)
    test = test if test is not None else collect_sequence(held_out(data), path)
    t0 = time.time()
    results = evaluate(estimator, test)
    results["seconds"] = round(time.time() - t0, 2)
    rows = errors_by_depth(estimator.predict(test.rgb), test.depth)   # where the errors are
    print("GT depth (m)   share   abs rel   signed rel (> 0: too far)   [median-scaled]")
    for r in rows:
        print(f"{r['from_m']:4.0f} - {r['to_m']:<4.0f}    {r['share']:.2f}    "
              f"{r['abs_rel']:.3f}     {r['signed_rel']:+.3f}")
    results["by_depth"] = rows
    results = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in results.items()}
    print(json.dumps(results))           # said first: a failed write loses no number
    if args.pictures:
        rows = np.linspace(0, len(test) - 1, 6).astype(int)
        comparison_picture(test.rgb[rows], estimator.predict(test.rgb[rows]),
                           test.depth[rows], args.pictures)
    if args.json:
        write_json(args.json, results)
    return 0
