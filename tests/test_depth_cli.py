"""The depth commands (collect, train-depth, eval-depth) and the example, in smoke mode."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.depth import commands

pytestmark = pytest.mark.depth
ROOT = Path(__file__).resolve().parent.parent


def _run(argv):
    return commands.main(argv)


def test_collect_train_eval_smoke(tmp_path, capsys):
    data = tmp_path / "train.npz"
    assert _run(["collect", "--frames", "20", "--frames-per-flight", "10", "--out",
                 str(data)]) == 0
    run = tmp_path / "run"
    assert _run(["train-depth", "--smoke", "--quiet", "--dir", str(run)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert {"abs_rel", "a1", "rot_err_deg"} <= set(out)
    assert (run / "model.npz").is_file() and (run / "pictures.png").is_file()
    meta = json.loads((run / "results.json").read_text())
    assert meta["seed"] == 0 and meta["command"].startswith("python -m minid3rqn train-depth")
    assert "--seed 0" in meta["command"] and "--smoke" in meta["command"]
    assert meta["machine"]["numpy"] == np.__version__ and meta["machine"]["blas_core"]
    # resume: a finished run resumes at its last iteration and does no more work
    assert _run(["train-depth", "--smoke", "--quiet", "--resume", "--dir", str(run)]) == 0
    assert "resuming at iteration 3" in capsys.readouterr().out
    assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                 str(run / "test.npz"), "--json", str(tmp_path / "m.json")]) == 0
    assert 0 <= json.loads((tmp_path / "m.json").read_text())["a1"] <= 1
    assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                 str(run / "test.npz"), "--flip-tta", "--json", str(tmp_path / "f.json")]) == 0
    assert 0 <= json.loads((tmp_path / "f.json").read_text())["a1"] <= 1
    # --posenet: the checkpoint's PoseNet is judged too, and equals the training's own
    # final pose evaluation; a model file (DispNet only) is refused by name
    assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                 str(run / "test.npz"), "--posenet", str(run / "checkpoint.npz"),
                 "--json", str(tmp_path / "p.json")]) == 0
    got = json.loads((tmp_path / "p.json").read_text())
    assert got["trans_err_m"] == pytest.approx(meta["results"]["trans_err_m"], abs=1e-4)
    with pytest.raises(ValueError, match="holds no PoseNet"):
        _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
              str(run / "test.npz"), "--posenet", str(run / "model.npz")])


def test_a_raised_horizon_is_kept_with_the_data_and_the_model(tmp_path, capsys):
    """train-depth --horizon-row films its frames with that camera and records it in the
    model; eval-depth then films its own held-out frames the same way; frames filmed
    with another horizon are refused by name, not silently mixed."""
    run = tmp_path / "run"
    assert _run(["train-depth", "--smoke", "--quiet", "--horizon-row", "4", "--dir",
                 str(run)]) == 0
    from minid3rqn.depth.data import load_sequence
    from minid3rqn.depth.evaluate import DepthEstimator
    assert load_sequence(run / "train.npz").K[1, 2] == 4.0
    assert DepthEstimator.load(run / "model.npz").horizon_row == 4.0
    assert DepthEstimator.load(run / "checkpoint.npz").horizon_row == 4.0
    capsys.readouterr()
    fresh = tmp_path / "fresh_test.npz"            # collected here, with the model's camera
    assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-frames", "6",
                 "--test-data", str(fresh)]) == 0
    assert load_sequence(fresh).K[1, 2] == 4.0
    with pytest.raises(SystemExit, match="horizon at row 4.*row 15.5"):
        _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
              str(run / "test.npz"), "--horizon-row", "15.5"])
    capsys.readouterr()                            # --band: the rows both cameras see
    assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                 str(fresh), "--band", "4:15.5"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["band_rows"] == [0, 19]
    with pytest.raises(SystemExit, match="eval-depth --band: expected ABOVE:BELOW"):
        _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data", str(fresh),
              "--band", "4"])
    with pytest.raises(SystemExit, match="train-depth --horizon-row: Camera: horizon_row"):
        _run(["train-depth", "--smoke", "--quiet", "--horizon-row", "40", "--dir",
              str(tmp_path / "bad")])


def test_example_smoke(tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "03_train_depth.py"),
                          "--smoke", "--out", str(tmp_path)], capture_output=True, text=True,
                         cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "emerging.png").is_file()


def test_recorded_command_parses_back():
    """The command line a run records (results.json, the shipped JSONs) gives the same
    arguments when run again, also for values that start with a dash (source offsets)."""
    import argparse
    import shlex
    p = argparse.ArgumentParser()
    commands.add_arguments_train_depth(p)
    args = p.parse_args(["--source-offsets=-2,-1,1,2", "--full-res", "--seed", "3"])
    line = commands._command_line(args, "train-depth")
    assert "--source-offsets=-2,-1,1,2" in line
    again = p.parse_args(shlex.split(line)[4:])     # after "python -m minid3rqn train-depth"
    assert vars(again) == vars(args)
