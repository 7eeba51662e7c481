"""Every command refuses a bad input with one line that names the option (or the file),
without a traceback, before it changes any file.

Each case runs ``python -m minid3rqn ...`` as ``cli.main`` in this process (fast: the
commands fail before any work); a few run as a real subprocess too, which is what a
user sees. The files the cases point at (a Q-net with NaN weights, a depth model where a
Q-net belongs, a folder holding a run...) are made once, in a folder whose every file
is compared before and after each case, as are the case's own working folder and
minid3rqn/models.
"""
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import cli
from minid3rqn.io import MODELS, load_npz, save_npz

ROOT = Path(__file__).resolve().parent.parent

# (command line, what the one line must name); {fx} is the folder of the files below.
CASES = [
    # fly
    ("fly --flights 0", "--flights: expected a number >= 1"),
    ("fly --scenario moon", "--scenario: invalid choice: 'moon'"),
    ("fly --seed abc", "--seed: expected an integer"),
    ("fly --bogus", "unrecognized arguments: --bogus"),
    ("fly --model nope.npz", "--model: Q-net 'nope.npz' not found"),
    ("fly --model {fx}/qnet.npz+", "--model: Q-net '' not found"),
    ("fly --model {fx}/nan.npz", "--model: '{fx}/nan.npz': weight"),
    ("fly --model {fx}/qmissing.npz", "--model: '{fx}/qmissing.npz' is not a readable Q-net"),
    ("fly --model {fx}/depth.npz", "--model: '{fx}/depth.npz' is a depth model"),
    ("fly --model {fx}/trunc.npz", "--model: '{fx}/trunc.npz' is not a readable .npz"),
    ("fly --depth gt --flip-tta", "--flip-tta: averages the DispNet's disparity"),
    ("fly --model {fx}/qnet.npz+{fx}/odd.npz", "--model: 'D3RQN' was trained with another "
                                               "action table or camera"),
    ("fly --gif {fx}/afile/x.gif", "--gif: '{fx}/afile/x.gif' cannot be made"),
    ("fly --gif out.png", "--gif: expected a .gif file"),
    ("fly --gif " + str(MODELS / "x.gif"), "--gif: '" + str(MODELS / "x.gif") + "' is inside"),
    # train-agent
    ("train-agent --steps 0", "--steps: expected a number >= 1; got 0"),
    ("train-agent --batch-size 0", "--batch-size: expected a number >= 1"),
    ("train-agent --lr -1", "--lr: expected a number > 0"),
    ("train-agent --variant dqn", "--variant: invalid choice: 'dqn'"),
    ("train-agent --seq-len 0", "--seq-len: expected a number >= 1"),
    ("train-agent --replay-capacity 10", "--replay-capacity: expected a number >= 64"),
    ("train-agent --set nope=1", "--set: expected NAME=VALUE"),
    ("train-agent --smoke --set n_envs=64 --replay-capacity 64", "--replay-capacity: expected "
                                                                 "at least 4 frames per flight"),
    ("train-agent --set conv_channels=1.5,2,3", "--set conv_channels: expected three whole"),
    ("train-agent --set n_envs=abc", "--set n_envs: expected an integer"),
    ("train-agent --set actions=1,2,3", "--set actions: expected rows of (speed"),
    ("train-agent --set actions=2,0;2,x", "--set actions: expected numbers joined by ','"),
    ("train-agent --depth-model", "--depth-model: expected one argument"),
    ("train-agent --resume --overwrite", "--resume and --overwrite: give one of them"),
    ("train-agent --depth pred --depth-model nope.npz", "--depth-model: depth model 'nope.npz'"),
    ("train-agent --depth pred --depth-model {fx}/qnet.npz",
     "--depth-model: '{fx}/qnet.npz' is not a depth model"),
    ("train-agent --smoke --depth-model {fx}/depth.npz", "--depth-model: only read with "
                                                         "--depth pred"),
    ("train-agent --smoke --init-model nope.npz", "--init-model: no file 'nope.npz'"),
    ("train-agent --smoke --init-model {fx}/depth.npz", "--init-model: '{fx}/depth.npz' is "
                                                        "a depth model"),
    ("train-agent --smoke --init-model {fx}/nan.npz", "--init-model: '{fx}/nan.npz': weight"),
    ("train-agent --smoke --init-model {fx}/qnet.npz", "--init-model: '{fx}/qnet.npz' is "
                                                       "another network"),
    ("train-agent --smoke --out {fx}/afile", "--out: '{fx}/afile' is a file"),
    ("train-agent --smoke --out {fx}/run", "--out: '{fx}/run' holds a run"),
    ("train-agent --smoke --hidden 8 --out {fx}/run --resume", "hidden 16 (now 8)"),
    ("train-agent --smoke --steps 64 --out {fx}/run --resume", "at 128 steps already"),
    ("train-agent --smoke --out {fx}/drun --resume", "--resume: the checkpoint in '{fx}/drun' "
                                                     "is not one of train-agent or distil"),
    ("train-agent --smoke --out {fx}/damaged --resume", "--resume: '{fx}/damaged/checkpoint.npz' "
                                                        "cannot be continued"),
    ("train-agent --smoke --out {fx}/modelonly --resume", "--resume: '{fx}/modelonly' holds "
                                                          "no checkpoint.npz"),
    ("train-agent --smoke --out " + str(MODELS), "--out: '" + str(MODELS) + "' is inside"),
    # distil
    ("distil --smoke", "--teachers: expected Q-net .npz files"),
    ("distil --smoke --teachers nope.npz", "--teachers: 'nope.npz' is not a file"),
    ("distil --smoke --teachers {fx}/qnet.npz+", "--teachers: expected Q-net .npz files"),
    ("distil --smoke --teachers {fx}/depth.npz", "--teachers: '{fx}/depth.npz' is a depth"),
    ("distil --smoke --teachers {fx}/nan.npz", "--teachers: '{fx}/nan.npz': weight"),
    ("distil --smoke --teachers {fx}/odd.npz", "--teachers: '{fx}/odd.npz' was trained with "
                                               "another action table or camera"),
    ("distil --smoke --teachers {fx}/qnet.npz --set init_widen=true", "--init-model"),
    ("distil --steps 0", "--steps: expected a number >= 1"),
    ("distil --set distil_kl=-1", "--set distil_kl: expected a number >= 0"),
    ("distil --set teacher_mix=2", "--set teacher_mix: expected a number in [0, 1]"),
    ("distil --smoke --teachers {fx}/qnet.npz --depth-model nope.npz",
     "--depth-model: depth model 'nope.npz'"),
    ("distil --smoke --teachers {fx}/qnet.npz --out {fx}/afile", "--out: '{fx}/afile' is a"),
    ("distil --smoke --teachers {fx}/qnet.npz --out {fx}/run", "--out: '{fx}/run' holds a run"),
    ("distil --smoke --teachers {fx}/qnet.npz --out {fx}/run --resume", "--resume: the run in "
                                                "'{fx}/run' was made by train-agent, not distil"),
    # evaluate
    ("evaluate", "the following arguments are required: policies"),
    ("evaluate nope.npz", "'nope.npz' not found"),
    ("evaluate straight moon", "'moon' not found"),
    ("evaluate {fx}/adir", "'{fx}/adir' is a folder"),
    ("evaluate {fx}/nan.npz", "'{fx}/nan.npz': weight"),
    ("evaluate {fx}/trunc.npz", "'{fx}/trunc.npz' is not a readable .npz"),
    ("evaluate straight {fx}/qnet.npz+{fx}/odd.npz", "was trained with another action table"),
    ("evaluate straight --flights 0", "--flights: expected a number >= 1"),
    ("evaluate straight --chunk 0", "--chunk: expected a number >= 1"),
    ("evaluate straight --workers 0", "--workers: expected a number >= 1"),
    ("evaluate straight --mirror", "--mirror: mirrors Q-nets"),
    ("evaluate reactive --flip-tta", "--flip-tta: expected false with --depth gt"),
    ("evaluate reactive --depth-model {fx}/depth.npz", "--depth-model: expected none with "
                                                       "--depth gt"),
    ("evaluate reactive --depth pred --depth-model nope.npz", "--depth-model: depth model "
                                                              "'nope.npz'"),
    ("evaluate reactive --depth pred --depth-model {fx}/qnet.npz", "--depth-model: "),
    ("evaluate {fx}/qmissing.npz", "'{fx}/qmissing.npz' is not a readable Q-net file"),
    ("evaluate reactive --depth pred --depth-model {fx}/dnan.npz", "--depth-model: "
                                                                   "'{fx}/dnan.npz': weight"),
    ("evaluate straight --json {fx}/adir.jsonl", "--json: '{fx}/adir.jsonl' is a folder"),
    ("evaluate straight --json {fx}/afile/x.jsonl", "--json: '{fx}/afile/x.jsonl' cannot"),
    ("evaluate straight --json {fx}/half.jsonl", "--json: '{fx}/half.jsonl': its last line"),
    ("evaluate straight --json {fx}/bad.jsonl", "--json: '{fx}/bad.jsonl': its last line is "
                                                "not a JSON record"),
    ("evaluate straight --json {fx}/qnet.json", "--json: expected a .jsonl file"),
    ("evaluate straight --json " + str(MODELS / "x.jsonl"), "--json: '" + str(MODELS) + ""),
    # reproduce
    ("reproduce --workers 0", "--workers: expected a number >= 1"),
    ("reproduce --students 2", "--students 2: only for --recipe distil"),
    ("reproduce --recipe nope", "--recipe: invalid choice: 'nope'"),
    ("reproduce --quick --out {fx}/afile", "--out: '{fx}/afile' is a file"),
    ("reproduce --quick --out " + str(MODELS), "--out: '" + str(MODELS) + "' is inside"),
    ("reproduce --executor dask", "--executor: invalid choice: 'dask'"),
    ("sweep --seeds 0,0", "--seeds: expected different whole numbers >= 0"),
    ("sweep --seeds one", "--seeds: expected numbers joined by ','"),
    ("sweep --flights 0", "--flights: expected a number >= 1"),
    ("sweep --workers 0", "--workers: expected a number >= 1"),
    ("sweep --out {fx}/afile", "--out: '{fx}/afile' is a file"),
    ("sweep --depth pred --depth-model {fx}/nope.npz", "--depth-model: depth model"),
    # pool
    ("pool", "the following arguments are required: files"),
    ("pool nope.jsonl", "no such results file: nope.jsonl"),
    ("pool {fx}/bad.jsonl", "{fx}/bad.jsonl line 1 is not a JSON record"),
    ("pool {fx}/list.jsonl", "{fx}/list.jsonl line 1 is not a JSON object"),
    ("pool {fx}/short.jsonl", "{fx}/short.jsonl line 1 has world counts that do not match"),
    ("pool {fx}/old.jsonl --where nokey", "--where: expected KEY=VALUE"),
    ("pool {fx}/old.jsonl --against x", "--against: expected KEY=VALUE"),
    ("pool {fx}/empty.jsonl", "no evaluation records to pool"),
    ("pool {fx}/old.jsonl", "record 0 (x, basic, seed 1) has no world counts"),
    # collect
    ("collect --frames 2", "--frames: expected a number >= 3"),
    ("collect --scenario moon", "--scenario: invalid choice: 'moon'"),
    ("collect --set late_turns=2", "--set late_turns: expected a number in [0.0, 1.0]"),
    ("collect --frames 20 --out {fx}/frames.npz", "--out: '{fx}/frames.npz' exists; give "
                                                  "--overwrite"),
    ("collect --frames 20 --out x.txt", "--out: expected a .npz file"),
    ("collect --frames 20 --out {fx}/afile/x.npz", "--out: '{fx}/afile/x.npz' cannot be made"),
    ("collect --frames 20 --out " + str(MODELS / "depth_basic.npz"), "--out: '"
     + str(MODELS / "depth_basic.npz") + "' is inside"),
    # train-depth
    ("train-depth --iterations 0", "--iterations: expected a number >= 1"),
    ("train-depth --lr nan", "--lr: expected a finite number"),
    ("train-depth --set test_frames=2", "--set test_frames: expected a number >= 3"),
    ("train-depth --set ssim_weight=2", "--set ssim_weight: expected a number in"),
    ("train-depth --init-from nope.npz", "--init-from: no file 'nope.npz'"),
    ("train-depth --init-from {fx}/qnet.npz --dir d", "--init-from: '{fx}/qnet.npz' is "
                                                      "neither"),
    ("train-depth --data {fx}/qnet.npz --dir d", "--data: '{fx}/qnet.npz' holds no frames"),
    ("train-depth --data {fx}/trunc.npz --dir d", "--data: '{fx}/trunc.npz' is not a readable"),
    ("train-depth --data x.txt --dir d", "--data: expected a .npz file"),
    ("train-depth --scenario channel --data {fx}/frames.npz --dir d", "--data: "
     "'{fx}/frames.npz' holds frames of basic, not channel"),
    ("train-depth --dir {fx}/afile", "--dir: '{fx}/afile' is a file"),
    ("train-depth --dir {fx}/drun", "--dir: '{fx}/drun' holds a run"),
    ("train-depth --dir {fx}/drun --resume --lr 0.001", "lr 0.0005 (now 0.001)"),
    ("train-depth --dir {fx}/drun --resume --iterations 1", "at iteration 2 already"),
    ("train-depth --data {fx}/frames.npz --test-data {fx}/frames.npz",
     "--test-data: '{fx}/frames.npz' is the --data file"),
    ("train-depth --data {fx}/two.npz --test-data {fx}/dframes/train.npz",
     "--data: '{fx}/two.npz' holds no triplet"),
    ("eval-depth --test-data {fx}/nodepth.npz", "--test-data: '{fx}/nodepth.npz' holds no "
                                                "finite ground-truth depth"),
    ("train-depth --dir {fx}/run --resume --data {fx}/frames.npz --test-data "
     "{fx}/dframes/train.npz",
     "--resume: '{fx}/run/checkpoint.npz' is not a train-depth checkpoint"),
    ("train-depth --dir {fx}/dframes", "frames 20 (now 5000)"),
    ("train-depth --dir " + str(MODELS), "--dir: '" + str(MODELS) + "' is inside"),
    # eval-depth
    ("eval-depth --model {fx}/dnan.npz", "--model: '{fx}/dnan.npz': weight"),
    ("eval-depth --model {fx}/dmissing.npz", "--model: '{fx}/dmissing.npz' is not a readable"),
    ("eval-depth --model {fx}/dscale.npz", "--model: '{fx}/dscale.npz' records the scale 0.0"),
    ("eval-depth --model nope.npz", "--model: no file 'nope.npz'"),
    ("eval-depth --model {fx}/qnet.npz", "--model: '{fx}/qnet.npz' is not a depth model"),
    ("eval-depth --scenario moon", "--scenario: invalid choice: 'moon'"),
    ("eval-depth --test-data {fx}/qnet.npz", "--test-data: '{fx}/qnet.npz' holds no frames"),
    ("eval-depth --scenario corners --test-data {fx}/frames.npz", "--test-data: "
     "'{fx}/frames.npz' holds frames of basic, not corners"),
    ("eval-depth --test-data {fx}/frames.npz --json {fx}/adir.json", "--json: '{fx}/adir.json' "
                                                                      "is a"),
    ("eval-depth --test-data {fx}/frames.npz --json r.txt", "--json: expected a .json file"),
    ("eval-depth --test-data {fx}/frames.npz --json {fx}/old.json", "--json: '{fx}/old.json' "
                                                                    "exists; give --overwrite"),
    ("eval-depth --test-data {fx}/frames.npz --pictures {fx}/old.png", "--pictures: "
                                                                       "'{fx}/old.png' exists"),
    ("train-agent --smoke --out {fx}/run --overwrite --init-model {fx}/run/model.npz",
     "--init-model: '{fx}/run/model.npz' is a file of the run in '{fx}/run', which --overwrite"),
    ("train-depth --init-from {fx}/dnan.npz", "--init-from: '{fx}/dnan.npz': weight"),
    ("train-depth --dir {fx}/drun --overwrite --init-from {fx}/drun/checkpoint.npz",
     "--init-from: '{fx}/drun/checkpoint.npz' is a file of the run"),
    ("eval-depth --test-data {fx}/frames.npz --pictures p.txt", "--pictures: expected a .png"),
    ("eval-depth --test-data {fx}/frames.npz --pictures {fx}/afile/p.png",
     "--pictures: '{fx}/afile/p.png' cannot be made"),
    ("eval-depth --test-data {fx}/frames.npz --json " + str(MODELS / "depth_basic.json"),
     "--json: '" + str(MODELS / "depth_basic.json") + "' is inside"),
    # check, exercise
    ("check", "the following arguments are required: exercise"),
    ("check nope", "unknown exercise 'nope'"),
    ("check all --file {fx}/afile", "--file: 'all' checks a folder of exercise files; got the file"),
    ("check reward --file x.py", "--file: 'x.py' does not exist"),
    ("check reward --file nope_dir/", "--file"),
    ("exercise reward --seed x", "--seed"),
    ("exercise nope", "unknown exercise 'nope'"),
    ("exercise reward --file nope.py", "--file: 'nope.py' is not a file"),
    ("exercise reward --file {fx}/adir", "--file: '{fx}/adir' is not a file"),
    ("exercise fov --budget huge", "--budget: invalid choice: 'huge'"),
    ("exercise", "the following arguments are required: exercise"),
    # a negative seed, in every command that takes one
    ("fly --seed -1", "--seed: expected a number >= 0; got -1"),
    ("train-agent --smoke --seed -1", "--seed: expected a number >= 0; got -1"),
    ("distil --smoke --teachers {fx}/qnet.npz --seed -1", "--seed: expected a number >= 0"),
    ("evaluate straight --seed -1", "--seed: expected a number >= 0; got -1"),
    ("collect --frames 20 --seed -1", "--seed: expected a number >= 0; got -1"),
    ("train-depth --seed -1", "--seed: expected a number >= 0; got -1"),
    ("exercise reward --seed -1", "--seed: expected a number >= 0; got -1"),
    # the command itself
    ("nope", "invalid choice: 'nope'"),
    ("--bogus", "unrecognized arguments: --bogus"),
]

# What a user sees: a few of them as real processes (one of each way of failing).
IN_SUBPROCESS = ["fly --scenario moon", "train-agent --steps 0", "train-agent --smoke --out "
                 "{fx}/run", "evaluate {fx}/nan.npz", "collect --frames 20 --out x.txt", "nope"]


def _make_files(fx: Path) -> None:
    from minid3rqn.depth.data import CollectConfig, collect_sequence
    from minid3rqn.depth.train import TrainConfig as DepthConfig, Trainer
    from minid3rqn.rl.train import SMOKE, Run, TrainConfig
    shutil.copy(MODELS / "d3rqn_basic.npz", fx / "qnet.npz")
    shutil.copy(MODELS / "depth_basic.npz", fx / "depth.npz")
    arrays, meta = load_npz(fx / "qnet.npz")
    first = next(iter(arrays))
    arrays[first] = arrays[first].copy()
    arrays[first].flat[0] = np.nan
    save_npz(fx / "nan.npz", arrays, meta)
    save_npz(fx / "qmissing.npz", dict(list(arrays.items())[1:]), meta)   # a weight gone
    arrays, meta = load_npz(fx / "depth.npz")
    save_npz(fx / "dmissing.npz", dict(list(arrays.items())[1:]), meta)
    first = next(iter(arrays))
    arrays[first] = arrays[first].copy()
    arrays[first].flat[0] = np.inf
    save_npz(fx / "dnan.npz", arrays, meta)
    save_npz(fx / "dscale.npz", load_npz(fx / "depth.npz")[0], {**meta, "scale": 0.0})
    arrays, meta = load_npz(fx / "qnet.npz")
    meta["train_config"]["hfov_deg"] = 60.0                # a net of another camera
    save_npz(fx / "odd.npz", arrays, meta)
    (fx / "trunc.npz").write_bytes((fx / "qnet.npz").read_bytes()[:5000])
    (fx / "afile").write_text("a file where a folder is meant")
    (fx / "adir").mkdir()
    (fx / "adir.json").mkdir()
    (fx / "adir.jsonl").mkdir()
    (fx / "old.json").write_text("{}")
    (fx / "old.png").write_bytes(b"not really a picture")
    (fx / "half.jsonl").write_text('{"a": 1}\n{"a": 2')
    (fx / "bad.jsonl").write_text("not json\n")
    (fx / "list.jsonl").write_text("[1, 2]\n")
    (fx / "short.jsonl").write_text('{"scenario": "basic", "seed": 1, "world_seeds": [1, 2], '
                                    '"world_successes": [1], "world_flights": [2, 2]}\n')
    (fx / "old.jsonl").write_text('{"spec": "x", "scenario": "basic", "seed": 1}\n')
    (fx / "empty.jsonl").write_text("")
    (fx / "modelonly").mkdir()
    shutil.copy(fx / "qnet.npz", fx / "modelonly" / "model.npz")
    frames = collect_sequence(CollectConfig(frames=20, frames_per_flight=10),
                              fx / "frames.npz", progress=False)
    arrays, meta = load_npz(fx / "frames.npz")
    save_npz(fx / "two.npz", {k: v[:2] if k in ("rgb", "flight", "depth", "pose") else v
                              for k, v in arrays.items()}, meta)
    save_npz(fx / "nodepth.npz", {k: v for k, v in arrays.items() if k != "depth"}, meta)
    (fx / "dframes").mkdir()
    shutil.copy(fx / "frames.npz", fx / "dframes" / "train.npz")
    run = Run(TrainConfig(**SMOKE), fx / "run")           # a run checkpointed at 128 steps
    run.start()
    run.steps = 128
    run.save_checkpoint()
    shutil.copytree(fx / "run", fx / "damaged")             # its checkpoint missing an array
    arrays, meta = load_npz(fx / "damaged" / "checkpoint.npz")
    save_npz(fx / "damaged" / "checkpoint.npz", dict(list(arrays.items())[1:]), meta)
    trainer = Trainer(frames, DepthConfig(), checkpoint=fx / "drun" / "checkpoint.npz",
                      settings={"data": str((fx / "drun" / "train.npz").resolve())})
    trainer.iteration = 2                                  # a depth run at iteration 2
    trainer.save_checkpoint(trainer.checkpoint)


@pytest.fixture(scope="module")
def fx(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fx")
    _make_files(folder)
    return folder


def _state(*folders) -> dict:
    """Every file and folder under ``folders``: its size and modification time."""
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns)
            for folder in folders for p in sorted(Path(folder).rglob("*"))}


def _check(code, err: str, expected: str, before: dict, after: dict) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code not in (0, None), err
    assert "Traceback" not in err, err
    assert len(lines) == 1, err
    assert expected in lines[0], (expected, lines[0])
    assert after == before, "files changed"


@pytest.mark.parametrize("line, expected", CASES, ids=[c[0][:60] for c in CASES])
def test_a_bad_input_is_one_line_naming_it(line, expected, fx, tmp_path, monkeypatch, capsys):
    argv = shlex.split(line.format(fx=fx))
    monkeypatch.chdir(tmp_path)
    before = _state(fx, tmp_path, MODELS)
    try:
        code = cli.main(argv)
    except SystemExit as e:           # argparse's refusals
        code = e.code
    _check(code, capsys.readouterr().err, expected.format(fx=fx), before,
           _state(fx, tmp_path, MODELS))


@pytest.mark.parametrize("line", IN_SUBPROCESS)
def test_as_a_user_sees_it(line, fx, tmp_path):
    expected = dict(CASES)[line]
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    before = _state(fx, tmp_path, MODELS)
    done = subprocess.run([sys.executable, "-m", "minid3rqn",
                           *shlex.split(line.format(fx=fx))], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    _check(done.returncode, done.stderr, expected.format(fx=fx), before,
           _state(fx, tmp_path, MODELS))


def test_the_table_covers_every_command():
    commands = {shlex.split(line)[0] for line, _ in CASES}
    assert set(cli.COMMANDS) <= commands and len(CASES) >= 60
