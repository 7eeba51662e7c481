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

``--quick`` is the same story in one class period (``reproduce_quick``): the shipped
DispNets instead of training them, the four Q-nets at the classroom budget, each on the
shipped DispNet's depth from the start, flown on the test worlds.

``--recipe distil`` runs instead our recipe for one D3RQN that flies ``basic`` at 0.95
on predicted depth (``reproduce_distilled``; docs/d3rqn.md section 11, docs/beyond.md
"What helped"): not the paper's method, our addition.

Every model lands with the ``train-agent`` or ``distil`` command that makes it alone.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

from ..config import at_least, capped_workers, setting, validate
from ..executor import EXECUTORS, get_executor
from ..io import write_file, write_json
from .distill import DistilConfig, distil, student
from .evaluate import EvalConfig, evaluate_spec
from .evaluate import TEST_WORLDS
from .models import MODELS, command_for, load_depth_estimator, save_trained
from .train import SMOKE, TrainConfig, train

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
            finetune_steps=20_000, flights=2000, depth_frames=5000,
            stage1_steps=20_000, stage2_steps=40_000, stage_learning_starts=2000)


@dataclass
class ReproduceConfig:
    recipe: str = setting("paper", "paper: Tables 5 and 6; distil (ours): the distilled "
                                   "D3RQN (four GT parents, two distillation stages)",
                          source="run", choices=("paper", "distil"))
    quick: bool = setting(False, "Table 5 and 6 in one class period (about 12.5 min on 2 "
                                 "cores): the shipped DispNets, the classroom budget, 500 "
                                 "test flights per cell", source="run")
    skip_depth: bool = setting(False, "reuse the shipped depth models instead of training "
                                      "them", source="run")
    workers: int = setting(1, "processes training the Q-nets and flying the evaluations, "
                              "that many at a time (run with OMP_NUM_THREADS=1; with the "
                              "local executor at most the cores)", source="run",
                           check=at_least(1))
    executor: str = setting("local", "where the trainings and evaluations run: processes "
                                     "of this machine (--workers), or Ray tasks on the "
                                     "cluster ray.init() finds (RAY_ADDRESS; the run "
                                     "folders on storage shared by every node)",
                            source="run", choices=EXECUTORS)
    students: int = setting(1, "--recipe distil: students of stage 2 (seeds 0, 1, ...)",
                            source="run", check=at_least(1))
    seed: int = setting(0, "seeds every training (nets, worlds, exploration); the test "
                           "worlds stay seed 271828", source="run", check=at_least(0))

    def __post_init__(self):
        validate(self)
        if self.executor == "local":    # a cluster has cores of its own
            capped_workers(self)


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


def _smoke(cfg: TrainConfig, budget: dict) -> TrainConfig:
    """Tests: every run at train-agent --smoke's size."""
    return replace(cfg, **SMOKE) if budget.get("smoke") else cfg


def _finished(run_dir: Path, command: str, steps: int) -> bool:
    """``run_dir`` holds the finished model (``steps`` transitions) that ``command`` makes."""
    from ..io import load_npz
    path = run_dir / "model.npz"
    if not path.is_file():
        return False
    meta = load_npz(path)[1]
    return meta.get("command") == command and meta.get("steps") == steps


def _train_qnet(cfg, run_dir: Path, depth_model=None, progress: bool = True) -> Path:
    """Train a TrainConfig (``rl.train.train``) or a DistilConfig (``rl.distill.distil``)
    in ``run_dir``, resumed if it was cut off; returns the model file, which records
    the one command that makes it."""
    t = cfg.train if isinstance(cfg, DistilConfig) else cfg
    depth_model = depth_model if t.depth == "pred" else None
    command = command_for(cfg, run_dir, depth_model)
    if _finished(run_dir, command, t.steps):          # kept as it is, with its own record
        return run_dir / "model.npz"
    est = load_depth_estimator(depth_model) if t.depth == "pred" else None
    t0 = time.time()
    fit = distil if isinstance(cfg, DistilConfig) else train
    run = fit(cfg, run_dir, est, progress=progress, resume=True)
    return save_trained(run, command, depth_model, time.time() - t0)


def _train_task(progress: bool, task) -> Path:
    return _train_qnet(*task, progress=progress)


def _train_all(tasks: list, executor) -> list:
    """Train independent runs ((config, run_dir, depth_model) each) with ``executor``
    (``executor.get_executor``): one after the other with progress bars, or that many at a
    time (no progress bars: each prints a line per checkpoint; the same runs, each fixed
    by its own seed). Ctrl-C stops every run with its checkpoint (``io.RunStopped``)."""
    serial = executor.name == "local" and min(executor.workers, len(tasks)) <= 1
    if serial:
        return executor.run(_train_task, tasks, True)
    print(f"\n== {len(tasks)} runs on {executor.name} (no progress bars: each prints a line "
          f"per checkpoint): {', '.join(Path(t[1]).name for t in tasks)}", flush=True)
    names = [Path(t[1]).name for t in tasks]
    finished = []

    def report(i, model):
        finished.append(names[i])
        print(f"== {len(finished)} of {len(tasks)} runs finished: {names[i]}", flush=True)
    return executor.run(_train_task, tasks, False, report,
                        check_folders={Path(t[1]).parent for t in tasks})


def _family_member(spec: str, seed: int, budget: dict, init_model: Path | None = None):
    """A Q-net of the family (``spec`` "variant" or "variant:stack"): from scratch on GT
    depth (the shipped 240k recipe), or with ``init_model`` its fine-tune on predicted
    depth (the shipped fine-tune: docs/results.md)."""
    variant, _, stack = spec.partition(":")
    cfg = TrainConfig(variant=variant, seed=seed, stack=int(stack or 1), depth="gt",
                      steps=budget["steps"], learning_starts=budget["learning_starts"],
                      eps_decay_steps=budget["eps_decay"], replay_capacity=100_000,
                      updates_per_step=budget["updates_per_step"])
    if init_model is not None:
        steps = budget["finetune_steps"]
        cfg = replace(cfg, depth="pred", steps=steps, learning_starts=steps // 10,
                      eps_start=0.2, eps_decay_steps=steps * 2 // 5, replay_capacity=60_000,
                      updates_per_step=4.0, init_model=str(init_model))
    return _smoke(cfg, budget)


def _evaluate(spec, scenario: str, budget: dict, seed: int, depth: str, depth_model,
              executor, mirror: bool = False) -> dict:
    """``evaluate SPEC`` on ``budget["flights"]`` test flights; returns its record."""
    cfg = EvalConfig(scenario=scenario, flights=budget["flights"], seed=12345 + seed,
                     depth=depth, workers=executor.workers or 1, executor=executor.name,
                     mirror=mirror,
                     depth_model=str(depth_model) if depth == "pred" else "")
    est = load_depth_estimator(depth_model) if depth == "pred" else None
    return evaluate_spec(str(spec), cfg, est)[1]


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


def reproduce(out: Path, seed: int = 0, skip_depth: bool = False, workers: int = 1,
              budget: dict | None = None, executor: str = "local") -> dict:
    """Run the pipeline of the module docstring (Tables 5 and 6); ``budget`` (tests)
    overrides FULL's entries. The family's trainings, then their fine-tunes, and the
    evaluations' chunks run ``workers`` at a time with ``executor``
    (``executor.get_executor``)."""
    budget = {**FULL, **(budget or {})}
    ex = get_executor(executor, workers)
    out.mkdir(parents=True, exist_ok=True)
    results = {"budget": budget, "seed": seed, "depth": "pred", "table5": [], "table6": [],
               "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    depth_models = _depth_models(out, seed, budget, ["basic", *TRANSFER], skip_depth)
    names = {}
    for spec in FAMILY:
        variant, _, stack = spec.partition(":")
        names[spec] = f"{variant}{f'_stack{stack}' if int(stack or 1) > 1 else ''}_basic"
    trained = _train_all([(_family_member(spec, seed, budget),
                           out / "agent" / f"{names[spec]}_gt_s{seed}", None)
                          for spec in FAMILY], ex)
    if budget["finetune_steps"] > 0:
        trained = _train_all([(_family_member(spec, seed, budget, gt),
                               out / "agent" / f"{names[spec]}_pred_s{seed}_finetuned",
                               depth_models["basic"]) for spec, gt in zip(FAMILY, trained)],
                             ex)
    models = dict(zip(FAMILY, trained))

    def run_eval(policies, scenario):
        return [_evaluate(spec, scenario, budget, seed, "pred", depth_models[scenario],
                          ex) for spec in policies]

    baselines = ["straight", "random", "reactive", "oracle"]
    results["table5"] = run_eval(baselines + [models[s] for s in FAMILY], "basic")
    for sc in TRANSFER:
        results["table6"] += run_eval(baselines + [models["d3rqn"]], sc)
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    print(markdown_tables(results))       # said first: a failed write loses no number
    write_json(out / "results.json", results)
    write_file(out / "results.md", markdown_tables(results))
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
# with mirrored replay windows and the KL term on the teacher's preferences
# (``rl.distill.student`` and ``DistilConfig``'s defaults).
WIDE = [8, 16, 16]
PARENTS = (("parent_s0", 0, None), ("parent_s1", 1, None),
           ("parent_wide_s0", 0, WIDE), ("parent_wide_s1", 1, WIDE))


def _stage(teacher: str, init_model, seed: int, steps: int, budget: dict, depth: str,
           **distil_settings) -> DistilConfig:
    """A distillation stage: the recipe's student from ``init_model``, ``steps``
    transitions on ``depth``, the teacher's share falling over the first half."""
    t = replace(student(), seed=seed, steps=steps, depth=depth, init_model=str(init_model),
                learning_starts=budget["stage_learning_starts"])
    return DistilConfig(teachers=teacher, teacher_mix_steps=steps // 2,
                        train=_smoke(t, budget), **distil_settings)


def reproduce_distilled(out: Path, seed: int = 0, students: int = 1,
                        skip_depth: bool = False, tables: str = "both", workers: int = 1,
                        budget: dict | None = None, executor: str = "local") -> dict:
    """The distilled D3RQN end to end: the basic DispNet (and, for Table 6, the transfer
    ones) as in ``reproduce``; the four GT parents; stage 1 from the wide seed-``seed``
    parent; ``students`` students of stage 2 (seeds ``seed``, ``seed`` + 1, ...), each
    flown on predicted depth in ``basic`` (and the transfer worlds), two or more also
    together, each with its mirror image (ours); the teacher on GT depth in ``basic``.
    ``workers`` > 1 trains the parents (and the students) that many at a time, one
    process per core, and flies the evaluations' chunks likewise (``executor``: where,
    ``executor.get_executor``). Everything lands in
    ``out/distil`` (results.json, results.md)."""
    budget = {**FULL, **(budget or {})}
    ex = get_executor(executor, workers)
    scenarios = ["basic"] + (list(TRANSFER) if tables in ("6", "both") else [])
    depth_models = _depth_models(out, seed, budget, scenarios, skip_depth)
    agents = out / "distil"
    results = {"recipe": "distil", "budget": budget, "seed": seed, "students": [],
               "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    parents = _train_all([     # the shipped D3RQN's 240k recipe, GT depth
        (_smoke(TrainConfig(seed=seed + offset, steps=budget["steps"],
                            learning_starts=budget["learning_starts"],
                            eps_decay_steps=budget["eps_decay"], replay_capacity=100_000,
                            updates_per_step=budget["updates_per_step"],
                            conv_channels=torso), budget), agents / name, None)
        for name, offset, torso in PARENTS], ex)
    teacher = "+".join(str(m) for m in parents)
    stage1 = _train_qnet(_stage(teacher, parents[2], seed, budget["stage1_steps"], budget,
                                "gt", init_widen=True, distil_kl=0.0, mirror_augment=False),
                         agents / "stage1_gt")
    trained = _train_all([
        (_stage(teacher, stage1, seed + k, budget["stage2_steps"], budget, "pred"),
         agents / f"stage2_student_s{seed + k}", depth_models["basic"])
        for k in range(students)], ex)
    for model in trained:
        for sc in scenarios:
            results["students"].append(_evaluate(model, sc, budget, seed, "pred",
                                                 depth_models[sc], ex))
    if len(trained) > 1:     # ours: the students flown together, with mirror images
        together = "+".join(str(m) for m in trained)
        results["together"] = [_evaluate(together, sc, budget, seed, "pred",
                                         depth_models[sc], ex, mirror=True)
                               for sc in scenarios]
    results["teacher"] = _evaluate(teacher, "basic", budget, seed, "gt", None, ex)
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    agents.mkdir(parents=True, exist_ok=True)
    print(distilled_table(results))       # said first: a failed write loses no number
    write_json(agents / "results.json", results)
    write_file(agents / "results.md", distilled_table(results))
    return results


def distilled_table(results: dict) -> str:
    """The students' rates per world (predicted depth), against the targets."""
    steps = results.get("budget", {}).get("steps")
    parents = "the four parents" + (f", {steps:,} transitions each" if steps else "")
    lines = ["The distilled D3RQN (ours), predicted depth; the teacher on GT depth in basic",
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
    return "\n".join(lines) + "\n"


# -- the quick reproduction: Tables 5 and 6 in one class period -------------------------------
# The classroom budget (classroom/runner.py, "small"): 40k transitions, 64 LSTM / fully
# connected units, a 40k-frame replay. Each Q-net reads the shipped basic DispNet's depth
# from its first step (the paper trains on the depth net's output; no GT stage, no
# fine-tune), all with training seed 0. They fly the test worlds, which no choice of this
# budget looked at (it was chosen on the validation worlds of seed 12345).
QUICK_TRAIN = dict(steps=40_000, learning_starts=2_000, eps_decay_steps=25_000, hidden=64,
                   replay_capacity=40_000, updates_per_step=1.5, depth="pred", log_every=4_000)
QUICK_FLIGHTS = 500
QUICK_FAMILY = ("d3rqn", "ddrqn", "d3qn", "ddqn")
QUICK_NOTE = """\
What this quick run can show: orderings. Are the learned nets far above Straight and
Random? Are the recurrent nets (DDRQN, D3RQN: memory of the last 5 frames) above the
feed-forward ones (DDQN, D3QN)? How much of its skill does the D3RQN trained in basic
keep in three worlds it never saw? What it cannot show: the paper's values, or gaps of
a few points (500 flights give intervals about 0.1 wide). Each net learned from 40k
transitions with 64 units, on the shipped DispNets (the full recipe: 240k transitions
on GT depth, then 20k on predicted depth, 128 units, and its own DispNets).
The full tables: python -m minid3rqn reproduce (hours; docs/results.md)."""


def reproduce_quick(out: Path, seed: int = 0, workers: int = 1,
                    budget: dict | None = None, executor: str = "local") -> dict:
    """Tables 5 and 6 at the classroom budget (the block above): trains DDQN, D3QN, DDRQN
    and D3RQN in ``basic`` (``workers`` at a time, with ``executor``), flies them with
    Straight and Random on ``QUICK_FLIGHTS`` test flights in basic, and the D3RQN in the
    three new worlds, each on its shipped DispNet. A finished net is kept (model.npz) and reused; its
    checkpoint (the whole replay) is removed. ``budget`` (tests) overrides QUICK_TRAIN's
    entries (and "flights")."""
    budget = {**QUICK_TRAIN, "flights": QUICK_FLIGHTS, **(budget or {})}
    flights = budget.pop("flights")
    out = out / "quick"
    depth_basic = MODELS / "depth_basic.npz"
    _train_all([(TrainConfig(variant=v, seed=seed, **budget), out / "agent" / v, depth_basic)
                for v in QUICK_FAMILY], get_executor(executor, workers))
    for variant in QUICK_FAMILY:
        (out / "agent" / variant / "checkpoint.npz").unlink(missing_ok=True)
    models = [out / "agent" / v / "model.npz" for v in QUICK_FAMILY]

    def fly(spec, scenario):         # Straight and Random read no depth: the same flights
        if spec in ("straight", "random"):         # on GT depth, without the DispNet
            cfg = EvalConfig(scenario=scenario, flights=flights, seed=TEST_WORLDS,
                             workers=workers, executor=executor)
            return evaluate_spec(spec, cfg, progress=False)[1]
        cfg = EvalConfig(scenario=scenario, flights=flights, seed=TEST_WORLDS, depth="pred",
                         workers=workers, executor=executor,
                         depth_model=str(MODELS / f"depth_{scenario}.npz"))
        est = load_depth_estimator(cfg.depth_model)
        return evaluate_spec(str(spec), cfg, est, progress=False)[1]
    results = {"recipe": "quick", "budget": {**budget, "flights": flights}, "seed": seed,
               "worlds": TEST_WORLDS, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    print(f"\n== Table 5: {flights} test flights in basic (seed {TEST_WORLDS})", flush=True)
    results["table5"] = [fly(s, "basic") for s in ["straight", "random", *models]]
    results["table6"] = []
    for sc in TRANSFER:
        print(f"\n== Table 6: {sc}", flush=True)
        results["table6"] += [fly(s, sc) for s in ["straight", "random", models[0]]]
    results["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    text = markdown_tables(results) + "\n" + QUICK_NOTE + "\n"
    print("\n" + text)                    # said first: a failed write loses no number
    write_json(out / "results.json", results)
    write_file(out / "results.md", text)
    return results
