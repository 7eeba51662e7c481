"""``python -m minid3rqn sweep``: one training configuration, several seeds.

How much of a success rate is the recipe and how much the luck of one training seed?
Each seed's net is trained as ``train-agent --seed S`` would train it (into
``--out/s<S>``), then flown on the same test flights (``evaluate``, seed
``eval_seed``); the table gives each seed's rate with its intervals, and the spread
across seeds: their mean, standard deviation (n - 1) and range. A seed's intervals say
how sure its flights make us of *that net's* rate; the spread says how much another
seed would change it.

Each seed is one task (train, then fly), run ``workers`` at a time with ``executor``
(``minid3rqn/executor.py``: this machine's processes, or Ray). A sweep stopped (Ctrl-C,
SIGTERM, a lost node) and started again with the same command goes on from its runs:
a finished seed is kept with its evaluation, an unfinished one resumes from its
checkpoint; a finished run's checkpoint (the whole replay) is removed.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..config import at_least, command_line, setting, shell_command, validate
from ..executor import EXECUTORS, get_executor
from ..io import write_file, write_json
from .evaluate import TEST_WORLDS, EvalConfig, evaluate_spec
from .train import TrainConfig


def _seed_list(v):
    whole = all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in v)
    return None if v and whole and len(set(v)) == len(v) else \
        "different whole numbers >= 0 joined by ',' (e.g. 0,1,2,3)"


@dataclass
class SweepConfig:
    seeds: list = setting(default_factory=lambda: [0, 1, 2, 3],
                          help="training seeds, joined by ','", source="run", check=_seed_list)
    flights: int = setting(500, "test flights per seed", source="run", check=at_least(1))
    eval_seed: int = setting(TEST_WORLDS, "the test flights' seed (the same for every "
                                          "seed)", check=at_least(0))
    workers: int = setting(1, "seeds trained at a time, one process per core (run with "
                              "OMP_NUM_THREADS=1)", source="run", check=at_least(1))
    executor: str = setting("local", "where the seeds train: processes of this machine "
                                     "(--workers), or Ray tasks on the cluster ray.init() "
                                     "finds (RAY_ADDRESS; --out on storage shared by every "
                                     "node)", source="run", choices=EXECUTORS)
    train: TrainConfig = setting(default_factory=TrainConfig)

    def __post_init__(self):
        validate(self)


def eval_config(cfg: SweepConfig, depth_model) -> EvalConfig:
    """How every seed's net is flown: on its training worlds' scenario and depth."""
    t = cfg.train
    return EvalConfig(scenario=t.scenario, flights=cfg.flights, seed=cfg.eval_seed,
                      depth=t.depth, depth_model=str(depth_model) if t.depth == "pred" else "")


def _evaluation(model: Path, ecfg: EvalConfig, depth_model) -> dict:
    """The record of ``evaluate MODEL`` with ``ecfg``: kept in ``evaluation.json`` beside
    the model, and flown again only if the model or the evaluation changed."""
    from ..io import read_metadata
    from .models import load_depth_estimator
    made = read_metadata(model)["command"]
    command = shell_command(["evaluate", str(model), *command_line(EvalConfig, ecfg)])
    kept = model.parent / "evaluation.json"
    if kept.is_file():
        try:
            old = json.loads(kept.read_text())
            if old.get("model_command") == made and old["record"]["command"] == command:
                return old["record"]
        except (ValueError, KeyError, TypeError):
            pass                          # unreadable: flown again
    est = load_depth_estimator(depth_model) if ecfg.depth == "pred" else None
    record = evaluate_spec(str(model), ecfg, est, progress=False)[1]
    write_json(kept, {"model_command": made, "record": record}, indent=1)
    return record


def _seed_task(progress: bool, task) -> dict:
    """One seed: train (or resume, or keep) its net, then its evaluation record."""
    from .reproduce import _train_qnet
    train_cfg, run_dir, depth_model, ecfg = task
    model = _train_qnet(train_cfg, run_dir, depth_model, progress=progress)
    (Path(run_dir) / "checkpoint.npz").unlink(missing_ok=True)
    return _evaluation(model, ecfg, depth_model)


def check_runs(cfg: SweepConfig, out: Path, depth_model) -> None:
    """ValueError if a seed's folder holds a finished run that is not this sweep's (it
    would be trained over)."""
    from ..io import read_metadata
    from .models import command_for
    for seed in cfg.seeds:
        run_dir = out / f"s{seed}"
        model = run_dir / "model.npz"
        if not model.is_file() or (run_dir / "checkpoint.npz").is_file():
            continue                      # nothing, or a run --resume checks itself
        try:
            made = (read_metadata(model) or {}).get("command")
        except ValueError:
            made = None
        mine = command_for(replace(cfg.train, seed=seed), run_dir, depth_model)
        if made != mine:
            raise ValueError(f"{str(run_dir)!r} holds a finished run of other settings "
                             f"({made or 'no command recorded'}); give another --out")


def spread(rates) -> dict:
    """Mean, standard deviation (n - 1; None for one seed) and range of the rates."""
    r = np.asarray(rates, dtype=np.float64)
    return {"seeds": len(r), "mean": float(r.mean()),
            "sd": float(r.std(ddof=1)) if len(r) > 1 else None,
            "min": float(r.min()), "max": float(r.max())}


def sweep(cfg: SweepConfig, out: Path, depth_model=None, progress: bool = True) -> dict:
    """Train and fly every seed of ``cfg`` (module docstring) into ``out``; writes and
    returns the results (results.json, results.md: the table)."""
    from .models import command_for, shipped_depth_model
    t = cfg.train
    if t.depth == "pred":
        depth_model = depth_model or shipped_depth_model(t.scenario)
    else:
        depth_model = None
    out = Path(out)
    check_runs(cfg, out, depth_model)
    executor = get_executor(cfg.executor, cfg.workers)
    ecfg = eval_config(cfg, depth_model)
    tasks = [(replace(t, seed=s), out / f"s{s}", depth_model, ecfg) for s in cfg.seeds]
    serial = executor.name == "local" and min(cfg.workers, len(tasks)) <= 1
    bar = None
    if progress and not serial:            # a bar over the seeds finished
        from tqdm import tqdm
        bar = tqdm(total=len(tasks), unit="seed", desc=f"sweep {t.variant}",
                   dynamic_ncols=True)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    try:
        records = executor.run(_seed_task, tasks, serial and progress,
                               on_result=None if bar is None else lambda i, r: bar.update(),
                               check_folders=[out])
    finally:
        if bar is not None:
            bar.close()
    words = ["sweep", *command_line(SweepConfig, cfg)]
    if depth_model and t.depth == "pred":
        words += ["--depth-model", str(depth_model)]
    results = {"variant": t.variant, "scenario": t.scenario, "depth": t.depth,
               "command": shell_command(words + ["--out", str(out)]),
               "train_command": command_for(tasks[0][0], tasks[0][1], depth_model),
               "seconds": round(time.time() - t0, 1), "flights": cfg.flights,
               "eval_seed": cfg.eval_seed, "seeds": cfg.seeds, "runs": records,
               "spread": spread([r["rate"] for r in records])}
    text = sweep_table(results)
    print("\n" + text)                      # said first: a failed write loses no number
    write_json(out / "results.json", results)
    write_file(out / "results.md", text)
    return results


def sweep_table(results: dict) -> str:
    """Each seed's rate and intervals, then the spread across seeds."""
    from .reproduce import intervals
    from .models import VARIANT_NAMES
    runs, s = results["runs"], results["spread"]
    name = VARIANT_NAMES.get(results["variant"], results["variant"])
    lines = [f"Seed sweep: {name} in {results['scenario']} on {results['depth']} "
             f"depth, {results['flights']} test flights per seed (seed "
             f"{results['eval_seed']})", "",
             "| training seed | success rate | 95% CI by flight | by world |",
             "|---|---|---|---|"]
    lines += [f"| {seed} | {r['rate']:.3f} | {intervals(r)} |"
              for seed, r in zip(results["seeds"], runs)]
    sd = "" if s["sd"] is None or not math.isfinite(s["sd"]) else f" ± {s['sd']:.3f}"
    lines += ["", f"Across {s['seeds']} seeds: mean {s['mean']:.3f}{sd} (standard "
              f"deviation), range {s['min']:.3f}-{s['max']:.3f}.", "",
              f"Seed {results['seeds'][0]} (each seed's model.npz records its own "
              f"command): {results['train_command']}",
              f"All: {results['command']}"]
    return "\n".join(lines) + "\n"
