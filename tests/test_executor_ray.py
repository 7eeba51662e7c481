"""The same numbers on Ray: on a local Ray cluster, an evaluation gives the counts of the
local pool and of one process, a seed sweep bit-identical model files; a run folder the
workers cannot see is refused in one line. Skipped when ray is not installed."""
import json
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow       # a Ray start alone takes about 20 s

from minid3rqn.config import UsageError  # noqa: E402
from minid3rqn.executor import LocalPool, RayExecutor  # noqa: E402
from minid3rqn.io import load_npz  # noqa: E402
from minid3rqn.rl.train import SMOKE, TrainConfig  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def on_ray(killed_once):
    import sys
    for fn in (_where, killed_once):       # by value: the workers cannot import the tests
        ray.cloudpickle.register_pickle_by_value(sys.modules[fn.__module__])
    executor = RayExecutor()
    executor._init()
    yield executor
    ray.shutdown()


def _where(shared, task):
    import minid3rqn
    return minid3rqn.__file__


def test_ray_workers_import_this_copy(on_ray):
    assert on_ray.run(_where, [0, 1]) == [str(ROOT / "minid3rqn" / "__init__.py")] * 2


def test_an_evaluation_on_ray_gives_the_local_counts(on_ray):
    from minid3rqn.rl.evaluate import evaluate_policy
    from minid3rqn.rl.models import MODELS, load_policy
    policy = load_policy(str(MODELS / "d3rqn_basic.npz"), 1)
    results = [evaluate_policy(policy, n_flights=24, chunk=8, max_steps=20, progress=False,
                               executor=executor).to_dict()
               for executor in (LocalPool(1), LocalPool(2), on_ray)]
    for r in results:
        r.pop("seconds")
    assert results[0] == results[1] == results[2]


def test_a_sweep_on_ray_trains_the_local_models_bit_for_bit(on_ray, tmp_path):
    from minid3rqn.rl.sweep import SweepConfig, sweep
    train = TrainConfig(**{**SMOKE, "steps": 64})
    runs = {}
    for name, how in (("one", {"workers": 1}), ("pool", {"workers": 2}),
                      ("ray", {"executor": "ray"})):
        cfg = SweepConfig(seeds=[0, 1], flights=8, train=train, **how)
        res = sweep(cfg, tmp_path / name, progress=False)
        runs[name] = [{k: v for k, v in r.items() if k not in ("seconds", "spec", "command")}
                      for r in res["runs"]]
    assert runs["one"] == runs["pool"] == runs["ray"]
    for seed in (0, 1):
        one = load_npz(tmp_path / "one" / f"s{seed}" / "model.npz")[0]
        for name in ("pool", "ray"):
            other = load_npz(tmp_path / name / f"s{seed}" / "model.npz")[0]
            assert one.keys() == other.keys()
            for k in one:
                np.testing.assert_array_equal(one[k], other[k], err_msg=f"{name} s{seed} {k}")
    assert not list((tmp_path / "ray").glob(".minid3rqn-executor-*"))   # markers removed
    assert json.loads((tmp_path / "ray" / "results.json").read_text())["seeds"] == [0, 1]


def test_a_folder_the_ray_workers_cannot_see_is_refused(on_ray, tmp_path, monkeypatch):
    monkeypatch.setattr(RayExecutor, "_markers",
                        staticmethod(lambda folders: [str(tmp_path / "elsewhere" / "marker")]))
    with pytest.raises(UsageError, match=r"--executor ray: .*elsewhere' is not on storage "
                                         r"shared with .*; put the run folders on a file "
                                         r"system every node mounts at the same path"):
        on_ray.run(_where, [0], check_folders=[tmp_path])


def test_a_task_lost_with_its_ray_worker_runs_again(on_ray, tmp_path, killed_once):
    assert on_ray.run(killed_once, range(3), str(tmp_path)) == [0, 10, 20]
    assert (tmp_path / "ran1").exists()
