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

Every run writes ``<out>/<exercise>/<tag>/result.json``; runs with the same budget and
seed are comparable.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .checks import _targets_reference
from .loader import REPO_ROOT, default_path, load_student_module
from .registry import EXERCISES, Exercise, find
from .report import Report, Stop

OUT = Path("runs/classroom")
EVAL_SEED = 12345

# Classroom budgets for the Q-learning exercises. "small" is the one the exercise sheets
# quote: 40k transitions, ~3,500 double-Q updates, about 5-8 minutes on a free 2-core
# laptop (the full run behind the shipped model is 100k transitions, ~40 min). In the
# library's own runs, learning shows after ~2,000 updates (mean steps rising above a
# random pilot's ~11), success after ~3,000. "tiny" is a 2-minute look at the
# mechanics (too short to learn much); "smoke" is for tests.
AGENT_BUDGETS = {
    "smoke": dict(train=dict(steps=256, learning_starts=64, n_envs=8, hidden=16,
                             replay_capacity=4_000, eps_decay_steps=200, log_every=64,
                             updates_per_step=1.0),
                  flights=16, minutes=0.2, n_worlds=4),
    "tiny": dict(train=dict(steps=12_000, learning_starts=2_000, n_envs=16, hidden=64,
                            replay_capacity=12_000, eps_decay_steps=8_000, log_every=2_000,
                            updates_per_step=1.5),
                 flights=100, minutes=2),
    "small": dict(train=dict(steps=40_000, learning_starts=2_000, n_envs=16, hidden=64,
                             replay_capacity=40_000, eps_decay_steps=25_000, log_every=4_000,
                             updates_per_step=1.5),
                  flights=200, minutes=7),
}
DEPTH_BUDGETS = {
    "smoke": dict(frames=60, test_frames=30, iterations=3, log_every=1, minutes=0.2),
    "tiny": dict(frames=600, test_frames=100, iterations=300, log_every=50, minutes=2),
    "small": dict(frames=2000, test_frames=200, iterations=2000, log_every=100, minutes=8),
}


# -- what a student's file means for training ------------------------------------------
def agent_settings(ex: Exercise, module, variant: str | None) -> dict:
    """The training changes an agent exercise asks for; ``module`` None = the paper's."""
    s = {"exercise": ex.name, "variant": variant or "d3rqn", "seq_len": 5, "actions": None,
         "hfov_deg": 90.0, "reward_fn": None, "td_target": None, "depth_fn": None,
         "eval_pred": False}
    base = module is None
    if ex.name == "reward":
        s["reward_fn"] = None if base else module.reward
        s["tag"] = "paper" if base else "yours"
    elif ex.name == "actions":
        s["actions"] = None if base else np.asarray(module.ACTIONS, dtype=np.float64).tolist()
        s["tag"] = "paper" if base else f"yours-{len(s['actions'])}actions"
    elif ex.name == "fov":
        s["hfov_deg"] = 90.0 if base else float(module.HFOV_DEG)
        s["tag"] = f"{s['variant']}-fov{s['hfov_deg']:g}"
    elif ex.name == "memory":
        s["seq_len"] = 5 if base else int(module.SEQ_LEN)
        s["tag"] = f"{s['variant']}-seq{s['seq_len']}"
    elif ex.name == "ablation":
        dueling = True if base else bool(module.DUELING)
        kind = "double"
        if not base:
            rng = np.random.default_rng(1)
            qo, qt = rng.standard_normal((2, 3, 4, 5))
            rew, term = rng.standard_normal((3, 4)), np.zeros((3, 4))
            y = np.asarray(module.td_target(qo, qt, rew, term, 0.99))
            kind = next(k for k, v in _targets_reference(qo, qt, rew, term, 0.99).items()
                        if np.allclose(y, v, atol=1e-6))
            s["td_target"] = None if kind == "double" else module.td_target
        s["variant"] = "d3rqn" if dueling else "ddrqn"
        s["tag"] = ("dueling" if dueling else "no-dueling") + "-" + \
                   {"double": "double-q", "single": "no-double-q", "online": "no-target-net"}[kind]
    elif ex.name == "depth-errors":
        s["depth_fn"] = None if base else module.corrupt     # in training only
        s["eval_pred"] = True                 # test on GT depth and on predicted depth
        s["tag"] = "paper" if base else "yours"
    else:
        raise ValueError(f"exercise {ex.name!r} does not train an agent")
    return s


class CountingPolicy:
    """Wraps a policy and counts the actions it takes in flights that are still flying."""

    def __init__(self, inner, n_actions: int):
        self.inner, self.counts = inner, np.zeros(n_actions, dtype=np.int64)

    @property
    def name(self):
        return self.inner.name

    def reset(self, n):
        self.inner.reset(n)

    def reseed(self, seed):
        self.inner.reseed(seed)

    def act(self, obs):
        a = self.inner.act(obs)
        live = np.asarray(obs.get("active", np.ones(len(a), bool)), bool)
        self.counts += np.bincount(a[live], minlength=len(self.counts))
        return a


def _check_first(ex: Exercise, path, report_out: bool = True) -> tuple[Report, object]:
    report = ex.checker(path)
    if report_out:
        print(report.text())
    if not report.passed:
        raise SystemExit(f"exercise {ex.name}: fix the problems above first "
                         f"(python -m minid3rqn check {ex.name})")
    r = Report(ex.name, path)
    try:
        module = load_student_module(path, r)
    except Stop:
        raise SystemExit(r.text())
    return report, module


# -- agent exercises -------------------------------------------------------------------
def _agent_config(s: dict, b: dict, seed: int):
    """The TrainConfig of an agent exercise: the budget ``b``, the student's change ``s``
    (its action table and field of view are recorded in the model file)."""
    from ..rl.train import TrainConfig
    train = {**b["train"], "n_worlds": b.get("n_worlds", 32)}
    seq_len = s["seq_len"]
    if s["variant"] in ("ddqn", "d3qn") and s["exercise"] != "memory":
        seq_len = 1
    return TrainConfig(variant=s["variant"], seq_len=seq_len, seed=seed,
                       checkpoint_every=10 ** 9, actions=s["actions"],
                       hfov_deg=s["hfov_deg"], **train)


def run_agent_exercise(ex: Exercise, module, budget: str = "small", variant: str | None = None,
                       seed: int = 0, out=OUT, flights: int | None = None,
                       progress: bool = True, tag: str | None = None) -> dict:
    from ..rl.evaluate import evaluate_policy
    from ..rl.flights import FlightsConfig
    from ..rl.models import trained_actions, trained_camera
    from ..rl.policies import QNetPolicy
    from ..rl.train import train

    b = AGENT_BUDGETS[budget]
    s = agent_settings(ex, module, variant)
    tag = (tag or s["tag"]) + (f"-s{seed}" if seed else "") + \
        ("" if budget == "small" else f"-{budget}")
    run_dir = Path(out) / ex.name / tag
    cfg = _agent_config(s, b, seed)
    eval_flights_cfg = FlightsConfig(n_worlds=b["n_worlds"]) if "n_worlds" in b else None
    n_flights = flights or b["flights"]
    # exercise 8 also flies the test flights on the DispNet's depth: load it before
    # training, so that a missing depth model stops the run now, not minutes later
    est, est_path = _shipped_depth_estimator(cfg.scenario) if s["eval_pred"] else (None, None)
    print(f"exercise {ex.name} [{tag}]: training {cfg.variant} for {cfg.steps} transitions "
          f"(budget '{budget}', about {b['minutes']} min on a 2-core laptop), then "
          f"{n_flights} test flights" + (" on GT depth and on predicted depth" if est else "")
          + f" -> {run_dir}", flush=True)
    t0 = time.time()
    # training: the student's change, including the depth corruption (exercise 8) ...
    run = train(cfg, run_dir, reward_fn=s["reward_fn"], depth_fn=s["depth_fn"],
                td_target=s["td_target"], progress=progress)
    t_train = time.time() - t0
    meta = {"train_config": {"actions": cfg.actions, "hfov_deg": cfg.hfov_deg}}
    actions, camera = trained_actions(meta), trained_camera(meta)
    run.save_model(run_dir / "model.npz", {"exercise": ex.name, "tag": tag})
    # the checkpoint holds the whole replay (~140 MB at budget small); an exercise run is
    # never resumed, so keep only the model
    (run_dir / "checkpoint.npz").unlink(missing_ok=True)
    # ... testing: the same actions and camera, but never a corruption of the depth
    policy = CountingPolicy(QNetPolicy(run.agent.online, name=tag), len(actions))
    res = evaluate_policy(policy, cfg.scenario, n_flights, EVAL_SEED, actions=actions,
                          camera=camera, flights_config=eval_flights_cfg, progress=progress)
    pred = None
    if est is not None:           # the same test flights, on the DispNet's depth
        pred = evaluate_policy(QNetPolicy(run.agent.online, name=f"{tag} pred"),
                               cfg.scenario, n_flights, EVAL_SEED, depth="pred",
                               depth_estimator=est, flights_config=eval_flights_cfg,
                               actions=actions, camera=camera, progress=progress)
    gif = _flight_gif(run_dir, flights=8 if budget != "smoke" else 2)
    share = policy.counts / max(1, policy.counts.sum())
    result = {"exercise": ex.name, "tag": tag, "budget": budget, "seed": seed,
              "variant": cfg.variant, "seq_len": cfg.window(), "hfov_deg": cfg.hfov_deg,
              "actions": actions.tolist(),
              "success": res.rate, "ci": [res.ci_low, res.ci_high], "flights": res.flights,
              "mean_steps": res.mean_steps, "action_share": np.round(share, 4).tolist(),
              "mean_abs_yaw_rate": float(share @ np.abs(actions[:, 1])),
              "train_seconds": round(t_train, 1), "gif": gif,
              "last_curve_row": run.curve[-1] if run.curve else {}}
    if pred is not None:
        result.update({"pred_success": pred.rate, "pred_ci": [pred.ci_low, pred.ci_high],
                       "pred_mean_steps": pred.mean_steps, "depth_model": est_path})
    (run_dir / "result.json").write_text(json.dumps(result, indent=2))
    print(f"\n{tag}: success {res.rate:.3f} [{res.ci_low:.3f}, {res.ci_high:.3f}] over "
          f"{res.flights} flights" + (" on GT depth" if pred is not None else "") +
          f", mean steps {res.mean_steps:.1f} / 50, trained in "
          f"{t_train / 60:.1f} min; learning curve: {run_dir / 'curve.png'}"
          + (f"; a test flight: {gif}" if gif else ""))
    if pred is not None:
        print(f"{tag}: success {pred.rate:.3f} [{pred.ci_low:.3f}, {pred.ci_high:.3f}] on the "
              f"same flights on predicted depth ({est_path}), mean steps "
              f"{pred.mean_steps:.1f} / 50; GT minus predicted: {res.rate - pred.rate:+.3f}")
    print(summary_table(ex.name, out))
    return result


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
    try:
        shown = str(path.resolve().relative_to(REPO_ROOT))
    except ValueError:
        shown = str(path)
    return load_depth_estimator(path), shown


def _flight_gif(run_dir: Path, flights: int = 8):
    """GIF of test flight 0 (top view | camera | depth | Q-values), with ``rl.fly``, with
    the actions and camera of the model file.

    Every run uses the same evaluation seed, so flight 0 starts in the same world and
    pose in every run: the GIFs of two runs compare one flight. Returns the path, or
    None if the GIF could not be made (it is a bonus, never a reason to fail a run).
    """
    try:
        from ..rl.fly import fly
        return fly(run_dir / "model.npz", None, "basic", EVAL_SEED, flights,
                   run_dir / "flight.gif").get("gif")
    except Exception as e:  # noqa: BLE001
        print(f"(no flight GIF: {type(e).__name__}: {e})")
        return None


# -- the depth exercise ----------------------------------------------------------------
def _sequence(data):
    from ..depth.data import Sequence
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


def _frames(out: Path, name: str, n: int, seed: int):
    from ..depth.data import collect, load_sequence, save_sequence
    path = out / f"{name}_{n}_s{seed}.npz"
    if path.is_file():
        return load_sequence(path)
    data = collect("basic", n, seed=seed, progress=False)
    save_sequence(path, data, {"scenario": "basic", "seed": seed})
    return _sequence(data)


def run_depth_exercise(ex: Exercise, module, budget: str = "small", seed: int = 0, out=OUT,
                       progress: bool = True, tag: str | None = None) -> dict:
    from ..depth.evaluate import DepthEstimator, comparison_picture, evaluate
    from ..depth.losses import LossConfig
    from ..depth.train import TrainConfig, Trainer

    b = DEPTH_BUDGETS[budget]
    tag = (tag or ("paper-L1" if module is None else "yours")) + \
        (f"-s{seed}" if seed else "") + ("" if budget == "small" else f"-{budget}")
    root = Path(out) / ex.name
    run_dir = root / tag
    run_dir.mkdir(parents=True, exist_ok=True)
    print(f"exercise {ex.name} [{tag}]: DispNet + PoseNet, {b['iterations']} iterations on "
          f"{b['frames']} frames (budget '{budget}', about {b['minutes']} min on a 2-core "
          f"laptop) -> {run_dir}", flush=True)
    train = _frames(root, "train", b["frames"], seed)
    test = _frames(root, "test", b["test_frames"], seed + 1000)
    loss = LossConfig(ssim_weight=0.0)          # the paper's L1, unless the student's error
    cfg = TrainConfig(iterations=b["iterations"], seed=seed, log_every=b["log_every"],
                      checkpoint_every=10 ** 9, loss=loss)
    fn = None if module is None else module.photometric_error
    t0 = time.time()
    trainer = Trainer(train, cfg, photometric_error=fn)
    trainer.run(progress=progress)
    t_train = time.time() - t0
    est = DepthEstimator(trainer.disp, trainer.speed_scale())
    metrics = evaluate(est, test)
    rows = np.linspace(0, len(test) - 1, 4).astype(int)
    comparison_picture(test.rgb[rows], est.predict(test.rgb[rows]), test.depth[rows],
                       run_dir / "pictures.png")
    result = {"exercise": ex.name, "tag": tag, "budget": budget, "seed": seed,
              **{k: float(v) for k, v in metrics.items() if np.isscalar(v)},
              "train_seconds": round(t_train, 1)}
    (run_dir / "result.json").write_text(json.dumps(result, indent=2))
    print(f"\n{tag}: abs rel {result.get('abs_rel', float('nan')):.3f}, delta<1.25 "
          f"{result.get('a1', float('nan')):.3f}, trained in {t_train / 60:.1f} min; "
          f"pictures (RGB | predicted | GT): {run_dir / 'pictures.png'}")
    print(summary_table(ex.name, out))
    return result


# -- the comparison table --------------------------------------------------------------
def summary_table(exercise: str, out=OUT) -> str:
    """Every result.json of an exercise so far, one line each."""
    rows = []
    for path in sorted(Path(out, exercise).glob("*/result.json")):
        try:
            rows.append(json.loads(path.read_text()))
        except (OSError, ValueError):
            continue
    if not rows:
        return f"(no runs of {exercise} yet)"
    if exercise == "depth-errors":
        lines = [f"{'':<22} {'':<7} {'--------- on GT depth ---------':>31} "
                 f"{'----- on predicted depth ------':>31}",
                 f"{'run':<22} {'budget':<7} {'success':>8} {'95% CI':>15} {'steps':>6} "
                 f"{'success':>8} {'95% CI':>15} {'steps':>6} {'GT-pred':>8} {'minutes':>8}"]
        for r in rows:
            ci = f"[{r['ci'][0]:.2f}, {r['ci'][1]:.2f}]"
            if "pred_success" in r:
                pci = f"[{r['pred_ci'][0]:.2f}, {r['pred_ci'][1]:.2f}]"
                pred = (f"{r['pred_success']:8.3f} {pci:>15} {r['pred_mean_steps']:6.1f} "
                        f"{r['success'] - r['pred_success']:+8.3f}")
            else:
                pred = f"{'-':>8} {'-':>15} {'-':>6} {'-':>8}"
            lines.append(f"{r['tag']:<22} {r['budget']:<7} {r['success']:8.3f} {ci:>15} "
                         f"{r['mean_steps']:6.1f} {pred} {r['train_seconds'] / 60:8.1f}")
    elif exercise == "depth-loss":
        lines = [f"{'run':<22} {'budget':<7} {'abs rel':>8} {'sq rel':>8} {'rmse':>7} "
                 f"{'d<1.25':>7} {'minutes':>8}"]
        for r in rows:
            lines.append(f"{r['tag']:<22} {r['budget']:<7} {r.get('abs_rel', np.nan):8.3f} "
                         f"{r.get('sq_rel', np.nan):8.3f} {r.get('rmse', np.nan):7.3f} "
                         f"{r.get('a1', np.nan):7.3f} {r['train_seconds'] / 60:8.1f}")
    else:
        lines = [f"{'run':<30} {'budget':<7} {'success':>8} {'95% CI':>15} {'steps':>6} "
                 f"{'|yaw|':>6} {'minutes':>8}"]
        for r in rows:
            ci = f"[{r['ci'][0]:.2f}, {r['ci'][1]:.2f}]"
            lines.append(f"{r['tag']:<30} {r['budget']:<7} {r['success']:8.3f} {ci:>15} "
                         f"{r['mean_steps']:6.1f} {r['mean_abs_yaw_rate']:6.3f} "
                         f"{r['train_seconds'] / 60:8.1f}")
    return f"\nAll runs of '{exercise}' in {Path(out, exercise)}:\n" + "\n".join(lines)


# -- entry point -----------------------------------------------------------------------
def run_exercise(name: str, file=None, baseline: bool = False, budget: str = "small",
                 variant: str | None = None, seed: int = 0, out=OUT, flights: int | None = None,
                 progress: bool = True, tag: str | None = None) -> dict:
    ex = find(name)
    if not ex.trains:
        path = Path(file) if file else default_path(ex.filename)
        report = ex.checker(path)
        print(report.text())
        print(f"\nExercise {ex.name} has nothing to train: passing the check is the result. "
              f"See {ex.doc} for the follow-up (use your op in a network).")
        return {"exercise": ex.name, "passed": report.passed}
    module = None
    if not baseline:
        path = Path(file) if file else default_path(ex.filename)
        _, module = _check_first(ex, path)
    if ex.trains == "depth":
        return run_depth_exercise(ex, module, budget, seed, out, progress, tag)
    return run_agent_exercise(ex, module, budget, variant, seed, out, flights, progress, tag)


def solution_path(ex: Exercise) -> Path:
    return REPO_ROOT / "docs" / "solutions" / ex.filename


__all__ = ["AGENT_BUDGETS", "DEPTH_BUDGETS", "run_exercise", "run_agent_exercise",
           "run_depth_exercise", "agent_settings", "summary_table", "EXERCISES"]
