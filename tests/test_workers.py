"""Workers follow their parent: the local pool gives the one-process results in order;
an error in a task is raised in the parent; a task lost with its worker runs again;
Ctrl-C and SIGTERM reach every worker (a training stops with its checkpoint, and goes on
from it exactly); a parent killed with kill -9 takes its workers with it."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.executor import RETRIES, LocalPool, WorkerLost, get_executor
from minid3rqn.io import load_npz, read_metadata

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")


def _square(shared, task):
    return shared * task * task


def test_the_pool_gives_the_one_process_results_in_order():
    tasks = list(range(7))
    seen = []
    forked = LocalPool(3).run(_square, tasks, 2, on_result=lambda i, r: seen.append(i))
    assert forked == LocalPool(1).run(_square, tasks, 2) == [2 * t * t for t in tasks]
    assert sorted(seen) == tasks


def _fails_on_3(shared, task):
    if task == 3:
        raise ValueError("task 3: a bad value")
    return task


def test_an_error_in_a_worker_is_raised_in_the_parent():
    with pytest.raises(ValueError, match="task 3: a bad value"):
        LocalPool(2).run(_fails_on_3, range(6))


def _always_killed(shared, task):
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_task_lost_with_its_worker_runs_again(tmp_path, capsys, killed_once):
    assert LocalPool(2).run(killed_once, range(4), str(tmp_path)) == [0, 10, 20, 30]
    assert "a worker was lost (killed by signal 9 (SIGKILL)) running task 2 of 4; " \
           "running it again (rerun 1 of 3)" in capsys.readouterr().err
    with pytest.raises(WorkerLost, match=rf"task \d of 2 lost its worker {RETRIES + 1} times"):
        LocalPool(2).run(_always_killed, range(2))


def test_an_unknown_executor_is_refused():
    with pytest.raises(ValueError, match="expected one of local, ray; got 'dask'"):
        get_executor("dask")


_HEARTBEATS = """
import os, sys, time
from pathlib import Path
from minid3rqn.executor import LocalPool, sigterm_as_ctrl_c

def beat(folder, task):          # writes a file every 50 ms for a minute
    path = Path(folder) / f"beat{task}"
    (Path(folder) / f"pid{task}").write_text(str(os.getpid()))
    for i in range(1200):
        path.write_text(str(i))
        time.sleep(0.05)
    return task

sigterm_as_ctrl_c()
print("parent", os.getpid(), flush=True)
try:
    LocalPool(2).run(beat, range(2), sys.argv[1])
except KeyboardInterrupt as e:
    print("interrupted", type(e).__name__, flush=True)
    sys.exit(130)
"""


def _start_heartbeats(tmp_path):
    child = subprocess.Popen([sys.executable, "-c", _HEARTBEATS, str(tmp_path)], env=ENV,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert child.stdout.readline().startswith("parent")
    deadline = time.time() + 30
    while not all((tmp_path / f"beat{k}").exists() for k in range(2)):
        assert time.time() < deadline and child.poll() is None
        time.sleep(0.05)
    pids = [int((tmp_path / f"pid{k}").read_text()) for k in range(2)]
    return child, pids


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                       # a zombie (dead, not yet reaped) is not working
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    except (FileNotFoundError, IndexError):
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_die_with_a_parent_killed_by_kill_9(tmp_path):
    child, pids = _start_heartbeats(tmp_path)
    child.send_signal(signal.SIGKILL)
    child.wait()
    deadline = time.time() + 5
    while any(map(_alive, pids)):
        assert time.time() < deadline, "a worker outlived its parent by 5 s"
        time.sleep(0.05)
    beats = {k: (tmp_path / f"beat{k}").stat().st_mtime_ns for k in range(2)}
    time.sleep(0.5)                       # nothing writes any more
    assert beats == {k: (tmp_path / f"beat{k}").stat().st_mtime_ns for k in range(2)}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ctrl_c_and_sigterm_of_the_parent_stop_every_worker(tmp_path, sig):
    child, pids = _start_heartbeats(tmp_path)
    child.send_signal(sig)
    out, err = child.communicate(timeout=30)
    assert child.returncode == 130 and "interrupted KeyboardInterrupt" in out, (out, err)
    assert not any(map(_alive, pids)) and "Traceback" not in err, err


_TRAIN_TWO = """
import sys
from pathlib import Path
from minid3rqn.executor import LocalPool, sigterm_as_ctrl_c
from minid3rqn.io import RunStopped
from minid3rqn.rl.reproduce import _train_all
from minid3rqn.rl.train import SMOKE, TrainConfig

out, steps, workers = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
sigterm_as_ctrl_c()
try:
    _train_all([(TrainConfig(**{**SMOKE, "steps": steps, "checkpoint_every": 64,
                                "seed": seed}), out / f"s{seed}", None)
                for seed in (0, 1)], LocalPool(workers))
except RunStopped as e:
    print("stopped:", e, flush=True)
    sys.exit(130)
"""


def _train_two(out, steps: int, workers: int, **kw):
    return subprocess.Popen([sys.executable, "-c", _TRAIN_TWO, str(out), str(steps),
                             str(workers)], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.parametrize("sig", [pytest.param(signal.SIGINT, marks=pytest.mark.slow),
                                 signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_training_with_workers_stopped_saves_every_checkpoint_and_resumes_exactly(
        tmp_path, sig):
    """Two trainings in two workers, stopped by Ctrl-C or SIGTERM of the parent: each
    saves its checkpoint, the parent names both; continued to the same length, each is
    bit for bit the run that was never stopped."""
    child = _train_two(tmp_path / "cut", 100_000, 2)
    seen = set()
    for line in child.stdout:                     # both in their loops
        seen.add(line.split(":")[0])
        if {"s0", "s1"} <= seen:
            break
    child.send_signal(sig)
    out, err = child.communicate(timeout=120)
    assert child.returncode == 130, (out, err)
    assert "stopped: 2 runs stopped with their checkpoint" in out, out
    done = [read_metadata(tmp_path / "cut" / f"s{s}" / "checkpoint.npz")["steps"]
            for s in (0, 1)]
    assert all(64 <= d < 100_000 for d in done) and "Traceback" not in err, err
    steps = max(done) + 64
    for folder, workers in (("cut", 2), ("straight", 1)):
        run = _train_two(tmp_path / folder, steps, workers)
        assert run.wait(timeout=600) == 0, run.stderr.read()
    for s in (0, 1):
        a = load_npz(tmp_path / "cut" / f"s{s}" / "model.npz")[0]
        b = load_npz(tmp_path / "straight" / f"s{s}" / "model.npz")[0]
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"s{s} {k}")


def test_sigterm_stops_a_training_as_ctrl_c_does(tmp_path):
    """What a scheduler or ``timeout`` sends: the checkpoint saved, the command that
    continues printed."""
    import shlex
    line = ["train-agent", "--smoke", "--steps", "100000", "--set", "checkpoint_every=64",
            "--out", str(tmp_path / "run")]
    child = subprocess.Popen([sys.executable, "-m", "minid3rqn", *line], cwd=tmp_path,
                             env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert child.stdout.readline().startswith("run: 64/100000 steps")
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130 and len(err.strip().splitlines()) == 1, err
    assert err.strip().endswith("continue with: python -m minid3rqn "
                                + shlex.join(line + ["--resume"]))
    assert read_metadata(tmp_path / "run" / "checkpoint.npz")["steps"] >= 64
