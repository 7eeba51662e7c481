"""What several test files share: a task that kills the process running it once."""
import os
import signal
from pathlib import Path

import pytest


def _killed_once(folder, task):
    """Task 1 kills the worker running it (SIGKILL) the first time it runs, leaving the
    file ``ran1`` in ``folder``; every task returns task * 10."""
    mark = Path(folder) / f"ran{task}"
    if task == 1 and not mark.exists():
        mark.write_text("once")
        os.kill(os.getpid(), signal.SIGKILL)
    return task * 10


@pytest.fixture
def killed_once():
    """For an executor's ``run(killed_once, tasks, folder)``: task 1 loses its worker once."""
    return _killed_once
