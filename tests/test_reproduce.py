"""The ``reproduce`` pipeline end to end, with every budget at its smoke size."""
import json

import numpy as np
import pytest

from minid3rqn.io import load_npz
from minid3rqn.rl.reproduce import (FAMILY, QUICK_FAMILY, TRANSFER, reproduce, reproduce_distilled,
                                    reproduce_quick)
from minid3rqn.rl.train import SMOKE


def test_reproduce_pipeline_smoke(tmp_path):
    res = reproduce(out=tmp_path, budget={"smoke": True, "flights": 4}, workers=1)
    depth = tmp_path / "depth"
    for name in ["basic", "basic_finetuned", "basic_long", *TRANSFER]:
        assert (depth / name / "model.npz").exists(), name
    for sc in TRANSFER:                # the shipped recipe: from basic's last DispNet
        command = json.loads((depth / sc / "results.json").read_text())["command"]
        assert f"--init-from {depth / 'basic_long' / 'model.npz'}" in command, command
        assert "full_res=True" in command and "late_turns=0.5" in command, command
    agents = sorted(p.name for p in (tmp_path / "agent").iterdir())
    assert len(agents) == 2 * len(FAMILY)               # each trained, then fine-tuned
    assert sum(a.endswith("_finetuned") for a in agents) == len(FAMILY)
    assert len(res["table5"]) == 4 + len(FAMILY)        # 4 baselines + the family
    assert len(res["table6"]) == 5 * len(TRANSFER)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["table5"] == res["table5"]
    assert "Table 6" in (tmp_path / "results.md").read_text()


def test_reproduce_quick_smoke(tmp_path):
    """The quick reproduction at smoke size: the four nets on the shipped DispNet's depth,
    their checkpoints removed, Tables 5 and 6 on the test worlds with the paper's column
    and the note on what it can show; a second run reuses the finished nets."""
    budget = {**SMOKE, "hidden": 16, "replay_capacity": 4_000, "flights": 4}
    res = reproduce_quick(tmp_path, budget=budget)
    agents = tmp_path / "quick" / "agent"
    for v in QUICK_FAMILY:
        assert (agents / v / "model.npz").is_file() and not (agents / v / "checkpoint.npz").exists()
        assert "--depth pred" in load_npz(agents / v / "model.npz")[1]["command"]
    assert [r["policy"] for r in res["table5"]] == ["Straight", "Random", "D3RQN", "DDRQN",
                                                    "D3QN", "DDQN"]
    assert {r["scenario"] for r in res["table6"]} == set(TRANSFER)
    rows = res["table5"] + res["table6"]
    assert all(r["seed"] == 271828 for r in rows)
    assert all(r["depth"] == "pred" for r in rows if r["policy"] not in ("Straight", "Random"))
    text = (tmp_path / "quick" / "results.md").read_text()
    assert "0.994" in text and "cannot show" in text and "python -m minid3rqn reproduce" in text
    stamp = {v: (agents / v / "model.npz").stat().st_mtime_ns for v in QUICK_FAMILY}
    again = reproduce_quick(tmp_path, budget=budget, workers=2)
    assert stamp == {v: (agents / v / "model.npz").stat().st_mtime_ns for v in QUICK_FAMILY}
    assert [r["rate"] for r in again["table5"]] == [r["rate"] for r in res["table5"]]


def _weights(agents):
    return {p.parent.name: load_npz(p)[0] for p in sorted(agents.glob("*/model.npz"))}


def test_reproduce_distilled_smoke(tmp_path):
    """The distilled recipe end to end at smoke size: four parents (two at a time in
    forked processes), the two stages (each model recording the one command that makes
    it), the evaluations; the same models as one process after the other; and a second
    run that resumes every stage from its finished checkpoint."""
    budget = {"smoke": True, "flights": 4}
    res = reproduce_distilled(out=tmp_path / "a", students=2, tables="5", skip_depth=True,
                              budget=budget, workers=2)
    agents = tmp_path / "a" / "distil"
    for name in ["parent_s0", "parent_s1", "parent_wide_s0", "parent_wide_s1", "stage1_gt",
                 "stage2_student_s0", "stage2_student_s1"]:
        assert (agents / name / "model.npz").exists(), name
    meta = load_npz(agents / "stage2_student_s1" / "model.npz")[1]
    assert meta["command"].startswith("python -m minid3rqn distil ")
    for flag in ["--seed 1", "--teachers " + str(agents / "parent_s0"),
                 "--init-model " + str(agents / "stage1_gt" / "model.npz"),
                 "--depth-model "]:
        assert flag in meta["command"], (flag, meta["command"])
    stage1 = load_npz(agents / "stage1_gt" / "model.npz")[1]["command"]
    for flag in ["--set init_widen=True", "--set depth=gt", "--set distil_kl=0.0",
                 "--set mirror_augment=False",
                 "--init-model " + str(agents / "parent_wide_s0" / "model.npz")]:
        assert flag in stage1, (flag, stage1)
    parent = load_npz(agents / "parent_wide_s1" / "model.npz")[1]["command"]
    assert parent.startswith("python -m minid3rqn train-agent ") and \
        "--set conv_channels=8,16,16" in parent and "--seed 1" in parent, parent
    assert [r["scenario"] for r in res["students"]] == ["basic", "basic"]
    assert all(r["depth"] == "pred" for r in res["students"])
    assert res["teacher"]["depth"] == "gt" and res["teacher"]["spec"].count("+") == 3
    # the two students together, each with its mirror image: one row per world
    [both] = res["together"]
    assert both["mirror"] and both["depth"] == "pred" and both["scenario"] == "basic"
    assert both["spec"] == "+".join(str(agents / f"stage2_student_s{k}" / "model.npz")
                                    for k in (0, 1))
    assert "--mirror" in both["command"]
    saved = json.loads((agents / "results.json").read_text())
    assert saved["students"] == res["students"] and saved["together"] == res["together"]
    table = (agents / "results.md").read_text()
    assert "target" in table and "the 2 students together" in table
    first = _weights(agents)
    # one process after the other: the same runs
    serial = reproduce_distilled(out=tmp_path / "b", students=2, tables="5", skip_depth=True,
                                 budget=budget, workers=1)
    assert [r["rate"] for r in serial["students"]] == [r["rate"] for r in res["students"]]
    for name, arrays in _weights(tmp_path / "b" / "distil").items():
        assert set(arrays) == set(first[name]), name
        for k in arrays:
            assert np.array_equal(arrays[k], first[name][k]), (name, k)
    # run again in the first folder: every stage resumes from its finished checkpoint
    again = reproduce_distilled(out=tmp_path / "a", students=2, tables="5", skip_depth=True,
                                budget=budget)
    assert [r["rate"] for r in again["students"]] == [r["rate"] for r in res["students"]]
    for name, arrays in _weights(agents).items():
        for k in arrays:
            assert np.array_equal(arrays[k], first[name][k]), (name, k)


@pytest.mark.parametrize("argv, message", [
    (["--workers", "0"], "--workers: expected a number >= 1; got 0"),
    (["--students", "0"], "--students: expected a number >= 1; got 0"),
    (["--students", "2"], "--students 2: only for --recipe distil"),
    (["--recipe", "distil-short"], "argument --recipe: invalid choice"),
    (["--quick", "--recipe", "distil"], "--quick: the paper's recipe on the shipped DispNets"),
])
def test_reproduce_cli_errors(argv, message, tmp_path, capsys):
    """Settings the recipes cannot honour stop before any training, naming the flag."""
    from minid3rqn.cli import main
    try:
        code = main(["reproduce", "--out", str(tmp_path), *argv])
    except SystemExit as e:              # argparse's own refusal of a choice
        code = e.code
    assert code == 2 and message in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("spec", ["straight", "random"])
def test_policies_that_read_no_depth_fly_the_same_flights_on_either_depth(spec):
    """Why the quick reproduction flies Straight and Random on GT depth: the worlds, starts
    and actions do not depend on what depth the flights compute."""
    from minid3rqn.rl.evaluate import EvalConfig, evaluate_spec
    from minid3rqn.rl.models import MODELS, load_depth_estimator
    gt = evaluate_spec(spec, EvalConfig(flights=8, seed=3), progress=False)[1]
    pred = evaluate_spec(spec, EvalConfig(flights=8, seed=3, depth="pred"),
                         load_depth_estimator(MODELS / "depth_basic.npz"), progress=False)[1]
    for key in ("successes", "mean_steps", "world_seeds", "world_successes"):
        if key in gt:
            assert gt[key] == pred[key], key
