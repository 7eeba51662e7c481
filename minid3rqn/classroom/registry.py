"""The eight exercises: name, template file, checker, and where the instructions are."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from . import checks


@dataclass(frozen=True)
class Exercise:
    number: int
    name: str            # what the student types: python -m minid3rqn check <name>
    title: str
    filename: str        # the template in exercises/, the solution in docs/solutions/
    checker: Callable
    doc: str             # instructions, in docs/exercises/
    trains: str          # "agent", "depth" or "" (nothing to run beyond the check)


EXERCISES = {e.name: e for e in [
    Exercise(1, "reward", "Reward: penalise turning, or clip/scale d_nearest", "reward.py",
             checks.check_reward, "docs/exercises/01_reward.md", "agent"),
    Exercise(2, "actions", "Actions: a sharper turn or a second speed", "actions.py",
             checks.check_actions, "docs/exercises/02_actions.md", "agent"),
    Exercise(3, "fov", "Field of view: narrow the camera, D3RQN vs D3QN", "camera.py",
             checks.check_fov, "docs/exercises/03_field_of_view.md", "agent"),
    Exercise(4, "memory", "Memory: sequence length 1 vs 5 vs 10", "memory.py",
             checks.check_memory, "docs/exercises/04_memory.md", "agent"),
    Exercise(5, "ablation", "Ablations: remove dueling, remove double-Q", "ablation.py",
             checks.check_ablation, "docs/exercises/05_ablations.md", "agent"),
    Exercise(6, "op", "Autograd: a new op (leaky ReLU) with its backward", "my_op.py",
             checks.check_op, "docs/exercises/06_autograd_op.md", ""),
    Exercise(7, "depth-loss", "Depth: photometric loss L1 vs SSIM + L1", "photometric.py",
             checks.check_photometric, "docs/exercises/07_depth_loss.md", "depth"),
    Exercise(8, "depth-errors", "Depth errors: corrupt the GT depth seen in training",
             "depth_errors.py", checks.check_depth_errors, "docs/exercises/08_depth_errors.md",
             "agent"),
]}


def find(name_or_number: str) -> Exercise:
    """'reward', '1', 'depth_loss' ... -> the Exercise; ValueError listing them otherwise."""
    key = str(name_or_number).strip().lower().replace("_", "-")
    for e in EXERCISES.values():
        if key in (e.name, str(e.number), f"{e.number:02d}", e.filename[:-3].replace("_", "-")):
            return e
    names = ", ".join(f"{e.number}={e.name}" for e in EXERCISES.values())
    raise ValueError(f"unknown exercise {name_or_number!r}; choose one of: {names}")
