"""The depth commands (collect, train-depth, eval-depth) and the example, at smoke size."""
import argparse
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import cli
from minid3rqn.config import from_args
from minid3rqn.depth import commands
from minid3rqn.depth.data import CollectConfig, load_sequence
from minid3rqn.depth.train import TrainConfig
from minid3rqn.io import read_metadata

pytestmark = pytest.mark.depth
ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT),
                                                               os.environ.get("PYTHONPATH")])))
SMOKE = ["--frames", "60", "--iterations", "3", "--set", "test_frames=30"]


def _run(argv):
    return cli.main(argv)


def test_collect_train_eval_smoke(tmp_path, capsys):
    data = tmp_path / "train.npz"
    assert _run(["collect", "--frames", "20", "--set", "frames_per_flight=10", "--seed", "4",
                 "--out", str(data)]) == 0
    seq = load_sequence(data)
    assert len(seq) == 20 and seq.flight.max() == 1 and seq.meta["seed"] == 4
    assert "--set frames_per_flight=10" in seq.meta["command"]
    run = tmp_path / "run"
    assert _run(["train-depth", *SMOKE, "--seed", "3", "--dir", str(run)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert {"abs_rel", "a1", "rot_err_deg"} <= set(out)
    assert (run / "model.npz").is_file() and (run / "pictures.png").is_file()
    meta = json.loads((run / "results.json").read_text())
    assert meta["seed"] == 3 and meta["command"].startswith("python -m minid3rqn train-depth")
    assert "--seed 3" in meta["command"] and "--iterations 3" in meta["command"]
    assert meta["data_command"].startswith("python -m minid3rqn collect")
    assert load_sequence(run / "train.npz").meta["seed"] == 3          # the run's seed
    assert load_sequence(run / "test.npz").meta["seed"] == 1003        # other worlds
    assert meta["machine"]["numpy"] == np.__version__ and meta["machine"]["blas_core"]
    # resume: a finished run does no more work and leaves its files as they are; with
    # more iterations it trains on from its last one
    written = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    assert _run(["train-depth", *SMOKE, "--seed", "3", "--resume", "--dir", str(run)]) == 0
    assert "has finished (3 of 3 iterations); nothing to do" in capsys.readouterr().err
    assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == written
    assert _run(["train-depth", *SMOKE, "--iterations", "4", "--seed", "3", "--resume",
                 "--dir", str(run)]) == 0
    assert "resuming at iteration 3" in capsys.readouterr().out
    assert read_metadata(run / "checkpoint.npz")["iteration"] == 4
    for extra in ([], ["--flip-tta"], ["--pictures", str(tmp_path / "p.png")]):
        assert _run(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                     str(run / "test.npz"), "--json", str(tmp_path / "m.json"), "--overwrite",
                     *extra]) == 0
        got = json.loads((tmp_path / "m.json").read_text())
        assert 0 <= got["a1"] <= 1 and got["frames"] == len(load_sequence(run / "test.npz"))
    assert len(got["by_depth"]) == 5 and (tmp_path / "p.png").is_file()


def test_fine_tune_from_a_model_file_on_given_frames(tmp_path, capsys):
    """--init-from a model file, --data/--test-data given: the recorded command names
    them, and the model file records the collect command of its frames."""
    frames = tmp_path / "frames.npz"
    assert _run(["collect", "--frames", "60", "--seed", "7", "--set", "late_turns=0.5",
                 "--out", str(frames)]) == 0
    run = tmp_path / "tuned"
    assert _run(["train-depth", *SMOKE, "--data", str(frames), "--test-data",
                 str(tmp_path / "held.npz"), "--init-from", str(commands.MODELS /
                                                                "depth_basic.npz"),
                 "--set", "full_res=true", "--set", "gyro_yaw=true", "--dir", str(run)]) == 0
    meta = json.loads((run / "results.json").read_text())
    for part in ("--data " + str(frames), "--init-from", "--set full_res=True",
                 "--set gyro_yaw=True"):
        assert part in meta["command"], meta["command"]
    assert "late_turns=0.5" in meta["data_command"] and "--seed 7" in meta["data_command"]
    assert meta["config"]["loss"]["full_res"] and meta["config"]["gyro_yaw"]


def test_recorded_command_parses_back(tmp_path):
    """The command line a run records gives back its configs when run again."""
    from minid3rqn.depth.losses import LossConfig
    from minid3rqn.depth.train import train_depth_command
    cfg = TrainConfig(iterations=10, seed=2, lr_decay_at=7, init_disp=0.1, gyro_yaw=True,
                      loss=LossConfig(full_res=True, unmasked_weight=0.1, ssim_weight=0.5))
    data = CollectConfig(scenario="channel", frames=90, seed=2, late_turns=0.25)
    line = train_depth_command(cfg, data, tmp_path / "run", tmp_path / "t.npz", None,
                               tmp_path / "init.npz")
    p = argparse.ArgumentParser()
    commands.add_arguments_train_depth(p)
    args = p.parse_args(shlex.split(line)[4:])    # after "python -m minid3rqn train-depth"
    assert from_args(TrainConfig, commands._options(args, TrainConfig, CollectConfig)) == cfg
    assert from_args(CollectConfig, commands._options(args, CollectConfig, TrainConfig), seed=2) == data
    assert (args.dir, args.data, args.test_data, args.init_from) == (
        str(tmp_path / "run"), str(tmp_path / "t.npz"), None, str(tmp_path / "init.npz"))


@pytest.mark.parametrize("argv, message", [
    (["collect", "--set", "late_turns=2"], "--set late_turns: expected a number in [0.0, 1.0]"),
    (["collect", "--scenario", "moon"], "invalid choice"),
    (["train-depth", "--iterations", "0"], "--iterations: expected a number >= 1; got 0"),
    (["train-depth", "--lr", "nan"], "--lr: expected a finite number"),
    (["train-depth", "--set", "ssim_weight=2"], "--set ssim_weight: expected a number in"),
    (["train-depth", "--set", "nope=1"], "--set: expected NAME=VALUE"),
    (["train-depth", "--init-from", "missing.npz"], "--init-from: no file 'missing.npz'"),
    (["eval-depth", "--model", "missing.npz"], "--model: no file 'missing.npz'"),
])
def test_bad_inputs_are_one_line_naming_the_option(argv, message, capsys):
    try:
        code = _run(argv)
    except SystemExit as e:                       # argparse's own refusals
        code = e.code
    assert code == 2
    assert message in capsys.readouterr().err


def test_option_budgets_and_the_default_model_from_anywhere(tmp_path):
    """collect <= 7, train-depth <= 14, eval-depth <= 7 visible options (--set counted
    once, -h not); eval-depth's default model is the shipped one from any directory."""
    budgets = {"collect": 7, "train-depth": 14, "eval-depth": 7}
    for name, most in budgets.items():
        p = argparse.ArgumentParser()
        getattr(commands, f"add_arguments_{name.replace('-', '_')}")(p)
        shown = [a for a in p._actions if a.option_strings and "-h" not in a.option_strings]
        assert len(shown) <= most, (name, [a.option_strings[0] for a in shown])
    p = argparse.ArgumentParser()
    commands.add_arguments_eval_depth(p)
    model = Path(p.parse_args([]).model)
    assert model.is_absolute() and model.is_file() and model.name == "depth_basic.npz"
    out = subprocess.run([sys.executable, "-m", "minid3rqn", "eval-depth", "--help"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120, env=ENV)
    assert out.returncode == 0 and "depth_basic.npz" in out.stdout


def test_example_smoke(tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "03_train_depth.py"),
                          "--smoke", "--out", str(tmp_path)], capture_output=True, text=True,
                         cwd=ROOT, timeout=300, env=ENV)
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "emerging.png").is_file()
