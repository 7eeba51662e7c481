"""The command line: every command's --help works and lists what it does."""
import subprocess
import sys

import pytest

from minid3rqn.cli import COMMANDS, main


def test_top_level_help_lists_every_command(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([name, "--help"])
    assert exit_info.value.code == 0
    assert "usage" in capsys.readouterr().out


def test_python_dash_m_runs():
    done = subprocess.run([sys.executable, "-m", "minid3rqn", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0 and "train-agent" in done.stdout
