"""The ``reproduce`` pipeline end to end, with every budget at its smoke size."""
import json
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.io import load_npz
from minid3rqn.rl.reproduce import (FAMILY, TRANSFER, distil_budget, parent_kinds, reproduce,
                                    reproduce_distilled)


def test_reproduce_pipeline_smoke(tmp_path):
    res = reproduce(out=tmp_path, budget={"smoke": True, "flights": 4}, workers=1)
    depth = tmp_path / "depth"
    for name in ["basic", "basic_finetuned", "basic_long", *TRANSFER]:
        assert (depth / name / "model.npz").exists(), name
    for sc in TRANSFER:                # the shipped recipe: from basic's last DispNet
        command = json.loads((depth / sc / "results.json").read_text())["command"]
        assert f"--init-from {depth / 'basic_long' / 'model.npz'}" in command, command
        assert "full_res=True" in command and "--late-turns 0.5" in command, command
    agents = sorted(p.name for p in (tmp_path / "agent").iterdir())
    assert len(agents) == 2 * len(FAMILY)               # each trained, then fine-tuned
    assert sum(a.endswith("_finetuned") for a in agents) == len(FAMILY)
    assert len(res["table5"]) == 4 + len(FAMILY)        # 4 baselines + the family
    assert len(res["table6"]) == 5 * len(TRANSFER)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["table5"] == res["table5"]
    assert "Table 6" in (tmp_path / "results.md").read_text()


def _weights(agents):
    return {p.parent.name: load_npz(p)[0] for p in sorted(agents.glob("*/model.npz"))}


def test_reproduce_distilled_smoke(tmp_path):
    """The distilled recipe end to end at smoke size: four parents (two at a time in
    forked processes), the two stages (the student's commands carrying the recipe's
    flags), the evaluations; the same models as one process after the other; and a
    second run that resumes every stage from its finished checkpoint."""
    budget = {"smoke": True, "flights": 4}
    res = reproduce_distilled(out=tmp_path / "a", students=2, tables="5", skip_depth=True,
                              budget=budget, workers=2)
    agents = tmp_path / "a" / "distil"
    for name in ["parent_s0", "parent_s1", "parent_wide_s0", "parent_wide_s1", "stage1_gt",
                 "stage2_student_s0", "stage2_student_s1"]:
        assert (agents / name / "model.npz").exists(), name
    meta = load_npz(agents / "stage2_student_s1" / "model.npz")[1]
    for flag in ["--seed 1", "--depth pred", "--mirror-augment", "--distil-kl 1",
                 "--distil-temperature 0.1", "--teachers " + str(agents / "parent_s0"),
                 "--init-model " + str(agents / "stage1_gt" / "model.npz")]:
        assert flag in meta["command"], (flag, meta["command"])
    stage1 = load_npz(agents / "stage1_gt" / "model.npz")[1]["command"]
    assert "--init-widen" in stage1 and "--depth gt" in stage1, stage1
    assert "--init-model " + str(agents / "parent_wide_s0" / "model.npz") in stage1, stage1
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


def test_reproduce_distilled_short_smoke(tmp_path):
    """The short chain: only the two wide parents, at SHORT's budget (120k transitions,
    epsilon over 50k), their pair the teacher; the stages as in the full recipe. With
    ``start="best"`` stage 1 grows the wide parent that flies the validation worlds
    better (a tie keeps seed 0)."""
    res = reproduce_distilled(out=tmp_path, students=1, tables="5", skip_depth=True,
                              budget={"smoke": True, "flights": 4, "val_flights": 4},
                              short=True, start="best")
    agents = tmp_path / "distil"
    assert sorted(p.name for p in agents.iterdir() if p.is_dir()) == [
        "parent_wide_s0", "parent_wide_s1", "stage1_gt", "stage2_student_s0"]
    parent = load_npz(agents / "parent_wide_s1" / "model.npz")[1]["command"]
    for flag in ["--steps 120000", "--eps-decay 50000", "--conv-channels 8,16,16", "--seed 1"]:
        assert flag in parent, (flag, parent)
    assert res["recipe"] == "distil-short" and res["budget"]["steps"] == 120_000
    assert res["teacher"]["spec"].count("+") == 1 and "parent_wide_s1" in res["teacher"]["spec"]
    assert "the two wide parents" in (agents / "results.md").read_text()
    assert "together" not in res            # one student: nothing to fly together
    val = res["validation"]
    assert [v["world_set"] for v in val] == ["validation"] * 2
    assert all("--validation" in v["command"] and v["flights"] == 4 for v in val)
    best = max(range(2), key=lambda i: (val[i]["rate"], -i))
    assert res["start"] == val[best]["spec"]
    stage1 = load_npz(agents / "stage1_gt" / "model.npz")[1]["command"]
    assert f"--init-model {res['start']}" in stage1, stage1


def test_reproduce_distilled_without_stage1_smoke(tmp_path):
    """``stage1=False`` (``--skip-stage1``) with one wide parent (``--wide-parents 1``):
    no stage 1 run; stage 2 starts from the parent itself, its LSTM grown. The students'
    replay windows (``--student-seq-len 10 --student-batch-size 16``) reach the student's
    command and only the student's: the parent keeps the paper's 5 x 32."""
    res = reproduce_distilled(out=tmp_path, students=1, tables="5", skip_depth=True,
                              budget={"smoke": True, "flights": 4}, short=True,
                              wide_parents=1, stage1=False, student_seq_len=10,
                              student_batch_size=16)
    agents = tmp_path / "distil"
    assert sorted(p.name for p in agents.iterdir() if p.is_dir()) == [
        "parent_wide_s0", "stage2_student_s0"]
    student = load_npz(agents / "stage2_student_s0" / "model.npz")[1]["command"]
    assert f"--init-model {agents / 'parent_wide_s0' / 'model.npz'} --init-widen" in student
    assert "--seq-len 10 --batch-size 16" in student, student
    parent = load_npz(agents / "parent_wide_s0" / "model.npz")[1]["command"]
    assert "--seq-len" not in parent and "--batch-size" not in parent, parent
    assert (res["student_seq_len"], res["student_batch_size"]) == (10, 16)
    assert "--teachers " + str(agents / "parent_wide_s0" / "model.npz") in student
    assert res["stage1"] is False and "+" not in res["teacher"]["spec"]
    table = (agents / "results.md").read_text()
    assert "the one wide parents" not in table and "No stage 1" in table


def test_distil_budget_parent_steps():
    """The presets' parents (240k and 120k, epsilon over 5/12 of them) and any other length
    with the same share; the stages keep their budgets."""
    assert (distil_budget()["steps"], distil_budget()["eps_decay"]) == (240_000, 100_000)
    short = distil_budget(short=True)
    assert (short["steps"], short["eps_decay"]) == (120_000, 50_000)
    for kw in ({}, {"short": True}):
        b = distil_budget(parent_steps=150_000, **kw)
        assert (b["steps"], b["eps_decay"]) == (150_000, 62_500)
        assert b["stage1_steps"] == distil_budget()["stage1_steps"]
    with pytest.raises(ValueError, match="parent_steps must exceed .* \\(5000\\); got 4000"):
        distil_budget(parent_steps=4000)


def test_parent_kinds():
    """The presets' parents (two narrow and two wide; the short chain: the two wide), and
    ``--wide-parents K``: K wide ones, seeds 0 to K-1, every run name distinct."""
    assert [name for name, *_ in parent_kinds()] == [
        "parent_s0", "parent_s1", "parent_wide_s0", "parent_wide_s1"]
    assert [name for name, *_ in parent_kinds(short=True)] == ["parent_wide_s0", "parent_wide_s1"]
    four = parent_kinds(short=True, wide_parents=4)
    assert [(name, seed) for name, seed, _ in four] == [
        (f"parent_wide_s{k}", k) for k in range(4)]
    assert all(torso == ["--conv-channels", "8,16,16"] for *_, torso in four)
    assert len(parent_kinds(wide_parents=3)) == 5
    with pytest.raises(ValueError, match="wide_parents must be >= 1; got 0"):
        parent_kinds(wide_parents=0)


def test_reproduce_students_error():
    with pytest.raises(ValueError, match="students must be >= 1; got 0"):
        reproduce_distilled(out=Path("unused"), students=0)
    with pytest.raises(ValueError, match="start must be 'first' or 'best'; got 'last'"):
        reproduce_distilled(out=Path("unused"), start="last")
    with pytest.raises(ValueError, match="student_seq_len must be an integer >= 1; got 0"):
        reproduce_distilled(out=Path("unused"), student_seq_len=0)
    with pytest.raises(ValueError, match="student_batch_size must be an integer >= 1; got 2.5"):
        reproduce_distilled(out=Path("unused"), student_batch_size=2.5)


@pytest.mark.parametrize("argv, message", [
    (["--workers", "0"], "--workers: expected a number of processes >= 1; got 0"),
    (["--students", "0"], "--students: expected a number of students >= 1; got 0"),
    (["--students", "2"], "--students 2: only for --recipe distil"),
    (["--recipe", "distil-short", "--depth", "gt"], "--recipe distil-short: its stages"),
    (["--recipe", "distil", "--depth", "gt"], "--recipe distil: its stages are fixed"),
    (["--parent-steps", "150000"], "--parent-steps 150000: only for --recipe distil"),
    (["--start", "best"], "--start best: only for --recipe distil"),
    (["--wide-parents", "4"], "--wide-parents 4: only for --recipe distil"),
    (["--skip-stage1"], "--skip-stage1: only for --recipe distil"),
    (["--student-seq-len", "10"], "--student-seq-len 10: only for --recipe distil"),
    (["--student-batch-size", "16"], "--student-batch-size 16: only for --recipe distil"),
    (["--recipe", "distil-short", "--student-seq-len", "0"],
     "--student-seq-len: expected an integer >= 1; got 0"),
    (["--recipe", "distil-short", "--student-batch-size", "-1"],
     "--student-batch-size: expected an integer >= 1; got -1"),
    (["--recipe", "distil-short", "--wide-parents", "0"],
     "--wide-parents: expected a number of parents >= 1; got 0"),
    (["--recipe", "distil-short", "--parent-steps", "5000"],
     "--parent-steps: expected more transitions than the parents' learning start \\(5000\\); "
     "got 5000"),
])
def test_reproduce_cli_errors(argv, message, tmp_path):
    """Settings the recipes cannot honour stop before any training, naming the flag."""
    from minid3rqn.cli import main
    with pytest.raises(SystemExit, match=message):
        main(["reproduce", "--out", str(tmp_path), *argv])
    assert not any(tmp_path.iterdir())
