"""Nothing is lost and nothing wrong passes silently: a run folder is written to only by
an explicit --resume or --overwrite; a resumed run has its checkpoint's settings (each
differing one is named); Ctrl-C saves a checkpoint that the run goes on from exactly; a
killed save leaves the previous checkpoint whole; only a finished, evaluated model is
shipped; an evaluation record says which chunk it was flown in."""
import json
import os
import shlex
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.cli import main
from minid3rqn.io import load_npz, read_metadata
from minid3rqn.rl import models

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
AGENT = ["train-agent", "--smoke", "--steps", "64"]


def _weights(path) -> dict:
    return load_npz(path)[0]


def _same_weights(a, b) -> None:
    wa, wb = _weights(a), _weights(b)
    assert wa.keys() == wb.keys()
    for k in wa:
        np.testing.assert_array_equal(wa[k], wb[k], err_msg=k)


def _files(folder: Path) -> dict:
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished train-agent run of 64 steps (smoke size)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main([*AGENT, "--out", str(out)]) == 0
    return out


def test_a_run_folder_is_kept_unless_resumed_or_overwritten(finished, tmp_path, capsys):
    run = tmp_path / "run"
    assert main([*AGENT, "--out", str(run)]) == 0
    written = _files(run)
    capsys.readouterr()
    assert main([*AGENT, "--out", str(run)]) == 2               # neither choice: refused
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"'{run}' holds a run" in err
    assert "--resume" in err and "--overwrite" in err and _files(run) == written
    assert main([*AGENT, "--out", str(run), "--resume"]) == 0   # finished: nothing to do
    assert "has finished (64 of 64 steps); nothing to do" in capsys.readouterr().err
    assert _files(run) == written
    assert main([*AGENT, "--out", str(run), "--overwrite"]) == 0   # afresh: the same run
    assert (run / "model.npz").stat().st_mtime_ns != written["model.npz"]
    _same_weights(run / "model.npz", finished / "model.npz")
    # --resume with more steps goes on, to the run made in one go
    assert main(["train-agent", "--smoke", "--steps", "128", "--out", str(run), "--resume"]) == 0
    assert main(["train-agent", "--smoke", "--steps", "128", "--out", str(tmp_path / "one")]) == 0
    _same_weights(run / "model.npz", tmp_path / "one" / "model.npz")
    assert read_metadata(run / "checkpoint.npz")["steps"] == 128


def test_resume_names_each_setting_that_differs(finished, tmp_path, capsys):
    from minid3rqn.depth.train import TrainConfig, Trainer
    from minid3rqn.depth.data import CollectConfig, collect_sequence
    assert main([*AGENT, "--hidden", "8", "--lr", "0.001", "--steps", "128", "--out",
                 str(finished), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "hidden 16 (now 8)" in err
    assert "lr 0.0003 (now 0.001)" in err and "steps" not in err.split("settings:")[1]
    # distil: its own settings, and the teacher, are the checkpoint's too
    out, teacher = tmp_path / "student", str(finished / "model.npz")
    distil = ["distil", "--smoke", "--teachers", teacher, "--steps", "64", "--set", "depth=gt",
              "--out", str(out)]
    assert main(distil) == 0
    capsys.readouterr()
    assert main([*distil, "--set", "distil_kl=0.5", "--resume"]) == 2
    assert "distil_kl 1.0 (now 0.5)" in capsys.readouterr().err
    # train-depth: every setting but those that may change (a nested loss setting too)
    seq = collect_sequence(CollectConfig(frames=12, frames_per_flight=6), tmp_path / "f.npz",
                           progress=False)
    ckpt = tmp_path / "depth" / "checkpoint.npz"
    Trainer(seq, TrainConfig(), checkpoint=ckpt).save_checkpoint(ckpt)
    later = TrainConfig(iterations=9, lr_decay_at=5, checkpoint_every=1, log_every=1,
                        eval_every=0)
    assert Trainer(seq, later, checkpoint=ckpt, resume=True).iteration == 0
    other = TrainConfig(seed=1, loss={"ssim_weight": 0.5})
    with pytest.raises(ValueError, match=r"seed 0 \(now 1\); ssim_weight 0.85 \(now 0.5\)"):
        Trainer(seq, other, checkpoint=ckpt, resume=True)


def test_ctrl_c_saves_a_checkpoint_and_the_run_goes_on_exactly(tmp_path):
    run = tmp_path / "run"
    line = ["train-agent", "--smoke", "--steps", "100000", "--set", "checkpoint_every=64",
            "--out", str(run)]
    child = subprocess.Popen([sys.executable, "-m", "minid3rqn", *line], cwd=tmp_path,
                             env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert child.stdout.readline().startswith("run: 64/100000 steps")  # in the loop now
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130 and len(err.strip().splitlines()) == 1, err
    assert err.strip().endswith("continue with: python -m minid3rqn "
                                + shlex.join(line + ["--resume"]))
    done = read_metadata(run / "checkpoint.npz")["steps"]
    assert 64 <= done < 100000 and f"stopped at {done} of 100000 steps" in err
    more = ["--steps", str(done + 64), "--set", "checkpoint_every=64"]
    for line in (["--out", str(run), "--resume"], ["--out", str(tmp_path / "one")]):
        # in child processes like the first part: the same BLAS threads, the same sums
        subprocess.run([sys.executable, "-m", "minid3rqn", "train-agent", "--smoke", *more,
                        *line], cwd=tmp_path, env=ENV, check=True, capture_output=True)
    _same_weights(run / "model.npz", tmp_path / "one" / "model.npz")


def test_ctrl_c_stops_depth_training_at_an_iteration_with_its_checkpoint(tmp_path):
    from minid3rqn.depth.data import Sequence, collect
    from minid3rqn.depth.train import TrainConfig, Trainer
    from minid3rqn.io import RunStopped
    from minid3rqn.world import Camera
    data = collect("basic", n_frames=24, frames_per_flight=12, seed=5,
                   camera=Camera(16, 24, 90.0), progress=False)
    seq = Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])

    def cfg(iterations):
        return TrainConfig(iterations=iterations, batch_size=2, lr=2e-3, checkpoint_every=100,
                           log_every=1)

    def ctrl_c_at_2(trainer, row):
        if trainer.iteration == 2:
            os.kill(os.getpid(), signal.SIGINT)
    ckpt = tmp_path / "ckpt.npz"
    with pytest.raises(RunStopped, match="stopped at iteration 2 of 4"):
        Trainer(seq, cfg(4), checkpoint=ckpt).run(progress=False, callback=ctrl_c_at_2)
    resumed = Trainer(seq, cfg(4), checkpoint=ckpt, resume=True)
    assert resumed.iteration == 2
    resumed.run(progress=False)
    straight = Trainer(seq, cfg(4))
    straight.run(progress=False)
    for a, b in zip(resumed.params, straight.params):
        np.testing.assert_array_equal(a.data, b.data)


def test_a_run_killed_while_saving_keeps_its_last_checkpoint(tmp_path):
    """The second checkpoint's save is killed half-way: the first is whole, the run goes
    on from it, and the next save removes the killed writer's temporary file."""
    from minid3rqn.rl.train import SMOKE, TrainConfig, train
    out = tmp_path / "run"
    code = textwrap.dedent(f"""
        import time
        import numpy as np
        from minid3rqn.rl.train import SMOKE, TrainConfig, train
        real, calls = np.savez, []
        def savez(f, **arrays):         # call 3: the second checkpoint (1, 2: the first's)
            calls.append(1)
            if len(calls) == 3:
                f.write(b"partial")
                f.flush()
                print("writing", flush=True)
                time.sleep(60)
            return real(f, **arrays)
        np.savez = savez
        train(TrainConfig(**{{**SMOKE, "steps": 64, "checkpoint_every": 32}}), {str(out)!r},
              progress=False)
    """)
    child = subprocess.Popen([sys.executable, "-c", code], env=ENV, stdout=subprocess.PIPE,
                             text=True)
    for line in child.stdout:          # ends early (and the asserts below fail) if it dies
        if line.strip() == "writing":
            break
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert len(list(out.glob("checkpoint.npz.*.tmp"))) == 1
    assert read_metadata(out / "checkpoint.npz")["steps"] == 32
    resumed = train(TrainConfig(**{**SMOKE, "steps": 64, "checkpoint_every": 32}), out,
                    progress=False, resume=True)
    assert resumed.steps == 64 and not list(out.glob("*.tmp"))
    assert read_metadata(out / "checkpoint.npz")["steps"] == 64


def test_only_a_finished_evaluated_model_is_shipped(finished, tmp_path, monkeypatch):
    from minid3rqn.rl.train import SMOKE, Run, TrainConfig
    monkeypatch.setattr(models, "MODELS", tmp_path / "models")
    (tmp_path / "models").mkdir()
    snapshot = Run(TrainConfig(**SMOKE), tmp_path / "cut")      # a checkpoint's snapshot
    snapshot.start()
    snapshot.save_checkpoint()
    with pytest.raises(ValueError, match=r"not the model of a finished run \(at 0 of 128"):
        models.ship(tmp_path / "cut" / "model.npz", "d3rqn_cut")
    model = finished / "model.npz"
    with pytest.raises(ValueError, match="no recorded evaluation"):
        models.ship(model, "d3rqn_smoke")
    with pytest.raises(ValueError, match="neither a Q-net nor a depth model"):
        models.ship(tmp_path / "cut" / "checkpoint.npz", "d3rqn_cut")
    assert list((tmp_path / "models").iterdir()) == []
    log = tmp_path / "e.jsonl"
    assert main(["evaluate", str(model), "--flights", "4", "--steps", "3", "--json",
                 str(log)]) == 0
    records = [json.loads(x) for x in log.read_text().splitlines()]
    shipped = models.ship(model, "d3rqn_smoke", records)
    about = json.loads(shipped.with_suffix(".json").read_text())
    assert about["command"].startswith("python -m minid3rqn train-agent")
    assert models.recorded_result(shipped, "basic", "gt")["rate"] == records[0]["rate"]
    _same_weights(shipped, model)


def test_an_evaluation_record_gives_its_chunk_and_its_command_gives_it_again(tmp_path):
    """The chunk is part of which worlds a seed draws: the record says which, and its
    recorded command flies the same flights again."""
    def flown(argv, name):
        log = tmp_path / name
        assert main(["evaluate", *argv, "--json", str(log)]) == 0
        return json.loads(log.read_text())
    tiny = ["reactive", "--flights", "12", "--steps", "5"]
    six = flown([*tiny, "--chunk", "6"], "six.jsonl")
    twelve = flown([*tiny, "--chunk", "12"], "twelve.jsonl")
    assert (six["chunk"], twelve["chunk"]) == (6, 12)
    assert six["world_seeds"] != twelve["world_seeds"] and "--chunk 6" in six["command"]
    again = flown(shlex.split(six["command"])[4:], "again.jsonl")
    assert {**again, "seconds": 0} == {**six, "seconds": 0}


def test_frames_collected_with_other_settings_are_not_read_as_the_runs_own(tmp_path,
                                                                          monkeypatch, capsys):
    """A run folder's train.npz, or eval-depth's default held-out file, collected with other
    settings than the command's: refused, naming them (train-depth --overwrite collects
    them anew)."""
    from minid3rqn.depth.data import CollectConfig, collect_sequence
    monkeypatch.chdir(tmp_path)
    collect_sequence(CollectConfig(frames=20, frames_per_flight=10, seed=1000),
                     tmp_path / "runs" / "depth" / "basic" / "test.npz", progress=False)
    assert main(["eval-depth"]) == 2
    err = capsys.readouterr().err
    assert "holds frames collected with other settings: frames 20 (now 500)" in err
    collect_sequence(CollectConfig(frames=20, frames_per_flight=10), tmp_path / "d" /
                     "train.npz", progress=False)
    small = ["train-depth", "--frames", "30", "--iterations", "1", "--set", "test_frames=12",
             "--set", "eval_every=0", "--dir", str(tmp_path / "d")]
    assert main(small) == 2
    assert "frames 20 (now 30)" in capsys.readouterr().err
    assert main([*small, "--overwrite"]) == 0
    assert read_metadata(tmp_path / "d" / "train.npz")["frames"] == 30
