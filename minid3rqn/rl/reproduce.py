"""``python -m minid3rqn reproduce``: Tables 5 and 6 end to end.

    1. depth: train a DispNet on basic (v1), fine-tune it with the full-resolution loss
       on a late-turning pilot's frames, then longer on three times as many of them
       (the one the Q-nets read in basic), and fine-tune that one the same way
       (full-resolution loss, a late-turning pilot's frames) in channel, intersections
       and corners (the shipped recipe, docs/depth.md section 7), unless
       ``--skip-depth`` (then the shipped ``models/depth_<scenario>.npz``);
    2. Table 5: train the Q-family on ``basic`` on ground-truth depth (same budget and
       seed for every model: D3RQN, DDRQN, D3QN, DDQN, and the non-recurrent pair with
       5 stacked frames; the shipped D3RQN's 240k-transition recipe), then, for
       ``--depth pred``, fine-tune each on the basic DispNet's depth (20k transitions,
       as the shipped model); evaluate them with Straight, Random, Reactive and the
       Oracle on fresh worlds;
    3. Table 6: the D3RQN from step 2, unchanged, in channel / intersections / corners,
       reading the depth net trained there.

Everything lands in ``--out`` (results.json, results.md, one folder per run).
``--quick`` shrinks every budget (minutes, for a classroom; the numbers are then only
a smoke test of the pipeline).

``--recipe distil`` runs instead our recipe for one D3RQN that flies ``basic`` at 0.95
on predicted depth (``reproduce_distilled``; docs/experiments.md, "A loss on the greedy
action"): not the paper's method, the way this project met its target.
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import time
from pathlib import Path

from .commands import (MODELS, add_arguments_train_agent, config_from_args,
                       load_depth_estimator, make_policy, run_name)
from .evaluate import evaluate_policy
from .train import train

PAPER_T5 = {"Straight": 0.0, "Random": 0.002, "DDQN": 0.137, "D3QN": 0.152, "DDRQN": 0.673,
            "D3RQN": 0.994}
PAPER_T6 = {"channel": {"Straight": 0.0, "Random": 0.003, "D3RQN": 0.923},
            "intersections": {"Straight": 0.0, "Random": 0.001, "D3RQN": 0.968},
            "corners": {"Straight": 0.0, "Random": 0.0, "D3RQN": 0.938}}
TRANSFER = ("channel", "intersections", "corners")
FAMILY = ("d3rqn", "ddrqn", "d3qn", "ddqn", "d3qn:5", "ddqn:5")

# Q-nets: ``steps`` transitions on GT depth (the shipped 240k recipe, docs/results.md),
# then ``finetune_steps`` on predicted depth when the tables are on predicted depth.
# The distilled recipe (``--recipe distil``) adds its two stages: ``stage1_steps`` on GT
# depth, ``stage2_steps`` on predicted depth, each learning from ``stage_learning_starts``.
FULL = dict(steps=240_000, updates_per_step=2.0, eps_decay=100_000, learning_starts=5000,
            finetune_steps=20_000, flights=2000, depth_frames=5000, depth_iterations=None,
            stage1_steps=20_000, stage2_steps=40_000, stage_learning_starts=2000,
            val_flights=500)
QUICK = dict(steps=3_000, updates_per_step=4.0, eps_decay=2_500, learning_starts=500,
             finetune_steps=1_000, flights=200, depth_frames=600, depth_iterations=300,
             stage1_steps=1_000, stage2_steps=2_000, stage_learning_starts=200,
             val_flights=100)


# The shipped depth recipe (docs/depth.md, sections 5 and 7): basic from scratch with the
# simulated gyro's yaw, heads starting far (10 m) and the soft auto-mask; each transfer
# scenario fine-tunes the basic DispNet on its own frames. Both with an lr step (x 0.1):
# (iterations, step at).
DEPTH_RECIPE = {"gyro_yaw": True, "init_disp": 0.1, "unmasked_weight": 0.1}
DEPTH_SCHEDULE = {"basic": (6000, 4500), "transfer": (3000, 2000), "long": (10000, 7000)}
# The shipped basic DispNet (v5) is v1 fine-tuned (the transfer schedule) with the
# full-resolution loss on frames of a late-turning pilot, then (the long schedule) on
# three times as many fresh such frames (docs/depth.md section 7; the shipped one went
# through one more plain fine-tune, v2, before the first, and its long stage's frames
# were collected with seed 2; here they share the seed, so the first third of them are
# the previous stage's frames). Each transfer DispNet fine-tunes that last basic one the
# same way (the transfer schedule) on its own world's late-turning frames.
BASIC_FINETUNE = {"full_res": True, "late_turns": 0.5}


def _train_depth(scenario: str, out: Path, seed: int, budget: dict,
                 init_from: Path | None = None, name: str | None = None,
                 extra: dict | None = None, schedule: str | None = None,
                 frames_factor: int = 1) -> Path:
    """Train (``init_from`` None) or fine-tune a DispNet in ``out/depth/<name>``, with
    ``extra`` settings over DEPTH_RECIPE; ``schedule`` a key of DEPTH_SCHEDULE (default:
    basic from scratch, transfer for a fine-tune); ``frames_factor`` x the budget's
    frames."""
    from ..depth.data import CollectConfig
    from ..depth.losses import LossConfig
    from ..depth.train import TrainConfig, train_depth
    schedule = schedule or ("basic" if init_from is None else "transfer")
    iterations, decay_at = DEPTH_SCHEDULE[schedule]
    if budget["depth_iterations"]:                    # --quick: the same shape, shorter
        iterations = budget["depth_iterations"]
        decay_at = iterations * 3 // 4
    frames, test_frames = budget["depth_frames"] * frames_factor, 500
    if budget.get("smoke"):                           # tests: seconds
        frames, test_frames, iterations = min(frames, 60), 30, min(iterations, 3)
    s = {**DEPTH_RECIPE, **(extra or {})}
    cfg = TrainConfig(iterations=iterations, lr_decay_at=decay_at, seed=seed,
                      init_disp=s["init_disp"], gyro_yaw=s["gyro_yaw"], test_frames=test_frames,
                      loss=LossConfig(unmasked_weight=s["unmasked_weight"],
                                      full_res=s.get("full_res", False)))
    data = CollectConfig(scenario=scenario, frames=frames, seed=seed,
                         late_turns=s.get("late_turns", 0.0))
    return train_depth(cfg, data, out / "depth" / (name or scenario), init_from=init_from)


def _train_agent(spec: str, out: Path, seed: int, budget: dict, train_depth: str, depth_model,
                 init_model: Path | None = None) -> Path:
    """Train one Q-net of the family: from scratch (``budget["steps"]``, the shipped
    240k recipe), or, with ``init_model``, fine-tune that one on ``train_depth``
    (``budget["finetune_steps"]``, the shipped fine-tune: docs/results.md)."""
    variant, _, stack = spec.partition(":")
    p = argparse.ArgumentParser()
    add_arguments_train_agent(p)
    argv = ["--variant", variant, "--seed", str(seed), "--depth", train_depth]
    if init_model is None:
        argv += ["--steps", str(budget["steps"]),
                 "--learning-starts", str(budget["learning_starts"]),
                 "--eps-decay", str(budget["eps_decay"]), "--replay", "100000",
                 "--updates-per-step", str(budget["updates_per_step"])]
    else:
        steps = budget["finetune_steps"]
        argv += ["--steps", str(steps), "--learning-starts", str(steps // 10),
                 "--eps-start", "0.2", "--eps-decay", str(steps * 2 // 5),
                 "--replay", "60000", "--updates-per-step", "4.0",
                 "--init-model", str(init_model)]
    if stack:
        argv += ["--stack", stack]
    if budget.get("smoke"):                           # tests: seconds
        argv.append("--smoke")
    args = p.parse_args(argv)
    cfg = config_from_args(args)
    run_dir = out / "agent" / (run_name(cfg) + ("" if init_model is None else "_finetuned"))
    est = load_depth_estimator(depth_model) if train_depth == "pred" else None
    tr = train(cfg, run_dir, depth_estimator=est, progress=True, resume=True)
    return tr.save_model(run_dir / "model.npz", {"command": "reproduce " + " ".join(argv),
                                                  "seed": seed})


def _depth_models(out: Path, seed: int, budget: dict, scenarios, skip_depth: bool) -> dict:
    """The DispNet of each scenario: the shipped recipe run in ``out/depth`` (module
    docstring, step 1), or with ``skip_depth`` the shipped ``models/depth_<scenario>.npz``."""
    depth_models = {}
    for sc in scenarios:                 # basic first: the transfer nets start from it
        if skip_depth:
            depth_models[sc] = MODELS / f"depth_{sc}.npz"
        elif sc == "basic":              # v1, then the shipped fine-tunes of it
            depth_models["basic_v1"] = _train_depth(sc, out, seed, budget)
            finetuned = _train_depth(sc, out, seed, budget, init_from=depth_models["basic_v1"],
                                     name="basic_finetuned", extra=BASIC_FINETUNE)
            depth_models[sc] = _train_depth(sc, out, seed, budget, init_from=finetuned,
                                            name="basic_long", extra=BASIC_FINETUNE,
                                            schedule="long", frames_factor=3)
        else:                            # the transfer nets start from basic's last one
            depth_models[sc] = _train_depth(sc, out, seed, budget,
                                            init_from=depth_models["basic"],
                                            extra=BASIC_FINETUNE)
    return depth_models


def reproduce(out: Path, quick: bool = False, seed: int = 0, depth: str = "pred",
              skip_depth: bool = False, tables: str = "both", train_depth: str = "gt",
              workers: int = 1, budget: dict | None = None) -> dict:
    """Run the pipeline of the module docstring; ``budget`` (tests) overrides the
    preset's entries."""
    budget = {**(QUICK if quick else FULL), **(budget or {})}
    out = out / "quick" if quick else out      # never resume a full run from a quick one
    out.mkdir(parents=True, exist_ok=True)
    results = {"budget": budget, "seed": seed, "depth": depth, "table5": [], "table6": [],
               "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    scenarios = ["basic"] + (list(TRANSFER) if tables in ("6", "both") else [])
    depth_models = {}
    if depth == "pred" or train_depth == "pred":
        depth_models = _depth_models(out, seed, budget, scenarios, skip_depth)
    models = {}
    finetune = depth == "pred" and train_depth == "gt" and budget["finetune_steps"] > 0
    for spec in FAMILY if tables in ("5", "both") else ("d3rqn",):
        models[spec] = _train_agent(spec, out, seed, budget, train_depth,
                                    depth_models.get("basic"))
        if finetune:
            models[spec] = _train_agent(spec, out, seed, budget, "pred",
                                        depth_models["basic"], init_model=models[spec])

    def run_eval(policies, scenario):
        est = load_depth_estimator(depth_models[scenario]) if depth == "pred" else None
        rows = []
        for spec in policies:
            pol = make_policy(str(spec), seed)
            res = evaluate_policy(pol, scenario, budget["flights"], seed=12345 + seed,
                                  depth=depth, depth_estimator=est, workers=workers)
            print(res.line(), flush=True)
            rows.append(res.to_dict())
        return rows

    if tables in ("5", "both"):
        results["table5"] = run_eval(["straight", "random", "reactive", "oracle"]
                                     + [models[s] for s in FAMILY], "basic")
    if tables in ("6", "both"):
        for sc in TRANSFER:
            results["table6"] += run_eval(["straight", "random", "reactive", "oracle",
                                           models["d3rqn"]], sc)
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    (out / "results.json").write_text(json.dumps(results, indent=2))
    (out / "results.md").write_text(markdown_tables(results))
    print(markdown_tables(results))
    return results


def intervals(r: dict) -> str:
    """A row's two 95% intervals as two table cells: Wilson's by flight, and by world
    (``evaluate.clustered_interval``; blank in results written before it existed)."""
    lo, hi = r.get("ci_low_worlds"), r.get("ci_high_worlds")
    by_world = "" if lo is None or not math.isfinite(lo) else f"[{lo:.3f}, {hi:.3f}]"
    return f"[{r['ci_low']:.3f}, {r['ci_high']:.3f}] | {by_world}"


def markdown_tables(results: dict) -> str:
    lines = []
    note = ("95% intervals: Wilson's by flight, and by world (the flights share worlds; "
            "read this one, docs/d3rqn.md section 9)")
    if results.get("table5"):
        lines += ["Table 5 (basic): success rate over test flights", "", note, "",
                  "| model | ours | 95% CI by flight | by world | paper |",
                  "|---|---|---|---|---|"]
        for r in results["table5"]:
            paper = PAPER_T5.get(r["policy"])
            lines.append(f"| {r['policy']} | {r['rate']:.3f} | {intervals(r)} | "
                         f"{'' if paper is None else paper} |")
        lines.append("")
    if results.get("table6"):
        lines += ["Table 6 (transfer, Q-net from basic unchanged)", "", note, "",
                  "| scenario | model | ours | 95% CI by flight | by world | paper |",
                  "|---|---|---|---|---|---|"]
        for r in results["table6"]:
            paper = PAPER_T6.get(r["scenario"], {}).get(r["policy"])
            lines.append(f"| {r['scenario']} | {r['policy']} | {r['rate']:.3f} | "
                         f"{intervals(r)} | {'' if paper is None else paper} |")
    return "\n".join(lines) + "\n"


# -- the distilled recipe (ours) -----------------------------------------------------------
# Four parents trained as the shipped D3RQN's parent (240k transitions on GT depth): two
# seeds of the paper's torso, two of the wide one (conv channels 8, 16, 16); their
# ensemble is the teacher. Stage 1 grows the wide seed-0 parent's LSTM to 256 units and
# distils the teacher on GT depth; stage 2 goes on from it on the basic DispNet's depth,
# with mirrored replay windows and the KL term on the teacher's preferences. Each line
# is a ``train-agent`` command of docs/results.md with its budget filled in.
WIDE = ["--conv-channels", "8,16,16"]
PARENTS = (("parent_s0", 0, []), ("parent_s1", 1, []),
           ("parent_wide_s0", 0, WIDE), ("parent_wide_s1", 1, WIDE))
STUDENT = ["--lr", "1e-4", "--replay", "60000", "--updates-per-step", "4.0", "--hidden", "256",
           *WIDE, "--teacher-mix", "0.5"]
STAGE2 = ["--mirror-augment", "--distil-kl", "1", "--distil-temperature", "0.1"]
# The short chain (``--recipe distil-short``, ours), aimed at the 45 minutes of two
# cores: only the two wide parents (trained side by side), each half as long, with epsilon
# falling over the first 50k of their 120k transitions; the two stages as above.
SHORT = dict(steps=120_000, eps_decay=50_000)
# Both presets let epsilon fall over the first 5/12 of a parent's transitions (100k of 240k,
# 50k of 120k); ``--parent-steps`` keeps that share for any other length.
EPS_SHARE = 5 / 12


def parent_kinds(short: bool = False, wide_parents: int = 2) -> tuple:
    """The GT parents of a distilled recipe, (run name, seed offset, torso flags) each: the
    two paper-torso ones (the full recipe only), then ``wide_parents`` wide ones, seeds 0,
    1, ... (``--wide-parents``; both presets have two)."""
    if wide_parents < 1:
        raise ValueError(f"reproduce_distilled: wide_parents must be >= 1; got {wide_parents}")
    narrow = () if short else PARENTS[:2]
    return narrow + tuple((f"parent_wide_s{k}", k, WIDE) for k in range(wide_parents))


def _train_agent_cli(argv: list, run_dir: Path, budget: dict, quiet: bool = False) -> Path:
    """``python -m minid3rqn train-agent ARGV --out RUN_DIR``, resumed if it was cut off;
    returns the model file."""
    from .commands import run_train_agent
    p = argparse.ArgumentParser()
    add_arguments_train_agent(p)
    argv = [*argv, "--out", str(run_dir), "--resume"] + (["--smoke"] if budget.get("smoke") else [])
    print(f"\n== train-agent {' '.join(argv)}", flush=True)
    run_train_agent(p.parse_args(argv + (["--quiet"] if quiet else [])),
                    command=f"python -m minid3rqn train-agent {' '.join(argv)}  (by reproduce "
                            f"--recipe distil)")
    return run_dir / "model.npz"


def _train_agent_task(task) -> Path:
    return _train_agent_cli(*task, quiet=True)


def _train_all(tasks: list, workers: int) -> list:
    """Train independent runs (``_train_agent_cli``'s arguments each), ``workers`` at a
    time in forked processes (one per core, no progress bars; the same runs as one after
    the other: each is fixed by its own seed)."""
    if workers <= 1 or len(tasks) == 1 or "fork" not in mp.get_all_start_methods():
        return [_train_agent_cli(*t) for t in tasks]
    print(f"\n== {len(tasks)} runs, {min(workers, len(tasks))} at a time (no progress bars: "
          f"each prints a line per checkpoint): {', '.join(Path(t[1]).name for t in tasks)}",
          flush=True)
    with mp.get_context("fork").Pool(min(workers, len(tasks))) as pool:
        return pool.map(_train_agent_task, tasks, chunksize=1)


def _evaluate_cli(spec: str, scenario: str, budget: dict, seed: int, depth: str,
                  depth_model, workers: int, validation: bool = False,
                  mirror: bool = False) -> dict:
    """``python -m minid3rqn evaluate SPEC`` as on the command line; returns its record.
    ``validation``: ``budget["val_flights"]`` flights in the validation worlds;
    ``mirror``: each Q-net also flies the mirrored view (``--mirror``)."""
    from .commands import _estimator_for, add_arguments_evaluate, evaluate_one
    p = argparse.ArgumentParser()
    add_arguments_evaluate(p)
    flights = budget["val_flights"] if validation else budget["flights"]
    argv = [spec, "--scenario", scenario, "--flights", str(flights),
            "--seed", str(12345 + seed), "--depth", depth, "--workers", str(workers)]
    if validation:
        argv += ["--validation"]
    if mirror:
        argv += ["--mirror"]
    if depth == "pred":
        argv += ["--depth-model", str(depth_model)]
    args = p.parse_args(argv)
    est = _estimator_for(args.depth, args.depth_model, scenario)
    _, record = evaluate_one(spec, args, est)
    return {**record, "command": "python -m minid3rqn evaluate " + " ".join(argv)}


def distil_budget(quick: bool = False, short: bool = False, parent_steps: int | None = None,
                  budget: dict | None = None) -> dict:
    """The distilled recipes' budget: ``FULL`` (``QUICK``), with ``SHORT``'s parents for the
    short chain, then ``budget``'s entries (tests); ``parent_steps`` sets the parents'
    length and lets epsilon fall over ``EPS_SHARE`` of it."""
    if short and not quick:
        budget = {**SHORT, **(budget or {})}
    budget = {**(QUICK if quick else FULL), **(budget or {})}
    if parent_steps is not None:
        if parent_steps <= budget["learning_starts"]:
            raise ValueError(f"reproduce_distilled: parent_steps must exceed the parents' "
                             f"learning start ({budget['learning_starts']}); got {parent_steps}")
        budget = {**budget, "steps": parent_steps, "eps_decay": round(parent_steps * EPS_SHARE)}
    return budget


def reproduce_distilled(out: Path, quick: bool = False, seed: int = 0, students: int = 1,
                        skip_depth: bool = False, tables: str = "both", workers: int = 1,
                        budget: dict | None = None, short: bool = False,
                        parent_steps: int | None = None, start: str = "first",
                        wide_parents: int = 2, stage1: bool = True,
                        student_seq_len: int = 5, student_batch_size: int = 32) -> dict:
    """The distilled D3RQN end to end: the basic DispNet (and, for Table 6, the transfer
    ones) as in ``reproduce``, the four GT parents (``short``: the two wide ones at
    ``SHORT``'s budget; ``parent_steps``: that many transitions each, epsilon over
    ``EPS_SHARE`` of them; ``wide_parents``: that many wide ones, seeds 0, 1, ...,
    instead of two), stage 1 (``stage1=False``: none; stage 2 starts from the wide parent,
    its LSTM grown to 256 units as stage 1 would grow it), then ``students`` students of
    stage 2 (seeds ``seed``, ``seed`` + 1, ...), each flown on predicted depth in ``basic`` (and the
    transfer worlds), two or more students also together, each with its mirror image
    (``evaluate A+B --mirror``; ours), and the teacher on GT depth in ``basic``. Stage 1 grows a wide
    parent: ``start="first"`` the seed-``seed`` one (every run in docs/results.md until
    the twenty-seventh session), ``"best"`` the one with the higher success on GT depth
    over ``budget["val_flights"]`` flights in the validation worlds (never the test
    worlds; a tie keeps the first). ``workers`` > 1 trains the parents (and the students)
    that many at a time, one process per core, and flies the evaluations' chunks
    likewise. ``student_seq_len`` and ``student_batch_size``: the stage-2 students' replay
    windows (``train-agent --seq-len --batch-size``; both presets: the paper's 5 and 32).
    Everything lands in ``out/distil`` (results.json, results.md)."""
    if students < 1:
        raise ValueError(f"reproduce_distilled: students must be >= 1; got {students}")
    for name, value in (("student_seq_len", student_seq_len),
                        ("student_batch_size", student_batch_size)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"reproduce_distilled: {name} must be an integer >= 1; got "
                             f"{value!r}")
    if start not in ("first", "best"):
        raise ValueError(f"reproduce_distilled: start must be 'first' or 'best'; got {start!r}")
    kinds = parent_kinds(short, wide_parents)
    budget = distil_budget(quick, short, parent_steps, budget)
    out = out / "quick" if quick else out
    scenarios = ["basic"] + (list(TRANSFER) if tables in ("6", "both") else [])
    depth_models = _depth_models(out, seed, budget, scenarios, skip_depth)
    agents = out / "distil"
    recipe = "distil-short" if short else "distil"
    results = {"recipe": recipe, "budget": budget, "seed": seed, "students": [],
               "wide_parents": wide_parents, "student_seq_len": student_seq_len,
               "student_batch_size": student_batch_size,
               "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    parents = _train_all([     # the shipped D3RQN's 240k recipe (short: SHORT's), GT depth
        (["--variant", "d3rqn", "--seed", str(seed + offset), "--steps", str(budget["steps"]),
          "--learning-starts", str(budget["learning_starts"]),
          "--eps-decay", str(budget["eps_decay"]), "--replay", "100000",
          "--updates-per-step", str(budget["updates_per_step"]), *torso],
         agents / name, budget) for name, offset, torso in kinds], workers)
    teacher = "+".join(str(m) for m in parents)
    wide = {name: m for (name, _, torso), m in zip(kinds, parents) if torso == WIDE}
    start_from = wide["parent_wide_s0"]
    if start == "best":        # the better wide parent on validation worlds, GT depth
        results["validation"] = [_evaluate_cli(str(m), "basic", budget, seed, "gt", None,
                                               workers, validation=True)
                                 for m in wide.values()]
        rates = [r["rate"] for r in results["validation"]]
        start_from = list(wide.values())[rates.index(max(rates))]
    results["start"], results["stage1"] = str(start_from), stage1
    starts = str(budget["stage_learning_starts"])
    if stage1:
        init = [str(_train_agent_cli(
            ["--variant", "d3rqn", "--seed", str(seed), "--steps", str(budget["stage1_steps"]),
             "--learning-starts", starts, "--depth", "gt", "--init-model", str(start_from),
             "--init-widen", *STUDENT, "--teachers", teacher,
             "--teacher-mix-steps", str(budget["stage1_steps"] // 2)],
            agents / "stage1_gt", budget))]
    else:                    # stage 2 grows the parent's LSTM itself
        init = [str(start_from), "--init-widen"]
    windows = []             # the students' replay windows, named only when not the
                             # paper's 5 x 32 (earlier runs' commands stay as recorded)
    if (student_seq_len, student_batch_size) != (5, 32):
        windows = ["--seq-len", str(student_seq_len), "--batch-size", str(student_batch_size)]
    trained = _train_all([
        (["--variant", "d3rqn", "--seed", str(seed + k), "--steps", str(budget["stage2_steps"]),
          "--learning-starts", starts, "--depth", "pred",
          "--depth-model", str(depth_models["basic"]), "--init-model", *init,
          *STUDENT, "--teachers", teacher,
          "--teacher-mix-steps", str(budget["stage2_steps"] // 2), *STAGE2, *windows],
         agents / f"stage2_student_s{seed + k}", budget) for k in range(students)], workers)
    for student in trained:
        for sc in scenarios:
            results["students"].append(_evaluate_cli(str(student), sc, budget, seed, "pred",
                                                     depth_models[sc], workers))
    if len(trained) > 1:     # ours: the chain's students flown together, with mirror images
        together = "+".join(str(m) for m in trained)
        results["together"] = [_evaluate_cli(together, sc, budget, seed, "pred",
                                             depth_models[sc], workers, mirror=True)
                               for sc in scenarios]
    results["teacher"] = _evaluate_cli(teacher, "basic", budget, seed, "gt", None, workers)
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    agents.mkdir(parents=True, exist_ok=True)
    (agents / "results.json").write_text(json.dumps(results, indent=2))
    (agents / "results.md").write_text(distilled_table(results))
    print(distilled_table(results))
    return results


def distilled_table(results: dict) -> str:
    """The students' rates per world (predicted depth), against the issue's targets."""
    short = results.get("recipe") == "distil-short"
    n = results.get("wide_parents", 2) + (0 if short else 2)
    count = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}.get(n, str(n))
    parents = ("the wide parent" if n == 1 else f"the {count} wide parents") if short else \
        f"the {count} parents"
    steps = results.get("budget", {}).get("steps")
    if steps:
        parents += f", {steps:,} transitions each"
    lines = [f"The distilled D3RQN (ours, {results.get('recipe', 'distil')}), predicted depth; "
             f"the teacher on GT depth in basic",
             "", "| model | scenario | ours | 95% CI by flight | by world | target |",
             "|---|---|---|---|---|---|"]
    def row(label, r):                          # a row on predicted depth, against the target
        target = 0.95 if r["scenario"] == "basic" else 0.90
        return f"| {label} | {r['scenario']} | {r['rate']:.3f} | {intervals(r)} | {target:.2f} |"
    lines += [row(r["spec"], r) for r in results["students"]]
    for r in results.get("together", []):       # an ensemble: n nets, 2n Q-net passes
        n = r["spec"].count("+") + 1
        lines.append(row(f"the {n} students together, each with its mirror image (ours: "
                         f"{2 * n} Q-net passes per step)", r))
    t = results["teacher"]
    lines.append(f"| teacher ({parents}), GT depth | basic | {t['rate']:.3f} | "
                 f"{intervals(t)} | |")
    for v in results.get("validation", []):
        lines.append(f"| {v['spec']}, GT depth, **validation worlds** | basic | {v['rate']:.3f} "
                     f"| {intervals(v)} | |")
    if "start" in results:
        grew = "Stage 1" if results.get("stage1", True) else "No stage 1: stage 2"
        lines.append(f"\n{grew} grew {results['start']}.")
    return "\n".join(lines) + "\n"


__all__ = ["reproduce", "reproduce_distilled", "distil_budget", "parent_kinds", "markdown_tables",
           "PAPER_T5", "PAPER_T6"]
