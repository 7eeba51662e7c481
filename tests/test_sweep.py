"""The seed sweep: each seed trained and flown, a table with the spread across seeds; a
sweep started again keeps its finished seeds; a folder holding another sweep's finished
run is refused; SIGTERM stops every seed's training with its checkpoint and names the
command that continues; ``--executor ray`` without ray is one line."""
import json
import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from minid3rqn.cli import main
from minid3rqn.io import read_metadata
from minid3rqn.rl.sweep import spread

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
SWEEP = ["sweep", "--smoke", "--steps", "64", "--flights", "4"]


def _stamps(out: Path, seeds) -> dict:
    return {(s, f): (out / f"s{s}" / f).stat().st_mtime_ns for s in seeds
            for f in ("model.npz", "evaluation.json")}


def test_a_sweep_tabulates_its_seeds_and_goes_on_from_its_finished_runs(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main([*SWEEP, "--seeds", "0,1", "--workers", "2", "--out", str(out)]) == 0
    first = json.loads((out / "results.json").read_text())
    assert first["seeds"] == [0, 1] and len(first["runs"]) == 2
    assert all(r["flights"] == 4 and r["seed"] == 271828 for r in first["runs"])
    assert not list(out.glob("s*/checkpoint.npz"))           # a finished run keeps no replay
    table = (out / "results.md").read_text()
    assert "| 0 | " in table and "| 1 | " in table and "Across 2 seeds: mean" in table
    assert "--seed 1" in read_metadata(out / "s1" / "model.npz")["command"]
    kept = _stamps(out, (0, 1))
    assert main([*SWEEP, "--seeds", "0,1,2", "--out", str(out)]) == 0
    assert _stamps(out, (0, 1)) == kept                      # kept, not trained or flown again
    again = json.loads((out / "results.json").read_text())
    assert again["runs"][:2] == first["runs"] and again["spread"]["seeds"] == 3


def test_a_finished_run_of_other_settings_is_not_trained_over(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main([*SWEEP, "--seeds", "0", "--out", str(out)]) == 0
    kept = _stamps(out, (0,))
    capsys.readouterr()
    assert main([*SWEEP, "--seeds", "0", "--hidden", "8", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holds a finished run of other settings" in err, err
    assert _stamps(out, (0,)) == kept


def test_the_spread_across_seeds():
    s = spread([0.5, 0.7, 0.9])
    assert s["seeds"] == 3 and s["mean"] == pytest.approx(0.7) and \
        s["sd"] == pytest.approx(0.2) and (s["min"], s["max"]) == (0.5, 0.9)
    assert spread([0.4])["sd"] is None


@pytest.mark.parametrize("seeds", ["0,0", "-1", "1.5"])
def test_bad_seeds_are_one_line(seeds, tmp_path, capsys):
    assert main([*SWEEP, "--seeds", seeds, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("python -m minid3rqn sweep: --seeds: expected") and \
        len(err.splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("argv", [["evaluate", "straight", "--flights", "4"],
                                  SWEEP + ["--seeds", "0"]])
def test_executor_ray_without_ray_is_one_line(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)           # import ray fails
    monkeypatch.chdir(tmp_path)
    assert main([*argv, "--executor", "ray"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith('--executor ray: ray is not installed (pip install -e ".[ray]", '
                        'or leave --executor at local)') and len(err.splitlines()) == 1, err


def test_sigterm_stops_every_seed_with_its_checkpoint_and_names_the_command(tmp_path):
    line = ["sweep", "--smoke", "--seeds", "0,1", "--workers", "2", "--steps", "100000",
            "--set", "checkpoint_every=64", "--out", str(tmp_path / "sweep")]
    child = subprocess.Popen([sys.executable, "-m", "minid3rqn", *line], env=ENV,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = set()
    for text in child.stdout:                                # both seeds in their loops
        seen.add(text.split(":")[0])
        if {"s0", "s1"} <= seen:
            break
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=120)
    last = err.strip().splitlines()[-1]
    assert child.returncode == 130 and "2 runs stopped with their checkpoint" in last, err
    assert last.endswith("continue with: python -m minid3rqn " + shlex.join(line)), last
    for s in (0, 1):
        assert read_metadata(tmp_path / "sweep" / f"s{s}" / "checkpoint.npz")["steps"] >= 64
