"""Faults: nothing is lost and nothing is said wrong when a command meets another one on
its output, a full disk, an odd path or a size too large.

- one writer per run folder or output file: a second command refuses in one line naming
  the holder; a holder that was killed holds nothing;
- every file is written whole or not at all: on a full disk the earlier file stays, the
  line names the file and the reason, and the command still says what it measured;
  ``--resume`` writes again a finished run's file that is not whole;
- odd paths (a loop of symbolic links, a name that is not UTF-8, a symbolic link as the
  output, '+' in a Q-net's name) each get their rule and one line;
- sizes beyond memory or beyond a flight's 50 steps are refused in one line, and more
  workers than cores are capped with a note.
"""
import errno
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import io
from minid3rqn.cli import main
from minid3rqn.io import MODELS, hold, load_npz, write_file

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
FLY = ["fly", "--depth", "gt", "--flights", "2", "--seed", "1"]


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """A small held-out frames file (30 frames, finite GT depth); ``train.npz`` beside it
    (30 frames of other worlds)."""
    folder = tmp_path_factory.mktemp("frames")
    for name, seed in (("test", 1000), ("train", 0)):
        assert main(["collect", "--frames", "30", "--set", "frames_per_flight=10", "--seed",
                     str(seed), "--out", str(folder / f"{name}.npz")]) == 0
    return folder / "test.npz"


# -- one writer per target ----------------------------------------------------------------
HOLDER = textwrap.dedent("""
    import sys, time
    from minid3rqn.io import hold
    with hold(sys.argv[1], "--out"):
        print("held", flush=True)
        time.sleep(120)
""")


@pytest.fixture
def holder():
    """Start a process holding the lock of a path; yields a function of the path that
    returns the process (killed at the end)."""
    started = []

    def start(path):
        child = subprocess.Popen([sys.executable, "-c", HOLDER, str(path)], env=ENV,
                                 stdout=subprocess.PIPE, text=True)
        assert child.stdout.readline().strip() == "held"
        started.append(child)
        return child

    yield start
    for child in started:
        child.kill()
        child.wait()


def _targets(tmp: Path, frames: Path) -> list:
    """(command line, the target it writes) for every command that writes one."""
    return [
        (["train-agent", "--smoke", "--steps", "64", "--out", str(tmp / "run")], tmp / "run"),
        (["distil", "--smoke", "--teachers", str(MODELS / "d3rqn_basic.npz"), "--out",
          str(tmp / "dist")], tmp / "dist"),
        (["collect", "--frames", "20", "--out", str(tmp / "c.npz")], tmp / "c.npz"),
        (["train-depth", "--dir", str(tmp / "d"), "--data", str(frames.with_name("train.npz")),
          "--test-data", str(frames), "--iterations", "2"], tmp / "d"),
        ([*FLY, "--gif", str(tmp / "f.gif")], tmp / "f.gif"),
        (["eval-depth", "--test-data", str(frames), "--json", str(tmp / "e.json")],
         tmp / "e.json"),
        (["eval-depth", "--test-data", str(frames), "--pictures", str(tmp / "e.png")],
         tmp / "e.png"),
        (["reproduce", "--quick", "--out", str(tmp / "rep")], tmp / "rep"),
    ]


def test_a_second_writer_refuses_in_one_line_naming_the_holder(holder, frames, tmp_path,
                                                              capsys):
    for argv, target in _targets(tmp_path, frames):
        child = holder(target)
        before = sorted(tmp_path.rglob("*"))
        assert main(argv) == 2, argv
        line = _one_line(capsys.readouterr().err)
        assert f"{str(target)!r} is in use by another command: pid {child.pid}" in line, line
        assert "hold(" not in line and "since" in line
        assert sorted(tmp_path.rglob("*")) == before, argv      # nothing written
        child.kill()
        child.wait()


def test_a_killed_holder_holds_nothing(holder, tmp_path, capsys):
    out = tmp_path / "c.npz"
    child = holder(out)
    argv = ["collect", "--frames", "20", "--set", "frames_per_flight=10", "--out", str(out)]
    assert main(argv) == 2
    capsys.readouterr()
    child.kill()                                 # kill -9: no chance to clean up
    child.wait()
    assert main(argv) == 0 and load_npz(out)[0]["rgb"].shape[0] == 20


def test_two_spellings_of_a_target_share_its_lock(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with hold(tmp_path / "real" / "x.gif", "--gif"):
        with pytest.raises(io.Busy, match="in use by another command"):
            with hold(tmp_path / "link" / ".." / "real" / "x.gif", "--gif"):
                pass
        with pytest.raises(io.Busy):
            with hold(tmp_path / "link" / "x.gif", "--gif"):
                pass
    with hold(tmp_path / "link" / "x.gif", "--gif"):        # released: free again
        pass


@pytest.mark.slow
def test_two_trainings_at_once_on_one_folder_one_refuses(tmp_path):
    """The case as a user meets it: two processes, seeds 0 and 1, one --out."""
    out = tmp_path / "run"
    runs = [subprocess.Popen([sys.executable, "-m", "minid3rqn", "train-agent", "--smoke",
                              "--seed", str(seed), "--out", str(out)], env=ENV, cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for seed in (0, 1)]
    done = [(r.wait(timeout=600), r.stderr.read()) for r in runs]
    codes = sorted(code for code, _ in done)
    assert codes == [0, 2], done
    refused = next(err for code, err in done if code == 2)
    assert "is in use by another command" in refused or "holds a run" in refused
    seed = load_npz(out / "model.npz")[1]["seed"]
    winner = [seed_ for (code, _), seed_ in zip(done, (0, 1)) if code == 0][0]
    assert seed == winner                       # the model is the run that wrote it


# -- whole files, or the earlier one ------------------------------------------------------
@pytest.fixture
def full_disk(monkeypatch):
    """Every write through ``io.write_file`` fails half-way with ENOSPC (a full disk)."""
    def fill(f, content):
        f.write(b"half a file")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(io, "_fill", fill)


def test_write_file_is_whole_or_keeps_the_earlier_file(tmp_path, full_disk):
    path = tmp_path / "a.json"
    path.write_text('{"old": 1}')
    with pytest.raises(io.WriteError) as e:
        io.write_json(path, {"new": 2})
    assert str(e.value) == (f"could not write {str(path)!r}: No space left on device; the "
                            f"earlier file is kept whole")
    assert e.value.errno == errno.ENOSPC
    assert json.loads(path.read_text()) == {"old": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]   # no temporary left
    with pytest.raises(io.WriteError, match="nothing was written"):
        io.save_npz(tmp_path / "b.npz", {"x": np.zeros(3)})
    assert not (tmp_path / "b.npz").exists()


def test_fly_on_a_full_disk_keeps_the_gif_and_says_the_success_rate(tmp_path, full_disk,
                                                                     capsys):
    gif = tmp_path / "f.gif"
    gif.write_bytes(b"GIF89a the earlier one")
    assert main([*FLY, "--gif", str(gif)]) == 1
    out, err = capsys.readouterr()
    assert json.loads(out)["flights"] == 2 and json.loads(out)["gif"] is None
    lines = err.strip().splitlines()
    assert lines[0].startswith("success ") and "GIF: not written" in lines[0]
    assert lines[-1].endswith(f"could not write {str(gif)!r}: No space left on device; the "
                              f"earlier file is kept whole")
    assert gif.read_bytes() == b"GIF89a the earlier one"


def test_eval_depth_on_a_full_disk_says_its_numbers_first(tmp_path, frames, full_disk,
                                                         capsys):
    pictures = tmp_path / "p.png"
    assert main(["eval-depth", "--test-data", str(frames), "--pictures", str(pictures)]) == 1
    out, err = capsys.readouterr()
    assert "abs_rel" in json.loads(out.strip().splitlines()[-1])
    assert f"could not write {str(pictures)!r}: No space left on device" in _one_line(err)
    assert not pictures.exists()


def test_whole_reads_each_kind_of_file(tmp_path):
    from PIL import Image
    io.save_npz(tmp_path / "a.npz", {"x": np.zeros(3)})
    io.write_json(tmp_path / "a.json", {"a": 1})
    io.write_image(tmp_path / "a.png", np.zeros((4, 4, 3), np.uint8))
    Image.new("RGB", (4, 4)).save(tmp_path / "a.gif")
    io.write_file(tmp_path / "a.csv", "a,b\n1,2\n")
    for path in sorted(tmp_path.iterdir()):
        assert io.whole(path), path
        data = path.read_bytes()
        path.write_bytes(b"" if path.suffix == ".json" else data[:-1] if path.suffix == ".csv"
                         else data[: len(data) // 2])
        assert not io.whole(path), path
    assert not io.whole(tmp_path / "missing.json")


@pytest.mark.slow
def test_a_finished_depth_run_with_a_damaged_file_is_written_again(tmp_path, frames, capsys,
                                                                   monkeypatch):
    run = tmp_path / "d"
    argv = ["train-depth", "--dir", str(run), "--data", str(frames.with_name("train.npz")),
            "--test-data", str(frames), "--iterations", "2", "--set", "test_frames=30",
            "--set", "eval_every=0"]
    assert main(argv) == 0
    capsys.readouterr()
    (run / "results.json").write_text("")            # as an in-place write on a full disk
    assert main([*argv, "--resume"]) == 0
    out, err = capsys.readouterr()
    assert "has finished" not in err and "results.json is missing or damaged" in out
    assert json.loads((run / "results.json").read_text())["results"]["abs_rel"] > 0
    assert main([*argv, "--resume"]) == 0                # now whole: nothing to do
    assert "has finished" in capsys.readouterr().err


def _tmpfs(folder: Path, size: str) -> bool:
    """Mount a small tmpfs on ``folder`` (root on Linux only); False where it cannot be."""
    if sys.platform != "linux" or os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    folder.mkdir()
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                           str(folder)], capture_output=True).returncode == 0


def test_a_really_full_disk(tmp_path, capsys):
    """A tmpfs of 1 MB, filled: a GIF written there fails whole, the earlier one stays."""
    disk = tmp_path / "disk"
    if not _tmpfs(disk, "1m"):
        pytest.skip("cannot mount a small tmpfs here (needs root on Linux)")
    try:
        gif = disk / "f.gif"
        gif.write_bytes(b"GIF89a the earlier one")
        try:                                         # fill the disk to the last block
            with open(disk / "filler", "wb", buffering=0) as f:
                while True:
                    f.write(b"\0" * 4096)
        except OSError as e:
            assert e.errno == errno.ENOSPC
        assert main([*FLY, "--gif", str(gif)]) == 1
        out, err = capsys.readouterr()
        assert json.loads(out)["flights"] == 2
        assert err.strip().splitlines()[-1].endswith(
            f"could not write {str(gif)!r}: No space left on device; the earlier file is "
            f"kept whole")
        assert gif.read_bytes() == b"GIF89a the earlier one"
        assert sorted(p.name for p in disk.iterdir()) == ["f.gif", "filler"]
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_a_read_only_folder_is_said_before_any_work(tmp_path, capsys):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        if os.access(folder, os.W_OK):
            pytest.skip("this user writes into read-only folders (root)")
        assert main([*FLY, "--gif", str(folder / "f.gif")]) == 2
        assert "is not writable" in _one_line(capsys.readouterr().err)
    finally:
        folder.chmod(0o755)


# -- odd paths ------------------------------------------------------------------------------
def test_a_symlink_loop_is_one_line_in_every_command(tmp_path, frames, capsys):
    loop = tmp_path / "loop"
    loop.symlink_to(tmp_path / "loop2")
    (tmp_path / "loop2").symlink_to(loop)
    commands = [
        ["train-agent", "--smoke", "--out", str(loop)],
        ["distil", "--smoke", "--teachers", str(MODELS / "d3rqn_basic.npz"), "--out", str(loop)],
        ["collect", "--frames", "20", "--out", str(loop / "c.npz")],
        ["train-depth", "--dir", str(loop)],
        [*FLY, "--gif", str(loop / "f.gif")],
        ["eval-depth", "--test-data", str(frames), "--json", str(loop / "e.json")],
        ["eval-depth", "--test-data", str(loop / "t.npz")],
        ["evaluate", "straight", "--json", str(loop / "e.jsonl")],
        ["reproduce", "--quick", "--out", str(loop)],
    ]
    for argv in commands:
        assert main(argv) == 2, argv
        assert "is in a loop of symbolic links" in _one_line(capsys.readouterr().err), argv


def test_a_name_that_is_not_utf8_is_refused_in_one_line(tmp_path):
    name = os.fsdecode(b"caf\xe9.npz")
    done = subprocess.run([sys.executable, "-m", "minid3rqn", "collect", "--frames", "20",
                           "--out", name], env=ENV, cwd=tmp_path, capture_output=True)
    err = done.stderr.decode("utf-8", "replace")
    assert done.returncode == 2, err
    assert "is not a UTF-8 name" in _one_line(err) and "caf\\udce9.npz" in err
    assert list(tmp_path.iterdir()) == []


def test_an_output_that_is_a_symlink_is_written_through(tmp_path, capsys):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "c.npz"
    target.write_bytes(b"old")
    link = tmp_path / "c.npz"
    link.symlink_to(target)
    assert main(["collect", "--frames", "3", "--out", str(link), "--overwrite"]) == 0
    assert link.is_symlink() and len(load_npz(target)[0]["rgb"]) == 3
    dangling = tmp_path / "d.json"                       # a dangling link makes its target
    dangling.symlink_to(tmp_path / "real" / "made.json")
    write_file(dangling, "{}")
    assert dangling.is_symlink() and (tmp_path / "real" / "made.json").read_text() == "{}"


def test_a_qnet_file_with_plus_in_its_name_is_one_file(tmp_path, capsys):
    plus = tmp_path / "a+b.npz"
    shutil.copy(MODELS / "d3rqn_basic.npz", plus)
    assert main(["evaluate", str(plus), "--flights", "2", "--chunk", "2"]) == 0
    capsys.readouterr()
    alone = tmp_path / "a.npz"                           # '+' joins files that exist ...
    shutil.copy(MODELS / "d3rqn_basic.npz", alone)
    assert main(["evaluate", f"{alone}+{alone}", "--flights", "2", "--chunk", "2"]) == 0
    assert "ens2" in capsys.readouterr().err + "ens2"
    assert main(["evaluate", f"{alone}+{tmp_path / 'nope.npz'}"]) == 2   # ... or none
    assert "'" + str(tmp_path / "nope.npz") + "' not found" in _one_line(capsys.readouterr().err)


# -- sizes ----------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, expected", [
    (["evaluate", "straight", "--flights", "99999999999999"],
     "--flights: expected at most 1,000,000 (a million flights give a 95% interval"),
    (["evaluate", "straight", "--chunk", "100000000000"], "--chunk: expected at most"),
    (["fly", "--flights", "100000000000"], "--flights: expected at most"),
    (["train-agent", "--seq-len", "1000"], "--seq-len: expected at most 50 (a flight's 50 "
                                           "steps); got 1000"),
    (["train-agent", "--set", "stack=51"], "--set stack: expected at most 50"),
    (["train-agent", "--replay-capacity", "10000000000"], "--replay-capacity: expected at most"),
    (["collect", "--frames", "100000000000"], "--frames: expected at most"),
    (["train-depth", "--set", "test_frames=100000000000"], "--set test_frames: expected at most"),
    (["evaluate", "straight", "--steps", "100000000"], "--steps: expected at most 10,000"),
])
def test_a_size_too_large_is_one_line(argv, expected, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert expected in line, line
    assert list(tmp_path.iterdir()) == []


def test_more_workers_than_cores_are_capped_with_a_note(tmp_path, capsys):
    from minid3rqn.config import cores
    assert main(["evaluate", "straight", "--flights", "4", "--chunk", "2", "--workers",
                 "1000", "--json", str(tmp_path / "e.jsonl")]) == 0
    err = capsys.readouterr().err
    assert f"note: --workers 1000 is more than the {cores()} cores of this machine; using " \
           f"{cores()}" in err
    record = json.loads((tmp_path / "e.jsonl").read_text())
    assert record["flights"] == 4


def test_a_seed_that_is_no_seed_is_named_where_it_enters():
    from minid3rqn.depth.data import collect
    from minid3rqn.rl.evaluate import evaluate_policy
    from minid3rqn.rl.policies import StraightPolicy
    for bad in (-1, 1.5, "7", None):
        with pytest.raises(ValueError, match=r"^evaluate_policy: seed: expected an integer "
                                             r">= 0; got "):
            evaluate_policy(StraightPolicy(), n_flights=2, seed=bad, progress=False)
        with pytest.raises(ValueError, match=r"^collect: seed: expected an integer >= 0"):
            collect(n_frames=3, seed=bad, progress=False)
    assert evaluate_policy(StraightPolicy(), n_flights=1, seed=np.int64(3),
                           progress=False).flights == 1


# -- the checker: student code in a process of its own --------------------------------------
STUDENT = {
    "kill9": "import os\ndef reward(d, c, w=0.0):\n    os.kill(os.getpid(), 9)\n",
    "cpu": ("import signal\ndef reward(d, c, w=0.0):\n"
            "    signal.signal(signal.SIGALRM, signal.SIG_IGN)\n    while True:\n"
            "        pass\n"),
    "hang": ("import signal, time\ndef reward(d, c, w=0.0):\n"
             "    signal.signal(signal.SIGALRM, signal.SIG_IGN)\n    time.sleep(600)\n"),
    "exit0": "import os\ndef reward(d, c, w=0.0):\n    os._exit(0)\n",
}


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the checker runs apart where it forks")
@pytest.mark.parametrize("kind, expected", [
    ("kill9", "your code stopped the checker: killed by signal 9 (SIGKILL)"),
    ("cpu", "your code stopped the checker: killed by signal 24 (SIGXCPU: more than 1 s of "
            "CPU time)"),
    ("hang", "your code stopped the checker: it was still running after 3 s"),
    ("exit0", "your code stopped the checker: it ended the process (exit status 0)"),
])
def test_student_code_that_stops_its_process_is_one_line(kind, expected, tmp_path):
    from minid3rqn.classroom.checks import EXERCISES
    from minid3rqn.classroom.student import check_in_child
    path = tmp_path / "reward.py"
    path.write_text(STUDENT[kind])
    report = check_in_child(EXERCISES["reward"].checker, path, "1 (reward)", seconds=3,
                            cpu_seconds=1)
    assert not report.passed and report.failures[0].startswith(expected), report.failures
    assert len(report.lines) == 1


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the checker runs apart where it forks")
def test_what_student_code_forks_does_not_outlive_the_check(tmp_path):
    from minid3rqn.classroom.checks import EXERCISES
    from minid3rqn.classroom.student import check_in_child
    pid_file = tmp_path / "pid"
    path = tmp_path / "reward.py"
    path.write_text(f"import os, time\nif os.fork() == 0:\n"
                    f"    open({str(pid_file)!r}, 'w').write(str(os.getpid()))\n"
                    f"    time.sleep(600)\n"
                    f"import numpy as np\n"
                    f"def reward(d, c, w=0.0):\n    return np.where(c, -1.0, d)\n")
    started = __import__("time").monotonic()
    report = check_in_child(EXERCISES["reward"].checker, path, "1 (reward)", seconds=30)
    assert __import__("time").monotonic() - started < 25      # not held by the fork's pipe
    assert "loads" in report.messages                          # the check itself ran
    pid = int(pid_file.read_text())
    for _ in range(50):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        __import__("time").sleep(0.1)
    else:
        pytest.fail(f"the student's forked process {pid} outlived the check")


def test_a_check_apart_reports_as_one_in_process(tmp_path):
    from minid3rqn.classroom.checks import EXERCISES
    from minid3rqn.classroom.student import check_in_child
    solution = ROOT / "docs" / "solutions" / "reward.py"
    here, apart = EXERCISES["reward"].checker(solution), \
        check_in_child(EXERCISES["reward"].checker, solution)
    assert apart.passed and apart.lines == here.lines and apart.text() == here.text()
    assert apart.summary == json.loads(json.dumps(here.summary, default=float))


# -- the right reason ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def snapshot(tmp_path_factory):
    """A train-agent run stopped at 64 of its 128 steps: checkpoint.npz and model.npz."""
    from minid3rqn.rl.train import SMOKE, Run, TrainConfig
    out = tmp_path_factory.mktemp("snap") / "run"
    run = Run(TrainConfig(**SMOKE), out)
    run.start()
    run.steps = 64
    run.save_checkpoint()
    return out


def _resave(src: Path, dst: Path, arrays=None, **meta) -> Path:
    a, m = load_npz(src)
    io.save_npz(dst, arrays(a) if arrays else a, {**m, **meta})
    return dst


def test_a_training_checkpoint_given_to_evaluate_is_named_as_one(snapshot, capsys):
    assert main(["evaluate", str(snapshot / "checkpoint.npz"), "--flights", "2"]) == 2
    assert "is a training checkpoint (its run's Q-net is model.npz beside it)" in \
        _one_line(capsys.readouterr().err)


def test_int_weights_are_refused(snapshot, tmp_path, capsys):
    bad = _resave(snapshot / "model.npz", tmp_path / "int.npz",
                  arrays=lambda a: {k: v.astype(np.int32) for k, v in a.items()})
    assert main(["evaluate", str(bad), "--flights", "2"]) == 2
    assert "is int32, not floating point" in _one_line(capsys.readouterr().err)


@pytest.mark.parametrize("damage, expected", [
    ("nan", "holds NaN or inf: the file is damaged"),
    ("steps", "records an impossible count (-5 steps"),
])
def test_a_damaged_checkpoint_is_not_resumed_for_the_wrong_reason(damage, expected, snapshot,
                                                                 tmp_path, capsys):
    from minid3rqn.rl.train import SMOKE
    run = tmp_path / "run"
    shutil.copytree(snapshot, run)
    ckpt = run / "checkpoint.npz"
    if damage == "nan":
        def poison(a):
            key = next(k for k in a if k.startswith("agent.") and a[k].dtype.kind == "f")
            a[key] = np.full_like(a[key], np.nan)
            return a
        _resave(ckpt, ckpt, arrays=poison)
    else:
        _resave(ckpt, ckpt, steps=-5)
    assert main(["train-agent", "--smoke", "--out", str(run), "--resume"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert expected in line and "diverged" not in line.split("damaged")[0], line
    assert SMOKE                                    # the run it resumes is a smoke run


def test_a_killed_runs_snapshot_is_said_by_fly_and_init_model(snapshot, tmp_path, capsys):
    assert main([*FLY, "--model", str(snapshot / "model.npz"),
                 "--gif", str(tmp_path / "f.gif")]) == 0
    assert "is a snapshot at 64 of its run's 128 transitions" in capsys.readouterr().err
    assert main(["train-agent", "--smoke", "--steps", "64", "--init-model",
                 str(snapshot / "model.npz"), "--out", str(tmp_path / "ft")]) == 0
    assert "--init-model: warning: Q-net" in capsys.readouterr().err


@pytest.mark.slow
def test_a_moved_depth_run_resumes(tmp_path, capsys, monkeypatch):
    from minid3rqn.depth import train as depth_train
    run = tmp_path / "d"
    argv = ["--iterations", "2", "--set", "test_frames=30", "--set", "eval_every=0",
            "--frames", "30"]

    def killed(self, *a, **k):                     # stopped before it writes its model
        raise KeyboardInterrupt
    monkeypatch.setattr(depth_train.DepthEstimator, "save", killed)
    assert main(["train-depth", "--dir", str(run), *argv]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    moved = tmp_path / "elsewhere"
    run.rename(moved)
    assert main(["train-depth", "--dir", str(moved), *argv, "--resume"]) == 0, \
        capsys.readouterr().err
    assert (moved / "model.npz").is_file()
