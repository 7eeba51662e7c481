"""Every example runs in smoke mode (``--smoke``), in a fresh process and a scratch folder.

The numbered examples of the learning path (docs/README.md) are expected; one
that does not exist yet is skipped with a note, and any other examples/*.py is run too.
"""
import importlib.util
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.examples

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
EXPECTED = ["01_autograd_tour.py", "02_world_and_camera.py", "03_train_depth.py",
            "04_train_d3rqn.py", "05_evaluate.py", "06_wall_ahead.py",
            "07_which_depth_errors_matter.py", "08_where_flights_crash.py",
            "09_plane_sweep.py", "10_sb3_dqn.py"]
SMOKE_SECONDS = 30        # each smoke run should take less than this on a laptop
TIMEOUT = 180             # generous hard limit: the test machine may be shared


def _all_examples():
    found = sorted(p.name for p in EXAMPLES.glob("*.py")) if EXAMPLES.is_dir() else []
    return sorted(set(EXPECTED) | set(found))


@pytest.mark.parametrize("name", _all_examples())
def test_example_smoke(name, tmp_path):
    path = EXAMPLES / name
    if not path.is_file():
        pytest.skip(f"examples/{name} does not exist yet")
    env = dict(os.environ, OMP_NUM_THREADS="1", MPLBACKEND="Agg", PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    t0 = time.time()
    proc = subprocess.run([sys.executable, str(path), "--smoke"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT)
    seconds = time.time() - t0
    assert proc.returncode == 0, (f"examples/{name} --smoke failed (exit {proc.returncode})\n"
                                  f"--- stdout ---\n{proc.stdout[-3000:]}\n"
                                  f"--- stderr ---\n{proc.stderr[-3000:]}")
    if seconds > SMOKE_SECONDS:
        warnings.warn(f"examples/{name} --smoke took {seconds:.0f} s (> {SMOKE_SECONDS} s)")


# the examples written as notebooks in the cell format (# %% code, # %% [markdown] prose)
IN_CELLS = _all_examples()


def cells(text: str) -> list[tuple[str, list[str]]]:
    """(kind, lines) of each cell of a file in the percent format: "markdown" or "code"."""
    out = []
    for line in text.split("\n"):
        if line.startswith("# %%"):
            out.append(("markdown" if "[markdown]" in line else "code", []))
        elif out:
            out[-1][1].append(line)
    return out


@pytest.mark.parametrize("name", IN_CELLS)
def test_example_is_a_notebook_in_cells(name):
    """Jupyter (jupytext), VS Code and PyCharm open the file as a notebook: it starts with
    a markdown cell (the prose, as comment lines), its code is in code cells, and nothing
    in it needs to be run as a script (no ``__file__``; a kernel's own command-line
    arguments are not parsed as the example's)."""
    text = (EXAMPLES / name).read_text(encoding="utf-8")
    assert text.startswith("# %% [markdown]\n# # "), f"{name}: no markdown title cell first"
    found = cells(text)
    assert sum(kind == "code" for kind, _ in found) >= 2, name
    for kind, lines in found:
        if kind == "markdown":
            assert all(not line or line.startswith("#") for line in lines), name
    assert "__file__" not in text, f"{name}: __file__ is not defined in a notebook"
    if ".parse_args(" in text:
        assert '"ipykernel" in sys.modules' in text, f"{name}: a notebook's argv is parsed"
    compile(text, name, "exec")


def load_example(name: str):
    """An example script as a module (its main() is not run)."""
    spec = importlib.util.spec_from_file_location(f"example_{name[:2]}", EXAMPLES / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_warp_picture_tells_the_truth(tmp_path):
    """Example 03's first picture: warped with the true depth and motion, the previous
    frame matches the target better than unwarped or warped with half the depth."""
    example = load_example("03_train_depth.py")
    rows = example.warp_rows(seed=0, height=32, width=104)
    err = {name: float(np.mean(e[valid])) for name, _, _, e, valid in rows}
    true, none, wrong = err["true depth, true motion"], err["no warp"], err["depth x 0.5"]
    assert true < 0.5 * none and true < wrong, err
    assert example.warp_picture(tmp_path / "warp.png").is_file()
