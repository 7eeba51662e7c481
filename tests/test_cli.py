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


def visible_options(name: str) -> list[str]:
    """The options a command's --help shows (-h and positional arguments left out)."""
    from minid3rqn.cli import build_parser
    parser = build_parser(only=name)
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    return [a.option_strings[0] for a in sub._actions
            if a.option_strings and a.option_strings[0] not in ("-h", "--help")]


@pytest.mark.parametrize("names, most", [(("train-agent",), 20), (("distil",), 10),
                                         (("evaluate",), 13), (("fly",), 8),
                                         (("reproduce",), 8), (("pool",), 4),
                                         (("check", "exercise"), 6)])
def test_each_command_keeps_to_its_option_budget(names, most):
    got = [o for name in names for o in visible_options(name)]
    assert len(got) <= most, got


def test_the_paper_and_the_budget_come_first_in_train_agent_help(capsys):
    with pytest.raises(SystemExit):
        main(["train-agent", "--help"])
    out = capsys.readouterr().out
    groups = [out.index(title) for title in ("the paper's settings:", "budget (scaled",
                                             "the run:", "other settings:")]
    assert groups == sorted(groups) and "--batch-size" in out and "--gamma" in out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_option_has_help(name):
    from minid3rqn.cli import build_parser
    parser = build_parser(only=name)
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    silent = [a.option_strings or a.dest for a in sub._actions if not (a.help or "").strip()]
    assert not silent, f"{name}: options without help text: {silent}"


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning",
                            "ignore:invalid value encountered:RuntimeWarning")
def test_a_diverging_training_ends_in_one_line(tmp_path, capsys):
    """A learning rate far too large: the gradients become NaN; the command says so in one
    line (exit status 1), with no traceback and no model written."""
    code = main(["train-agent", "--smoke", "--lr", "1e11", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "the training diverged" in err.strip().splitlines()[-1]
    assert not (tmp_path / "run" / "model.npz").exists()


def test_a_recorded_command_gives_back_its_settings():
    """What a model file records (``command_for``) parses back to the same settings, an
    action table (rows joined by ';') and a folder with a space in its name included."""
    import shlex

    from minid3rqn.cli import build_parser
    from minid3rqn.config import from_args
    from minid3rqn.rl.models import command_for
    from minid3rqn.rl.train import TrainConfig
    cfg = TrainConfig(actions=[[2, -0.5], [2, 0], [2, 0.5]], hfov_deg=60.0, steps=500)
    words = shlex.split(command_for(cfg, "my runs/seven"))
    assert words[:3] == ["python", "-m", "minid3rqn"] and words[-1] == "my runs/seven"
    args = build_parser("train-agent").parse_args(words[3:])
    assert from_args(TrainConfig, args) == cfg
