"""Run an exercise: check the student's file, train with it on a classroom budget,
evaluate, and print a table of every run of that exercise so far.

    run_exercise("reward")                    # exercises/reward.py, budget "small"
    run_exercise("reward", baseline=True)     # the paper's setting, same budget

Agent exercises (1-5, 8) train a Q-network on ground-truth depth (fast, and independent
of any depth model; the pipeline with predicted depth is the same code with
``--depth pred``) and evaluate it greedily on fresh test worlds: success rate (50
steps without a collision, the paper's test), mean steps survived, and how often each
action was chosen. Exercise 8 corrupts the GT depth seen in training only, and flies
the test flights twice: on GT depth and on the shipped DispNet's predicted depth. The
depth exercise (7) trains DispNet + PoseNet and reports abs rel and delta < 1.25
against ground truth on held-out frames.

The paper's setting is the same training for every agent exercise: it is trained once
per (budget, seed, variant, ...) and version of the package's code into
``<out>/baseline/<key>/`` and reused by every exercise that compares against it; after
an edit of the package it is trained again (and the run says so). Every run writes ``<out>/<exercise>/<run>/result.json``;
runs with the same budget and seed are comparable.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from ..io import hold, holding, write_json
from .checks import Exercise, find
from .student import Report, check_in_child, line_in, load, working_copy

OUT = Path("runs/classroom")
EVAL_SEED = 12345

# Classroom budgets for the Q-learning exercises. "small" is the one the exercise sheets
# quote: 40k transitions, ~3,500 double-Q updates (the full run behind the shipped model
# is 240k transitions). Learning shows after ~1,700 updates (mean steps rising above a
# random pilot's ~11), success soon after. "tiny" is a look at the mechanics (too short
# to learn much); "smoke" is for tests. ``minutes``: a whole run (training, the test
# flights, a GIF), on a free core (benchmarks/bench_examples.py records it). Seed 0,
# an otherwise idle 2-core machine: small 2.5 (the paper's setting), tiny 0.8; depth
# small 2.0 (L1, collecting the frames included), tiny 0.4.
AGENT_BUDGETS = {
    "smoke": dict(train=dict(steps=256, learning_starts=64, n_envs=8, hidden=16,
                             replay_capacity=4_000, eps_decay_steps=200, log_every=64,
                             updates_per_step=1.0, n_worlds=4),
                  flights=16, minutes=0.2),
    "tiny": dict(train=dict(steps=12_000, learning_starts=2_000, n_envs=16, hidden=64,
                            replay_capacity=12_000, eps_decay_steps=8_000, log_every=2_000,
                            updates_per_step=1.5),
                 flights=100, minutes=0.8),
    "small": dict(train=dict(steps=40_000, learning_starts=2_000, n_envs=16, hidden=64,
                             replay_capacity=40_000, eps_decay_steps=25_000, log_every=4_000,
                             updates_per_step=1.5),
                  flights=200, minutes=2.5),
}
DEPTH_BUDGETS = {
    "smoke": dict(frames=60, test_frames=30, iterations=3, log_every=1, minutes=0.2),
    "tiny": dict(frames=600, test_frames=100, iterations=300, log_every=50, minutes=0.4),
    "small": dict(frames=2000, test_frames=200, iterations=2000, log_every=100, minutes=2),
}


# -- what a student's file means for training ------------------------------------------
def agent_settings(ex: Exercise, module, summary: dict, variant: str | None) -> dict:
    """The training changes an agent exercise asks for (``summary``: its check's);
    ``module`` None = the paper's setting."""
    s = {"variant": variant or "d3rqn", "seq_len": 5, "actions": None, "hfov_deg": 90.0,
         "reward_fn": None, "td_target": None, "depth_fn": None, "tag": "paper"}
    if module is None:
        s["tag"] = {"fov": f"{s['variant']}-fov90", "memory": f"{s['variant']}-seq5",
                    "ablation": "dueling-double-q"}.get(ex.name, "paper")
    elif ex.name == "reward":
        s.update(reward_fn=module.reward, tag="yours")
    elif ex.name == "actions":
        s["actions"] = np.asarray(module.ACTIONS, dtype=np.float64).tolist()
        s["tag"] = f"yours-{len(s['actions'])}actions"
    elif ex.name == "fov":
        s["hfov_deg"] = float(module.HFOV_DEG)
        s["tag"] = f"{s['variant']}-fov{s['hfov_deg']:g}"
    elif ex.name == "memory":
        s["seq_len"] = int(module.SEQ_LEN)
        s["tag"] = f"{s['variant']}-seq{s['seq_len']}"
    elif ex.name == "ablation":
        kind = summary["target"]
        s["td_target"] = None if kind == "double" else module.td_target
        s["variant"] = "d3rqn" if summary["dueling"] else "ddrqn"
        s["tag"] = ("dueling" if summary["dueling"] else "no-dueling") + "-" + \
            {"double": "double-q", "single": "no-double-q", "online": "no-target-net"}[kind]
    elif ex.name == "depth-errors":
        s.update(depth_fn=module.corrupt, tag="yours")      # in training only
    else:
        raise ValueError(f"exercise {ex.name!r} does not train an agent")
    return s


def _agent_config(ex: Exercise, s: dict, budget: str, seed: int):
    """The TrainConfig of an agent exercise: the budget, the student's change ``s`` (its
    action table and field of view are recorded in the model file)."""
    from ..rl.train import TrainConfig
    seq_len = s["seq_len"]
    if s["variant"] in ("ddqn", "d3qn") and ex.name != "memory":
        seq_len = 1
    return TrainConfig(variant=s["variant"], seq_len=seq_len, seed=seed,
                       checkpoint_every=10 ** 9, actions=s["actions"], hfov_deg=s["hfov_deg"],
                       **AGENT_BUDGETS[budget]["train"])


class CountingPolicy:
    """A policy that also counts the actions it takes in flights still flying."""

    def __init__(self, inner, n_actions: int):
        self.inner, self.counts = inner, np.zeros(n_actions, dtype=np.int64)

    def __getattr__(self, name):          # everything else is the inner policy's
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def reset(self, env):
        self.env = env                     # its ``active``: the flights still flying
        self.inner.reset(env)

    def act(self, obs, started=None):
        a = self.inner.act(obs, started)
        self.counts += np.bincount(a[self.env.active], minlength=len(self.counts))
        return a


# -- agent exercises -------------------------------------------------------------------
def _train(cfg, s: dict, folder: Path, progress: bool, reuse: bool) -> tuple[Path, float]:
    """Train ``cfg`` with the student's functions of ``s`` into ``folder``; (model.npz,
    training seconds). ``reuse``: a model the folder holds already is taken as it is
    (the paper's setting, in ``baseline_folder``, is trained once)."""
    from ..io import load_npz
    from ..rl.train import train
    model = folder / "model.npz"
    if reuse and model.is_file():
        return model, load_npz(model)[1]["train_seconds"]
    t0 = time.time()
    run = train(cfg, folder, reward_fn=s["reward_fn"], depth_fn=s["depth_fn"],
                td_target=s["td_target"], progress=progress)
    seconds = round(time.time() - t0, 1)
    run.save_model(model, {"train_seconds": seconds})
    # the checkpoint holds the whole replay (~140 MB at budget small); an exercise run is
    # never resumed, so keep only the model
    (folder / "checkpoint.npz").unlink(missing_ok=True)
    return model, seconds


PACKAGE = Path(__file__).resolve().parent.parent


def source_digest(root=PACKAGE) -> str:
    """A digest of the code that trains: every .py file of the package (its path and
    bytes), but the exercise templates, which a baseline never runs. Edit the package and
    the digest changes."""
    h = hashlib.sha1()
    for path in sorted(Path(root).rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith("classroom/templates/") or "__pycache__" in rel:
            continue
        h.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def baseline_folder(cfg, budget: str, out=OUT, source: str | None = None) -> Path:
    """Where the paper's setting ``cfg`` (a TrainConfig) is trained once and reused:
    named by its variant, scenario, budget and seed, a digest of all its settings and
    one of the package's code (``source``, default ``source_digest()``): a baseline is
    reused only by the code that trained it."""
    from ..config import as_dict
    digest = hashlib.sha1(json.dumps(as_dict(cfg), sort_keys=True).encode()).hexdigest()
    return Path(out) / "baseline" / f"{cfg.variant}-{cfg.scenario}-{budget}-s{cfg.seed}-" \
                                    f"{digest[:8]}-code{(source or source_digest())[:8]}"


def older_baselines(folder: Path) -> list[Path]:
    """Baselines of the same setting trained by other versions of the package's code."""
    stem = folder.name.rsplit("-code", 1)[0]
    return sorted(p.parent for p in folder.parent.glob(f"{stem}-code*/model.npz")
                  if p.parent != folder)


STUDENT_FUNCTIONS = ("reward_fn", "td_target", "depth_fn")


def run_agent_exercise(ex: Exercise, module, summary: dict | None = None, budget: str = "small",
                       variant: str | None = None, seed: int = 0, out=OUT,
                       flights: int | None = None, progress: bool = True,
                       name: str | None = None) -> dict:
    """Train, evaluate and record one run of an agent exercise (``module`` None: the
    paper's setting); ``name`` replaces "yours" in the run's name."""
    s = agent_settings(ex, module, summary or {}, variant)
    cfg = _agent_config(ex, s, budget, seed)
    paper = _agent_config(ex, agent_settings(ex, None, {}, variant), budget, seed)
    tag = s["tag"].replace("yours", name or "yours") + (f"-s{seed}" if seed else "") + \
        ("" if budget == "small" else f"-{budget}")
    run_dir = Path(out) / ex.name / tag
    shared = cfg == paper and not any(s[k] for k in STUDENT_FUNCTIONS)
    folder = baseline_folder(cfg, budget, out) if shared else run_dir
    n_flights = flights or AGENT_BUDGETS[budget]["flights"]
    # one command at a time on a run (another file, or another seed, is another run)
    option = "--seed" if module is None else "--file"
    with holding((run_dir, option), (folder if shared else None, "--seed")):
        return _agent_run(ex, s, cfg, folder, run_dir, tag, budget, seed, n_flights,
                          shared, progress, out)


def _agent_run(ex, s, cfg, folder, run_dir, tag, budget, seed, n_flights, shared, progress,
               out) -> dict:
    """Train, fly and record one agent exercise run (its folders held by the caller)."""
    from ..rl.evaluate import evaluate_policy
    from ..rl.models import actions_and_camera, load_qnet_policy
    # exercise 8 also flies the test flights on the DispNet's depth: load it before
    # training, so that a missing depth model stops the run now, not minutes later
    est, est_path = _shipped_depth_estimator(cfg.scenario) if ex.name == "depth-errors" \
        else (None, None)
    if shared and (folder / "model.npz").is_file():
        what = f"the paper's setting, trained before ({folder}): reusing it"
    else:
        what = (f"training {cfg.variant} for {cfg.steps} transitions (budget '{budget}': "
                f"about {AGENT_BUDGETS[budget]['minutes']:g} min on a free core)")
        older = older_baselines(folder) if shared else []
        if older:               # the same setting, trained by other code: not reused
            what = (f"the package's code has changed since the paper's setting was trained "
                    f"({older[-1]}), so it is trained again: " + what.removeprefix("training "))
    print(f"exercise {ex.name} [{tag}]: {what}; then {n_flights} test flights"
          + (" on GT depth and on predicted depth" if est else "") + f" -> {run_dir}",
          flush=True)
    # training: the student's change, including the depth corruption (exercise 8) ...
    model, seconds = _train(cfg, s, folder, progress, reuse=shared)
    policy = load_qnet_policy(model)
    policy.name = tag
    actions, camera = actions_and_camera(policy)
    counting = CountingPolicy(policy, len(actions))
    # ... testing: the same actions and camera, but never a corruption of the depth
    test = dict(actions=actions, camera=camera, progress=progress,
                n_worlds=cfg.n_worlds)
    res = evaluate_policy(counting, cfg.scenario, n_flights, EVAL_SEED, **test)
    share = counting.counts / max(1, counting.counts.sum())
    result = {"exercise": ex.name, "tag": tag, "budget": budget, "seed": seed,
              "variant": cfg.variant, "seq_len": cfg.window(), "hfov_deg": cfg.hfov_deg,
              "actions": actions.tolist(), "success": res.rate, "ci": [res.ci_low, res.ci_high],
              "flights": res.flights, "mean_steps": res.mean_steps,
              "action_share": np.round(share, 4).tolist(),
              "mean_abs_yaw_rate": float(share @ np.abs(actions[:, 1])),
              "train_seconds": seconds, "model": str(model),
              "gif": _flight_gif(model, run_dir / "flight.gif", 8 if budget != "smoke" else 2)}
    if est is not None:           # the same test flights, on the DispNet's depth
        pred = evaluate_policy(policy, cfg.scenario, n_flights, EVAL_SEED, depth="pred",
                               depth_estimator=est, **test)
        result.update({"pred_success": pred.rate, "pred_ci": [pred.ci_low, pred.ci_high],
                       "pred_mean_steps": pred.mean_steps, "depth_model": est_path})
    write_json(run_dir / "result.json", result)
    print("\n" + _said(result))
    print(summary_table(ex.name, out))
    return result


def _said(r: dict) -> str:
    """What a finished agent run prints about itself."""
    pred = "pred_success" in r
    text = (f"{r['tag']}: success {r['success']:.3f} [{r['ci'][0]:.3f}, {r['ci'][1]:.3f}] over "
            f"{r['flights']} flights" + (" on GT depth" if pred else "") + f", mean steps "
            f"{r['mean_steps']:.1f} / 50; trained in {r['train_seconds'] / 60:.1f} min; "
            f"learning curve: {Path(r['model']).parent / 'curve.png'}"
            + (f"; a test flight: {r['gif']}" if r["gif"] else ""))
    if pred:
        text += (f"\n{r['tag']}: success {r['pred_success']:.3f} [{r['pred_ci'][0]:.3f}, "
                 f"{r['pred_ci'][1]:.3f}] on the same flights on predicted depth "
                 f"({r['depth_model']}), mean steps {r['pred_mean_steps']:.1f} / 50; GT minus "
                 f"predicted: {r['success'] - r['pred_success']:+.3f}")
    return text


def _shipped_depth_estimator(scenario: str):
    """(estimator, path): the shipped DispNet of ``scenario``
    (minid3rqn/models/depth_<scenario>.npz), loaded as ``evaluate --depth pred`` loads it."""
    from ..rl.models import load_depth_estimator, shipped_depth_model
    path = shipped_depth_model(scenario)
    if not path.is_file():
        raise SystemExit(f"exercise: the shipped depth model {str(path)!r} is missing; it is "
                         f"needed to fly the test flights on predicted depth (reinstall the "
                         f"package, or train one with `python -m minid3rqn train-depth "
                         f"--scenario {scenario}`)")
    return load_depth_estimator(path), f"minid3rqn/models/{path.name}"


def _flight_gif(model: Path, gif: Path, flights: int = 8):
    """GIF of test flight 0 (top view | camera | depth | Q-values), with ``rl.fly``, with
    the actions and camera of the model file.

    Every run uses the same evaluation seed, so flight 0 starts in the same world and
    pose in every run: the GIFs of two runs compare one flight. Returns the path, or
    None if the GIF could not be made (it is a bonus, never a reason to fail a run).
    """
    try:
        from ..rl.fly import fly
        return fly(model, None, "basic", EVAL_SEED, flights, gif).get("gif")
    except Exception as e:  # noqa: BLE001
        print(f"(no flight GIF: {type(e).__name__}: {e})")
        return None


# -- the depth exercise ----------------------------------------------------------------
def _frames(folder: Path, n: int, seed: int):
    """``n`` frames of the scripted pilot's flights, collected once into ``folder``."""
    from ..depth.data import CollectConfig, collect_sequence, load_sequence
    path = folder / f"frames_{n}_s{seed}.npz"
    return load_sequence(path) if path.is_file() else \
        collect_sequence(CollectConfig(frames=n, seed=seed), path, progress=False)


def run_depth_exercise(ex: Exercise, module, budget: str = "small", seed: int = 0, out=OUT,
                       progress: bool = True, name: str | None = None) -> dict:
    b = DEPTH_BUDGETS[budget]
    tag = ("paper-L1" if module is None else name or "yours") + \
        (f"-s{seed}" if seed else "") + ("" if budget == "small" else f"-{budget}")
    run_dir = Path(out) / ex.name / tag
    with hold(run_dir, "--seed" if module is None else "--file"):
        return _depth_run(ex, module, b, seed, run_dir, tag, budget, progress, out)


def _depth_run(ex, module, b, seed, run_dir, tag, budget, progress, out) -> dict:
    """Train, evaluate and record one depth exercise run (its folder held by the caller)."""
    from ..depth.evaluate import DepthEstimator, comparison_picture, evaluate
    from ..depth.losses import LossConfig
    from ..depth.train import TrainConfig, Trainer
    run_dir.mkdir(parents=True, exist_ok=True)
    print(f"exercise {ex.name} [{tag}]: DispNet + PoseNet, {b['iterations']} iterations on "
          f"{b['frames']} frames (budget '{budget}': about {b['minutes']:g} min on a free "
          f"core) -> {run_dir}", flush=True)
    train = _frames(run_dir.parent, b["frames"], seed)
    test = _frames(run_dir.parent, b["test_frames"], seed + 1000)
    cfg = TrainConfig(iterations=b["iterations"], seed=seed, log_every=b["log_every"],
                      checkpoint_every=10 ** 9, loss=LossConfig(ssim_weight=0.0))  # Eq. 2: L1
    t0 = time.time()
    trainer = Trainer(train, cfg, photometric_error=module and module.photometric_error)
    trainer.run(progress=progress)
    seconds = round(time.time() - t0, 1)
    est = DepthEstimator(trainer.disp, trainer.speed_scale())
    metrics = evaluate(est, test)
    rows = np.linspace(0, len(test) - 1, 4).astype(int)
    comparison_picture(test.rgb[rows], est.predict(test.rgb[rows]), test.depth[rows],
                       run_dir / "pictures.png")
    result = {"exercise": ex.name, "tag": tag, "budget": budget, "seed": seed,
              **{k: float(v) for k, v in metrics.items() if np.isscalar(v)},
              "train_seconds": seconds}
    write_json(run_dir / "result.json", result)
    print(f"\n{tag}: abs rel {result['abs_rel']:.3f}, delta<1.25 {result['a1']:.3f}, trained "
          f"in {seconds / 60:.1f} min; pictures (RGB | predicted | GT): "
          f"{run_dir / 'pictures.png'}")
    print(summary_table(ex.name, out))
    return result


# -- the comparison table --------------------------------------------------------------
def _ci(lo_hi) -> str:
    return f"[{lo_hi[0]:.2f}, {lo_hi[1]:.2f}]"


AGENT_COLUMNS = [("success", 8, lambda r: f"{r['success']:.3f}"),
                 ("95% CI", 13, lambda r: _ci(r["ci"])),
                 ("steps", 6, lambda r: f"{r['mean_steps']:.1f}")]
COLUMNS = {
    "agent": AGENT_COLUMNS + [("|yaw|", 6, lambda r: f"{r['mean_abs_yaw_rate']:.3f}")],
    "depth-errors": AGENT_COLUMNS + [
        ("pred success", 13, lambda r: f"{r['pred_success']:.3f}"),
        ("pred 95% CI", 13, lambda r: _ci(r["pred_ci"])),
        ("pred steps", 11, lambda r: f"{r['pred_mean_steps']:.1f}"),
        ("GT-pred", 8, lambda r: f"{r['success'] - r['pred_success']:+.3f}")],
    "depth-loss": [("abs rel", 8, lambda r: f"{r['abs_rel']:.3f}"),
                   ("sq rel", 8, lambda r: f"{r['sq_rel']:.3f}"),
                   ("rmse", 7, lambda r: f"{r['rmse']:.3f}"),
                   ("d<1.25", 7, lambda r: f"{r['a1']:.3f}")]}


def summary_table(exercise: str, out=OUT) -> str:
    """Every result.json of an exercise so far, one line each."""
    rows, skipped = [], []
    for path in sorted(Path(out, exercise).glob("*/result.json")):
        try:
            rows.append((path, json.loads(path.read_text())))
        except (OSError, ValueError):
            skipped.append(path)
    if not rows and not skipped:
        return f"(no runs of {exercise} yet)"
    columns = [("run", -30, lambda r: r["tag"]), ("budget", -7, lambda r: r["budget"])] + \
        COLUMNS.get(exercise, COLUMNS["agent"]) + \
        [("minutes", 8, lambda r: f"{r['train_seconds'] / 60:.1f}")]

    def cell(text, width):
        return f"{text:<{-width}}" if width < 0 else f"{text:>{width}}"

    lines = [" ".join(cell(title, w) for title, w, _ in columns)]
    for path, r in rows:
        try:
            lines.append(" ".join(cell(f(r), w) for _, w, f in columns))
        except (KeyError, TypeError, ValueError):   # not a result this table can show
            skipped.append(path)
    lines += [f"(left out: {path}, not a result of this exercise)" for path in skipped]
    caption = " (success, 95% CI, steps: on GT depth; pred: the same test flights on " \
        "predicted depth)" if exercise == "depth-errors" else ""
    return f"\nAll runs of '{exercise}' in {Path(out, exercise)}{caption}:\n" + "\n".join(lines)


# -- entry point -----------------------------------------------------------------------
def run_exercise(name: str, file=None, baseline: bool = False, budget: str = "small",
                 variant: str | None = None, seed: int = 0, out=OUT, flights: int | None = None,
                 progress: bool = True) -> dict:
    """Check the student's file (``file``, default their copy in exercises/), then train
    and evaluate with it; ``baseline``: the paper's setting instead. A run from a file of
    another name than the template's is named after it (``--file cap3.py``: "cap3")."""
    ex = find(name)
    path = None if baseline and ex.trains else Path(file) if file else working_copy(ex.filename)
    report = None if path is None else \
        check_in_child(ex.checker, path, f"{ex.number} ({ex.name})")   # in a process apart
    if report is not None:
        print(report.text())
    if not ex.trains:
        print(f"\nExercise {ex.name} has nothing to train: passing the check is the result. "
              f"See {ex.doc} for the follow-up (use your op in a network).")
        return {"exercise": ex.name, "passed": report.passed}
    if report is not None and not report.passed:
        again = f" --file {file}" if file else ""
        raise SystemExit(f"exercise {ex.name}: fix the problems above first "
                         f"(python -m minid3rqn check {ex.name}{again})")
    module = None if path is None else load(path, Report(report.exercise, path))
    named = path.stem if path is not None and path.name != ex.filename else None
    try:
        if ex.trains == "depth":
            return run_depth_exercise(ex, module, budget, seed, out, progress, named)
        return run_agent_exercise(ex, module, report and report.summary, budget, variant,
                                  seed, out, flights, progress, named)
    except Exception as e:            # the student's code failed during the run: say where
        found = line_in(path, e)
        if found is None:
            raise
        raise SystemExit(f"exercise {ex.name}: your {path.name} raised {type(e).__name__} at "
                         f"line {found[0]} during the run: {e}") from None
