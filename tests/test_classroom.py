"""The classroom checkers: each passes the reference solution, and fails with a helpful
message on the unmodified template (where the exercise asks for a change) and on
deliberately broken solutions. Plus the change reaching training as a parameter."""
import argparse
import importlib
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
from PIL import Image
import pytest

from minid3rqn.classroom import EXERCISES, find
from minid3rqn.classroom import checks, student
from minid3rqn.classroom.commands import run_check
from minid3rqn.classroom.student import TEMPLATES

pytestmark = pytest.mark.classroom

ROOT = Path(__file__).resolve().parents[1]
SOLUTIONS = ROOT / "docs" / "solutions"
# What each untouched template's first failure says (None: the template passes its check:
# memory's 5 steps are the paper's value, and the exercise runs it as one of three).
FIRST_FAILURE = {"reward": "still the paper's", "actions": "still the paper's Table 3",
                 "fov": "still 90 degrees", "memory": None, "ablation": "nothing is removed",
                 "op": "not written yet", "depth-loss": "still plain L1",
                 "depth-errors": "returns the depth unchanged"}


def write(tmp_path, name, code):
    path = tmp_path / name
    path.write_text(textwrap.dedent(code))
    return path


def failed_with(report, *phrases):
    assert not report.passed, report.text()
    text = report.messages
    for phrase in phrases:
        assert phrase in text, f"{phrase!r} not in:\n{report.text()}"


# -- every exercise: the pristine template (as shipped in the package, never the student's
# -- copy in exercises/) fails with its intended message; the reference solution passes --
def test_registry_files_exist():
    assert list(EXERCISES) == list(FIRST_FAILURE)
    for ex in EXERCISES.values():
        assert (TEMPLATES / ex.filename).is_file(), ex.filename
        assert (SOLUTIONS / ex.filename).is_file(), ex.filename
        assert (ROOT / ex.doc).is_file(), ex.doc
    assert find("1").name == "reward" and find("depth_loss").name == "depth-loss"
    assert find("8").name == "depth-errors" and find("depth_errors").name == "depth-errors"
    with pytest.raises(ValueError, match="choose one of"):
        find("nope")


@pytest.fixture(params=["template", "solution"])
def version(request):
    return request.param


@pytest.mark.parametrize("name", sorted(EXERCISES))
def test_checker_on_template_and_solution(name, version):
    ex = EXERCISES[name]
    report = ex.checker((TEMPLATES if version == "template" else SOLUTIONS) / ex.filename)
    if version == "solution" or FIRST_FAILURE[name] is None:
        assert report.passed, report.text()
    else:
        assert not report.passed and FIRST_FAILURE[name] in report.failures[0], report.text()
        assert "Hint:" in report.failures[0], report.text()


def test_check_works_on_the_students_copy_made_from_the_template(tmp_path, monkeypatch):
    """`check` makes exercises/<file> from the template when it is missing, then checks
    the student's copy: with no exercise filled in only memory passes (its template is
    the paper's 5 steps); with every one filled in, all pass. The templates stay as
    shipped whatever the copies hold."""
    ns = argparse.Namespace
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(student, "exercises_folder", lambda: tmp_path / "exercises")
    assert run_check(ns(exercise="all", file=None)) == 1
    for ex in EXERCISES.values():
        copy = tmp_path / "exercises" / ex.filename
        assert copy.read_text() == (TEMPLATES / ex.filename).read_text()
        shutil.copyfile(SOLUTIONS / ex.filename, copy)
    assert run_check(ns(exercise="all", file=None)) == 0
    assert run_check(ns(exercise="all", file="exercises")) == 0
    report = EXERCISES["reward"].checker(TEMPLATES / "reward.py")
    assert not report.passed


# -- whatever the student's code does, the check reports it and goes on ---------------------
@pytest.mark.parametrize("body, phrase", [
    ("while True:\n        pass",
     "reward(0.5, False, 0.0) took longer than 0.2 s: an infinite loop?"),
    ("import sys\n    sys.exit(0)", "called exit() (SystemExit: 0) (your file, line 3"),
    ("raise KeyboardInterrupt", "was interrupted (Ctrl-C)"),
])
def test_student_code_that_does_not_return(tmp_path, monkeypatch, body, phrase):
    monkeypatch.setattr(student, "TIME_LIMIT", 0.2)
    path = write(tmp_path, "reward.py",
                 f"def reward(d_nearest, collided, yaw_rate=0.0):\n    {body}\n")
    failed_with(checks.check_reward(path), phrase)


def test_exit_or_endless_loop_when_the_file_loads(tmp_path, monkeypatch):
    monkeypatch.setattr(student, "TIME_LIMIT", 0.2)
    failed_with(checks.check_fov(write(tmp_path, "camera.py", "exit()\nHFOV_DEG = 60\n")),
                "importing camera.py called exit()")
    failed_with(checks.check_fov(write(tmp_path, "camera.py", "while 1:\n    pass\n")),
                "importing camera.py took longer than 0.2 s")


def test_check_command_exits_non_zero_when_the_student_exits(tmp_path):
    path = write(tmp_path, "reward.py", """
        import sys
        def reward(d_nearest, collided, yaw_rate=0.0):
            sys.exit(0)
        """)
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-m", "minid3rqn", "check", "reward", "--file",
                           str(path)], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 1 and "called exit()" in done.stdout, done.stdout + done.stderr


def test_missing_file_and_syntax_error(tmp_path):
    failed_with(checks.check_reward(tmp_path / "nothing.py"), "file not found")
    bad = write(tmp_path, "reward.py", "def reward(d, c)\n    return d\n")
    failed_with(checks.check_reward(bad), "Python cannot read", "line 1")


# -- 1. reward -------------------------------------------------------------------------
def test_reward_scalar_if_is_caught(tmp_path):
    path = write(tmp_path, "reward.py", """
        def reward(d_nearest, collided, yaw_rate=0.0):
            if collided:
                return -1.0
            return min(d_nearest, 3.0)
        """)
    failed_with(checks.check_reward(path), "arrays", "np.where")


def test_reward_forgot_return(tmp_path):
    path = write(tmp_path, "reward.py", """
        def reward(d_nearest, collided, yaw_rate=0.0):
            d_nearest * 2
        """)
    failed_with(checks.check_reward(path), "returned None", "return")


def test_reward_collision_not_worst(tmp_path):
    path = write(tmp_path, "reward.py", """
        import numpy as np
        def reward(d_nearest, collided, yaw_rate=0.0):
            return np.where(collided, 0.0, np.asarray(d_nearest) - 2.0 * np.abs(yaw_rate))
        """)
    failed_with(checks.check_reward(path), "collision must be worse")


def test_reward_with_other_arguments(tmp_path):
    path = write(tmp_path, "reward.py", """
        import numpy as np
        def reward(d_nearest):
            return np.asarray(d_nearest)
        """)
    failed_with(checks.check_reward(path), "cannot be called this way",
                "def reward(d_nearest, collided, yaw_rate=0.0)")


def test_reward_that_pays_for_turning(tmp_path):
    path = write(tmp_path, "reward.py", """
        import numpy as np
        def reward(d_nearest, collided, yaw_rate=0.0):
            return np.where(collided, -1.0, np.minimum(d_nearest, 3.0) + np.abs(yaw_rate))
        """)
    failed_with(checks.check_reward(path), "does not penalise turning")


def test_reward_two_argument_clip_passes(tmp_path):
    path = write(tmp_path, "reward.py", """
        import numpy as np
        def reward(d_nearest, collided):
            return np.where(collided, -1.0, np.minimum(d_nearest, 3.0))
        """)
    report = checks.check_reward(path)
    assert report.passed, report.text()
    assert report.summary["sees_yaw_rate"] is False


# -- 2. actions ------------------------------------------------------------------------
@pytest.mark.parametrize("table, phrase", [
    ("[[2.0, 0.0], [0.0, 0.0], [2.0, 0.5]]", "must be > 0"),
    ("[[2.0, 0.0], [2.0, 0.5], [2.0, 0.5]]", "identical"),
    ("[2.0, 0.0, 0.5]", "rows of two numbers"),
    ("[[2.0, 0.0]]", "at least 2 rows"),
])
def test_actions_broken(tmp_path, table, phrase):
    failed_with(checks.check_actions(write(tmp_path, "actions.py", f"ACTIONS = {table}\n")), phrase)


def test_actions_second_speed_reaches_env_and_head(tmp_path):
    path = write(tmp_path, "actions.py", "ACTIONS = [[2.0, 0.0], [2.0, 0.5], [2.0, -0.5], "
                                         "[1.0, 0.0]]\n")
    report = checks.check_actions(path)
    assert report.passed, report.text()
    assert "head has 4 outputs" in report.messages
    failed_with(checks.check_actions(TEMPLATES / "actions.py"), "still the paper's Table 3")


# -- 3. field of view ------------------------------------------------------------------
@pytest.mark.parametrize("value, phrase", [("200", "between 0 and 180"),
                                           ("'60'", "must be a number")])
def test_fov_broken(tmp_path, value, phrase):
    failed_with(checks.check_fov(write(tmp_path, "camera.py", f"HFOV_DEG = {value}\n")), phrase)


# -- 4. memory -------------------------------------------------------------------------
@pytest.mark.parametrize("value, phrase", [("0", "from 1 to 50"), ("'5'", "whole number"),
                                           ("2.5", "whole number"), ("True", "whole number")])
def test_memory_broken(tmp_path, value, phrase):
    failed_with(checks.check_memory(write(tmp_path, "memory.py", f"SEQ_LEN = {value}\n")), phrase)


@pytest.mark.parametrize("L", [1, 10])
def test_memory_lengths(tmp_path, L):
    report = checks.check_memory(write(tmp_path, "memory.py", f"SEQ_LEN = {L}\n"))
    assert report.passed and f"windows of {L} step" in report.messages


# -- 5. ablations ----------------------------------------------------------------------
def test_ablation_no_dueling_passes(tmp_path):
    code = (TEMPLATES / "ablation.py").read_text().replace("DUELING = True", "DUELING = False")
    report = checks.check_ablation(write(tmp_path, "ablation.py", code))
    assert report.passed, report.text()
    assert report.summary["variant"] == "ddrqn"


def test_ablation_forgets_terminals(tmp_path):
    path = write(tmp_path, "ablation.py", """
        import numpy as np
        DUELING = True
        def td_target(q_online_next, q_target_next, rewards, terminals, gamma):
            return rewards + gamma * q_target_next.max(axis=-1)
        """)
    failed_with(checks.check_ablation(path), "reward alone", "(1 - terminals)")


def test_ablation_forgets_reduction(tmp_path):
    path = write(tmp_path, "ablation.py", """
        DUELING = True
        def td_target(q_online_next, q_target_next, rewards, terminals, gamma):
            return rewards[..., None] + gamma * q_target_next
        """)
    failed_with(checks.check_ablation(path), "one target per step")


# -- 6. autograd op --------------------------------------------------------------------
OP_HEADER = """
    import numpy as np
    from minid3rqn import autograd as ag
    from minid3rqn.autograd import Tensor, as_tensor
    """


def test_op_wrong_backward(tmp_path):
    path = write(tmp_path, "my_op.py", OP_HEADER + """
    def leaky_relu(x, slope=0.01):
        x = as_tensor(x)
        y = np.where(x.data > 0, x.data, slope * x.data).astype(x.dtype)
        return Tensor.from_op(y, (x,), lambda g: (g,), "leaky_relu")
    """)
    failed_with(checks.check_op(path), "gradcheck failed", "dy/dx = 1 for x > 0")


def test_op_wrong_forward(tmp_path):
    path = write(tmp_path, "my_op.py", OP_HEADER + """
    def leaky_relu(x, slope=0.01):
        x = as_tensor(x)
        y = np.maximum(x.data, 0)
        return Tensor.from_op(y, (x,), lambda g: (g * (x.data > 0),), "leaky_relu")
    """)
    failed_with(checks.check_op(path), "forward is wrong")


def test_op_composed_from_other_ops(tmp_path):
    path = write(tmp_path, "my_op.py", OP_HEADER + """
    def leaky_relu(x, slope=0.01):
        x = as_tensor(x)
        return ag.maximum(x, x * slope)
    """)
    failed_with(checks.check_op(path), "built from other Tensor ops")


def test_op_gradcheck_catches_a_subtle_error(tmp_path):
    # right at the test points used by the direct check, wrong in general (uses y, not x)
    path = write(tmp_path, "my_op.py", OP_HEADER + """
    def leaky_relu(x, slope=0.01):
        x = as_tensor(x)
        scale = np.where(x.data > 0, 1.0, slope).astype(x.dtype)
        y = x.data * scale
        def vjp(g):
            return (g * scale if g.shape != (3, 5) else g * scale * (1 + 0.01 * y),)
        return Tensor.from_op(y, (x,), vjp, "leaky_relu")
    """)
    failed_with(checks.check_op(path), "gradcheck failed")


# -- 7. depth loss ---------------------------------------------------------------------
def test_photometric_mixes_the_batch(tmp_path):
    path = write(tmp_path, "photometric.py", """
        from minid3rqn import autograd as ag
        def photometric_error(pred, target):
            e = ag.mean(ag.abs(pred - target), axis=1, keepdims=True)
            return e * 0.5 + ag.mean(e, axis=0, keepdims=True) * 0.5
        """)
    failed_with(checks.check_photometric(path), "image 0 changes")


def test_photometric_without_gradients(tmp_path):
    path = write(tmp_path, "photometric.py", """
        import numpy as np
        from minid3rqn.autograd import Tensor
        def photometric_error(pred, target):
            return Tensor(np.abs(pred.data - target.data).mean(axis=1, keepdims=True) * 1.5)
        """)
    failed_with(checks.check_photometric(path), "gradients into the warped image")


def test_photometric_other_alpha(tmp_path):
    code = (SOLUTIONS / "photometric.py").read_text().replace("ALPHA = 0.85", "ALPHA = 0.5")
    report = checks.check_photometric(write(tmp_path, "photometric.py", code))
    assert report.passed and abs(report.summary["alpha"] - 0.5) < 1e-6


# -- 8. depth errors -------------------------------------------------------------------
def test_depth_errors_template_has_work_to_do():
    report = checks.check_depth_errors(TEMPLATES / "depth_errors.py")
    failed_with(report, "returns the depth unchanged", "--baseline")
    assert report.summary["log_error"]["total"] == 0.0


def test_depth_errors_solution_compares_with_the_dispnet():
    report = checks.check_depth_errors(SOLUTIONS / "depth_errors.py")
    assert report.passed, report.text()
    assert "DispNet" in report.messages and "per column" in report.messages
    parts = report.summary["log_error"]
    assert 0.08 < parts["total"] < 0.25 and parts["per column"] > parts["per row"], parts
    assert "too strong" not in report.messages


@pytest.mark.parametrize("body, phrases", [
    ("return depth[0]", ["input's shape (32, 32, 104)", "got shape (32, 104)"]),
    ("return depth + rng.normal(0.0, 3.0, depth.shape)", ["<= 0", "depth * np.exp(e)"]),
    ("return np.round(depth).astype(int) + 1", ["floating-point", "int64"]),
    ("return depth * np.exp(0.1 * (depth - depth.mean()) / depth.std())",
     ["non-finite", "30 m away"]),
    ("depth *= np.float32(1.1)\n    return depth", ["in place", "depth.copy()"]),
    ("depth[:, :, :10] = 1.0\n    return depth * 1.0", ["in place"]),
    ("return depth * np.exp(np.random.normal(0.0, 0.1, depth.shape))",
     ["global random generator", "rng.normal"]),
    ("return depth * np.exp(np.random.default_rng().normal(0.0, 0.1, depth.shape))",
     ["same rng seed gave a different", "from `rng` only"]),
    ("return None", ["returned None", "return"]),
])
def test_depth_errors_broken(tmp_path, body, phrases):
    path = write(tmp_path, "depth_errors.py",
                 f"import numpy as np\n\n\ndef corrupt(depth, rng):\n    {body}\n")
    with np.errstate(all="ignore"):
        report = checks.check_depth_errors(path)
    failed_with(report, *phrases)
    assert "Hint:" in report.messages


def test_depth_errors_notes_a_strong_or_fixed_error(tmp_path):
    strong = write(tmp_path, "strong.py", """
        import numpy as np
        def corrupt(depth, rng):
            return depth * np.exp(rng.normal(0.0, 0.8, depth.shape))
        """)
    report = checks.check_depth_errors(strong)
    assert report.passed and "too strong" in report.messages, report.text()
    fixed = write(tmp_path, "fixed.py", """
        def corrupt(depth, rng):
            return depth * 0.8
        """)
    report = checks.check_depth_errors(fixed)
    assert report.passed and "fixed distortion" in report.messages, report.text()


def test_depth_errors_wrong_signature(tmp_path):
    path = write(tmp_path, "depth_errors.py", "def corrupt(depth):\n    return depth\n")
    failed_with(checks.check_depth_errors(path), "cannot be called this way",
                "def corrupt(depth, rng)")


def test_log_error_parts_splits_the_error():
    from minid3rqn.depth.evaluate import log_error_parts
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 8.0, (400, 32, 104))
    per_frame = depth * np.exp(rng.normal(0.0, 0.1, (400, 1, 1)))
    parts = log_error_parts(depth, np.clip(per_frame, 0.5, 10.0))
    assert parts["per column"] < 0.02 and parts["per row"] < 0.02 and parts["rest"] < 0.02
    per_column = depth * np.exp(rng.normal(0.0, 0.1, (400, 1, 104)))
    parts = log_error_parts(depth, np.clip(per_column, 0.5, 10.0))
    assert parts["per column"] > 5 * max(parts["per row"], parts["rest"]), parts


def test_depth_fn_applies_to_the_env_given_it_only():
    """DroneEnv(depth_fn=...) corrupts every depth map it observes (training); an env
    made without it (the runner's test flights) sees the depth as it is; the same seed
    flies the same worlds and start poses either way."""
    from minid3rqn.world import DroneEnv

    def double(depth, rng):
        return depth * 2.0

    env = DroneEnv("basic", 3, seed=0, n_worlds=2, depth_fn=double)
    obs, _ = env.reset()
    np.testing.assert_allclose(obs, 2.0 * env.gt_depth(), rtol=1e-6)
    obs = env.step(np.zeros(3, np.int64))[0]
    np.testing.assert_allclose(obs, 2.0 * env.gt_depth(), rtol=1e-6)
    plain = DroneEnv("basic", 3, seed=0, n_worlds=2)
    noisy = DroneEnv("basic", 3, seed=0, n_worlds=2,
                     depth_fn=lambda d, rng: d * rng.uniform(0.5, 2.0))
    plain_obs, noisy_obs = plain.reset()[0], noisy.reset()[0]
    assert np.array_equal(plain.world_seeds, noisy.world_seeds)
    np.testing.assert_array_equal(plain.poses, noisy.poses)
    assert not np.allclose(plain_obs, noisy_obs)
    np.testing.assert_array_equal(plain_obs, plain.gt_depth())
    # a corruption that breaks the depth is stopped with a clear message
    bad = DroneEnv("basic", 2, seed=0, n_worlds=2, depth_fn=lambda d, rng: -d)
    with pytest.raises(ValueError, match="positive finite"):
        bad.reset()


def test_run_depth_errors_smoke(tmp_path, monkeypatch):
    """Training sees the corruption, the test flights (GT and predicted) never do, and
    the result holds both success rates."""
    import importlib
    from minid3rqn.classroom.student import Report, load
    from minid3rqn.classroom.runner import run_agent_exercise
    module = load(SOLUTIONS / "depth_errors.py", Report("8", SOLUTIONS / "depth_errors.py"))
    calls = {"train": 0, "test": 0}
    testing = [False]
    solution = module.corrupt

    def spy(depth, rng):
        assert depth.ndim == 3 and depth.shape[1:] == (32, 104)
        calls["test" if testing[0] else "train"] += 1
        return solution(depth, rng)

    module.corrupt = spy
    ev = importlib.import_module("minid3rqn.rl.evaluate")
    evaluate = ev.evaluate_policy
    depths = []

    def watched(*args, **kwargs):
        testing[0] = True
        depths.append(kwargs.get("depth", "gt"))
        try:
            return evaluate(*args, **kwargs)
        finally:
            testing[0] = False

    monkeypatch.setattr(ev, "evaluate_policy", watched)
    res = run_agent_exercise(EXERCISES["depth-errors"], module, budget="smoke", out=tmp_path,
                             progress=False)
    assert calls["train"] > 0 and calls["test"] == 0, calls
    assert depths == ["gt", "pred"]
    assert 0.0 <= res["success"] <= 1.0 and 0.0 <= res["pred_success"] <= 1.0
    assert res["pred_mean_steps"] > 0 and res["depth_model"].endswith("depth_basic.npz")
    saved = json.loads((tmp_path / "depth-errors" / res["tag"] / "result.json").read_text())
    assert saved["pred_ci"] == res["pred_ci"]
    from minid3rqn.classroom.runner import summary_table
    table = summary_table("depth-errors", tmp_path)
    assert "on predicted depth" in table and res["tag"] in table


# -- the student's change reaches training as a parameter ----------------------------------
def test_the_env_pays_the_students_reward():
    from minid3rqn.world import DroneEnv
    seen = {}

    def reward(d, collided, yaw_rate=0.0):
        seen["yaw"] = np.asarray(yaw_rate).copy()
        return np.where(collided, -1.0, 7.0 - np.abs(yaw_rate))

    env = DroneEnv("basic", 3, seed=0, n_worlds=2, reward_fn=reward, observation=None)
    env.reset()
    _, rewards, terminated, _, _ = env.step(np.array([0, 3, 4]))
    np.testing.assert_allclose(seen["yaw"], [0.0, 0.5, -0.5])
    want = np.where(terminated, -1.0, 7.0 - np.array([0.0, 0.5, 0.5]))
    np.testing.assert_allclose(rewards, want)
    two = DroneEnv("basic", 3, seed=0, n_worlds=2, observation=None,
                   reward_fn=lambda d, c: np.where(c, -1.0, 3.0))
    two.reset()
    _, rewards, terminated, _, _ = two.step(np.array([0, 3, 4]))
    np.testing.assert_allclose(rewards, np.where(terminated, -1.0, 3.0))


# -- the runner and the CLI hooks ------------------------------------------------------
def test_run_agent_exercise_smoke(tmp_path):
    from minid3rqn.classroom.runner import run_exercise
    from minid3rqn.io import load_npz
    res = run_exercise("actions", file=SOLUTIONS / "actions.py", budget="smoke", out=tmp_path,
                       progress=False)
    assert len(res["actions"]) == 7 and len(res["action_share"]) == 7
    _, meta = load_npz(tmp_path / "actions" / res["tag"] / "model.npz")
    assert meta["qnet_config"]["n_actions"] == 7
    saved = json.loads((tmp_path / "actions" / res["tag"] / "result.json").read_text())
    assert 0.0 <= saved["success"] <= 1.0
    assert not (tmp_path / "actions" / res["tag"] / "checkpoint.npz").exists()
    assert res["gif"] and Path(res["gif"]).is_file()
    # the 7-action model flies with its own table: evaluate reads it from the file
    from minid3rqn.rl.evaluate import evaluate_policy
    from minid3rqn.rl.models import load_policy
    pol = load_policy(str(tmp_path / "actions" / res["tag"] / "model.npz"))
    assert evaluate_policy(pol, "basic", n_flights=2, chunk=2, max_steps=2,
                           progress=False).flights == 2


def test_the_papers_setting_is_trained_once_and_reused(tmp_path, monkeypatch):
    """The baselines of the agent exercises are one training per budget and seed: the
    first trains it into runs/classroom/baseline/<key>, the others (and a student's run
    that asks for the paper's setting) reuse it."""
    from minid3rqn.classroom.runner import run_exercise
    first = run_exercise("reward", baseline=True, budget="smoke", out=tmp_path, progress=False)
    assert Path(first["model"]).parent.parent == tmp_path / "baseline"
    clip = write(tmp_path, "clip.py", "import numpy as np\n\ndef reward(d, collided):\n"
                                      "    return np.where(collided, -1.0, np.minimum(d, 3.0))\n")
    mine = run_exercise("reward", file=clip, budget="smoke", out=tmp_path, progress=False)
    assert mine["tag"] == "clip-smoke"                # a run is named after its file
    titles = []                                       # each learning curve names its run
    for res in (first, mine):
        with Image.open(Path(res["model"]).parent / "curve.png") as im:
            titles.append(im.text["Title"])
    assert titles[0].startswith("baseline/d3rqn-basic-smoke-s0-"), titles
    assert titles[1].startswith("reward/clip-smoke: d3rqn on basic, seed 0"), titles

    def no_training(*args, **kwargs):
        raise AssertionError("the paper's setting was trained a second time")

    monkeypatch.setattr(importlib.import_module("minid3rqn.rl.train"), "train", no_training)
    again = run_exercise("actions", baseline=True, budget="smoke", out=tmp_path, progress=False)
    five = write(tmp_path, "memory.py", "SEQ_LEN = 5\n")
    memory = run_exercise("memory", file=five, budget="smoke", out=tmp_path, progress=False)
    for res in (again, memory):
        assert res["model"] == first["model"] and res["success"] == first["success"]
        assert res["mean_steps"] == first["mean_steps"]
    assert (tmp_path / "actions" / "paper-smoke" / "result.json").is_file()
    with pytest.raises(AssertionError, match="a second time"):      # another seed: trained
        run_exercise("reward", baseline=True, budget="smoke", seed=1, out=tmp_path,
                     progress=False)
    with pytest.raises(AssertionError, match="a second time"):      # a student's change:
        run_exercise("reward", file=clip, budget="smoke", out=tmp_path, progress=False)


def test_the_papers_setting_is_trained_again_after_an_edit_of_the_package(tmp_path, monkeypatch,
                                                                          capsys):
    """A baseline is keyed by the package's code too: after an edit (another source
    digest) the paper's setting is trained again, and the run says so in one line."""
    from minid3rqn.classroom import runner
    first = runner.run_exercise("reward", baseline=True, budget="smoke", out=tmp_path,
                                progress=False)
    assert capsys.readouterr().out.count("has changed") == 0
    monkeypatch.setattr(runner, "source_digest", lambda root=None: "0" * 40)
    again = runner.run_exercise("reward", baseline=True, budget="smoke", out=tmp_path,
                                progress=False)
    said = [line for line in capsys.readouterr().out.split("\n") if "has changed" in line]
    assert len(said) == 1 and str(Path(first["model"]).parent) in said[0], said
    assert again["model"] != first["model"] and Path(again["model"]).is_file()



def test_source_digest_follows_the_code(tmp_path):
    from minid3rqn.classroom.runner import source_digest
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "classroom" / "templates").mkdir(parents=True)
    (tmp_path / "classroom" / "templates" / "reward.py").write_text("y = 1\n")
    before = source_digest(tmp_path)
    (tmp_path / "classroom" / "templates" / "reward.py").write_text("y = 2\n")
    assert source_digest(tmp_path) == before          # the templates never train
    (tmp_path / "a.py").write_text("x = 2\n")
    assert source_digest(tmp_path) != before


def test_run_depth_exercise_smoke(tmp_path):
    from minid3rqn.classroom.runner import run_exercise
    res = run_exercise("depth-loss", file=SOLUTIONS / "photometric.py", budget="smoke",
                       out=tmp_path, progress=False)
    assert np.isfinite(res["abs_rel"])
    assert (tmp_path / "depth-loss" / res["tag"] / "pictures.png").is_file()


def test_run_exercise_refuses_a_failing_file(tmp_path):
    from minid3rqn.classroom.runner import run_exercise
    with pytest.raises(SystemExit, match="fix the problems"):
        run_exercise("reward", file=TEMPLATES / "reward.py", budget="smoke", out=tmp_path,
                     progress=False)


def test_check_command(capsys):
    ns = argparse.Namespace
    assert run_check(ns(exercise="reward", file=str(TEMPLATES / "reward.py"))) == 1
    assert "NOT YET" in capsys.readouterr().out
    assert run_check(ns(exercise="all", file=str(SOLUTIONS))) == 0
    assert "8/8 exercises pass" in capsys.readouterr().out


def test_student_code_failing_during_training_is_named_with_its_line(tmp_path):
    """A reward that passes the check but raises later, in training: the run ends with one
    message naming the student's file and line, not a traceback into the library."""
    from minid3rqn.classroom.runner import run_exercise
    late = write(tmp_path, "late.py", "import numpy as np\ncalls = [0]\n\n\n"   # the smoke
                                      "def reward(d, collided):\n"                # budget flies 8
                                      "    calls[0] += np.size(d) == 8\n"
                                      "    if calls[0] > 4:\n"
                                      "        raise ValueError('late trouble')\n"
                                      "    return np.where(collided, -1.0, np.minimum(d, 3.0))\n")
    with pytest.raises(SystemExit, match=r"late.py raised ValueError at line 8 during the run"):
        run_exercise("reward", file=late, budget="smoke", out=tmp_path, progress=False)


def test_a_file_that_is_not_utf8_is_the_students_problem(tmp_path):
    """A file saved in another encoding: the check says so, not that the checker broke."""
    path = tmp_path / "reward.py"
    path.write_bytes(b"# caf\xe9\ndef reward(d, collided):\n    return 0.0\n")
    report = EXERCISES["reward"].checker(path)
    assert not report.passed and "is not UTF-8 text" in report.messages
    assert "checker itself" not in report.messages


def test_an_exercise_run_is_one_command_at_a_time(tmp_path):
    """A run whose folder another command holds is refused in one line, before any
    training, naming the option that gives another run; the folder is left as it was."""
    from minid3rqn.classroom.runner import run_exercise
    from minid3rqn.io import Busy, hold
    clip = tmp_path / "clip.py"
    clip.write_text((SOLUTIONS / "reward.py").read_text())
    with hold(tmp_path / "reward" / "clip-smoke", "--file"):
        with pytest.raises(Busy, match="--file: .*clip-smoke.* is in use by another command"):
            run_exercise("reward", file=clip, budget="smoke", out=tmp_path, progress=False)
    assert not (tmp_path / "reward" / "clip-smoke").exists()
    with hold(tmp_path / "depth-loss" / "paper-L1-smoke", "--seed"):
        with pytest.raises(Busy, match="--seed: .*paper-L1-smoke"):
            run_exercise("depth-loss", baseline=True, budget="smoke", out=tmp_path,
                         progress=False)
