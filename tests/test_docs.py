"""The documentation's links: every relative link in README.md and docs/ points at a file
that exists, and every ``#anchor`` at a heading of that file (as GitHub renders it).

The method pages, docs/results.md and docs/beyond.md cite each other's sections by
link; when a section is renamed or moved, this test names the link that broke.
"""
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.docs

ROOT = Path(__file__).resolve().parent.parent
LINK = re.compile(r"\[([^\]]*)\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~)")


def markdown_files():
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def prose(text: str) -> str:
    """The text outside fenced and indented code blocks (links there are not links)."""
    keep, fenced = [], False
    for line in text.split("\n"):
        if FENCE.match(line.strip()):
            fenced = not fenced
            continue
        if not fenced and not line.startswith("    "):
            keep.append(line)
    return "\n".join(keep)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped (letters, digits,
    spaces, hyphens and underscores kept), spaces turned into hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)    # a link keeps its text
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set:
    """Every heading's anchor in a Markdown file; repeated headings get -1, -2, ..."""
    seen, out = {}, set()
    for line in prose(path.read_text(encoding="utf-8")).split("\n"):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        base = slug(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def test_slug_follows_github():
    assert slug("10. Ensembles and the mirror image (ours)") \
        == "10-ensembles-and-the-mirror-image-ours"
    assert slug("Tables 5 and 6: the paper's, on `basic` (ours)") \
        == "tables-5-and-6-the-papers-on-basic-ours"
    assert slug("What the transfer worlds ask: pillars beside walls, and a denser `basic`") \
        == "what-the-transfer-worlds-ask-pillars-beside-walls-and-a-denser-basic"
    assert slug("Better depth at 2-4 m? Frames") == "better-depth-at-2-4-m-frames"


def test_anchors_number_repeated_headings(tmp_path):
    md = tmp_path / "a.md"
    md.write_text("# Notes\n\n## Notes\n\n    # not a heading (code)\n\n## Other one\n")
    assert anchors(md) == {"notes", "notes-1", "other-one"}


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    broken = []
    for text, target in LINK.findall(prose(path.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z]+:", target):          # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            broken.append(f"[{text}]({target}): no file {dest.relative_to(ROOT)}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"[{text}]({target}): no heading with anchor #{anchor} in "
                          f"{dest.relative_to(ROOT)}")
    assert not broken, f"{path.relative_to(ROOT)}: broken links:\n" + "\n".join(broken)


CELL = re.compile(r"([01]\.\d+) \[([01]\.\d+), ([01]\.\d+)\]")
SCENARIOS = ("basic", "channel", "intersections", "corners")


def test_readme_results_are_the_recorded_test_world_evaluations():
    """Each figure of the README's results table is an evaluation on the test worlds
    recorded in the JSON beside its shipped model (rate and interval by world)."""
    import json
    rows = [line for line in (ROOT / "README.md").read_text().split("\n")
            if line.startswith("| ") and len(CELL.findall(line)) > 0]
    assert rows, "no model rows in the README's results table"
    model = None
    for row in rows:
        names = re.findall(r"(d3rqn_\w+)\.npz", row)
        model = names[0] if names else model      # "the same + ..." rows: the row above's
        mirror = "--mirror" in row
        record = json.loads((ROOT / "minid3rqn" / "models" / f"{model}.json").read_text())
        cells = CELL.findall(row)
        assert len(cells) == len(SCENARIOS), row
        for scenario, (rate, lo, hi) in zip(SCENARIOS, cells):
            found = [e for e in record["evaluations"]
                     if e.get("worlds_set") == "test" and e["scenario"] == scenario
                     and e["depth"] == "pred" and bool(e.get("mirror")) == mirror
                     and not e.get("flip_tta") and e["flights"] >= 2000]
            assert found, (model, scenario, mirror)
            e = found[0]
            assert float(rate) == e["rate"], (model, scenario, rate, e["rate"])
            assert [float(lo), float(hi)] == [round(v, 3) for v in e["ci95_by_world"]], \
                (model, scenario, lo, hi, e["ci95_by_world"])


# -- settings and defaults quoted in the docs --------------------------------------------
COMMAND = re.compile(r"(?:minid3rqn\s+|`)(train-agent|distil|train-depth|collect|evaluate|fly|"
                     r"reproduce)\b")
SPAN = re.compile(r"`([^`\n]+)`")
SET = re.compile(r"--set\s+'?(\w+)=([^'\s`]*)")
PLACEHOLDER = re.compile(r"[A-Z]")           # --set hidden=H: a name, not a value


def command_configs() -> dict:
    """Each command that takes --set -> the config classes its options come from."""
    from minid3rqn.depth.data import CollectConfig
    from minid3rqn.depth.train import TrainConfig as DepthTrainConfig
    from minid3rqn.rl.distill import DistilConfig
    from minid3rqn.rl.evaluate import EvalConfig
    from minid3rqn.rl.fly import FlyConfig
    from minid3rqn.rl.reproduce import ReproduceConfig
    from minid3rqn.rl.train import TrainConfig as AgentTrainConfig
    return {"train-agent": [AgentTrainConfig], "distil": [DistilConfig],
            "train-depth": [DepthTrainConfig, CollectConfig], "collect": [CollectConfig],
            "evaluate": [EvalConfig], "fly": [FlyConfig], "reproduce": [ReproduceConfig]}


def named_configs() -> dict:
    """``XConfig`` as the docs name it -> its class (two TrainConfigs: by their folder)."""
    from minid3rqn.depth.losses import LossConfig
    from minid3rqn.nets.qnet import QNetConfig
    from minid3rqn.rl.agent import AgentConfig
    by_command = command_configs()
    return {"AgentConfig": AgentConfig, "QNetConfig": QNetConfig, "LossConfig": LossConfig,
            "DistilConfig": by_command["distil"][0],
            "CollectConfig": by_command["collect"][0]}


def leaf_default(cls, name):
    """(found, default) of setting ``name`` of config ``cls`` (nested configs searched)."""
    from dataclasses import fields, is_dataclass
    obj = cls()
    for f in fields(cls):
        value = getattr(obj, f.name)
        if f.name == name:
            return True, value
        if is_dataclass(value):
            found, inner = leaf_default(type(value), name)
            if found:
                return True, inner
    return False, None


def where(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def the_command(text: str, at: int) -> str | None:
    """The command a setting quoted at ``at`` belongs to: the last one named before it in
    its paragraph (or code block), else None."""
    start = text.rfind("\n\n", 0, at) + 1
    found = COMMAND.findall(text[start:at])
    return found[-1] if found else None


def configs_for(name: str, command: str | None) -> list:
    """The config classes a setting can belong to: the command's, else every command's
    that has it."""
    table = command_configs()
    pool = table[command] if command else [c for cs in table.values() for c in cs]
    return [c for c in dict.fromkeys(pool) if leaf_default(c, name)[0]]


def quoted_settings(paths=None):
    """(file, line, command, name, value) of every ``--set NAME=VALUE`` in README and docs."""
    for path in paths or markdown_files():
        text = path.read_text(encoding="utf-8")
        for m in SET.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            yield (where(path), line, the_command(text, m.start()),
                   m.group(1), m.group(2))


def test_every_quoted_set_names_a_setting_and_a_valid_value():
    """``--set NAME=VALUE`` in the docs: NAME is a setting of the command's config (of
    some command's, where the paragraph names none) and VALUE one it accepts."""
    from minid3rqn.config import ConfigError, UsageError, _check_type, _leaves, _parse_text
    quoted, wrong = list(quoted_settings()), []
    assert len(quoted) > 30, "the docs quote fewer --set options than expected"
    for where, line, command, name, value in quoted:
        classes = configs_for(name, command)
        if not classes:
            wrong.append(f"{where}:{line}: --set {name}: no such setting of "
                         f"{command or 'any command'}")
            continue
        if PLACEHOLDER.fullmatch(value) or not value:
            continue
        for cls in classes:         # the value on its own: its type, choices and check
            _, f, hint = next(leaf for leaf in _leaves(cls) if leaf[0][-1] == name)
            try:
                v = _check_type(name, _parse_text(name, value, hint, f"--set {name}"), hint)
                problem = v is not None and f.metadata.get("check") and f.metadata["check"](v)
                choices = f.metadata.get("choices")
                if problem or (choices is not None and v not in choices):
                    raise ConfigError(name, v, problem or f"one of {choices}")
            except (UsageError, ConfigError) as e:
                wrong.append(f"{where}:{line}: --set {name}={value} ({cls.__name__}): {e}")
    assert not wrong, "\n".join(wrong)


NUMBER = r"[-+]?\d(?:[\d,]*\d)?(?:\.\d+)?(?:e-?\d+)?k?"
DEFAULT_AFTER = [re.compile(rf"^\s*\(({NUMBER})\)"),                 # `gamma` (0.99)
                 re.compile(rf"^[^.`]{{0,30}}?\b({NUMBER}|on|off) by default")]
DEFAULT_BEFORE = re.compile(rf"\b({NUMBER})(?: [a-z]+){{0,3}} \($")   # 128 (`QNetConfig.width`)


def as_number(text: str) -> float:
    text = text.replace(",", "")
    return float(text[:-1]) * 1000 if text.endswith("k") else float(text)


def quoted_defaults(paths=None):
    """(file, line, [classes], name, quoted) for every default the docs quote after a
    setting in code: "`AgentConfig.gamma` (0.99)", "`--set eval_every=N` iterations (500
    by default)", "(`init_disp`, 0.1 by default)"; also "W = 1" after "--set NAME=W"."""
    configs, names = named_configs(), set()
    for classes in command_configs().values():
        for cls in classes:
            names |= {n for n in cls.__dataclass_fields__} | \
                {n for c in [cls] for n in _all_names(c)}
    for path in paths or markdown_files():
        text = path.read_text(encoding="utf-8")
        for m in SPAN.finditer(text):
            span, after = m.group(1), text[m.end():m.end() + 80].replace("\n", " ")
            before = text[max(0, m.start() - 40):m.start()].replace("\n", " ")
            line = text.count("\n", 0, m.start()) + 1
            command = COMMAND.findall("`" + span) or [the_command(text, m.start())]
            sets = SET.findall(span)
            cfg = re.search(r"\b(\w+Config)\.(\w+)$", span)
            if cfg and cfg.group(1) in configs:
                targets = [([configs[cfg.group(1)]], cfg.group(2), None)]
            elif sets:
                targets = [(configs_for(n, command[-1]), n, v) for n, v in sets]
            elif re.fullmatch(r"[a-z_]+", span) and span in names:
                targets = [(configs_for(span, command[-1]), span, None)]
            else:
                continue
            for classes, name, placeholder in targets:
                if placeholder and PLACEHOLDER.fullmatch(placeholder):
                    said = re.search(rf"\b{placeholder} = ({NUMBER})", after)
                    if said:
                        yield where(path), line, classes, name, said.group(1)
                        continue
                if len(targets) > 1:
                    continue
                for pattern, near in [(p, after) for p in DEFAULT_AFTER] + \
                        [(DEFAULT_BEFORE, before)]:
                    said = pattern.search(near)
                    if said:
                        yield where(path), line, classes, name, said.group(1)
                        break


def _all_names(cls):
    from minid3rqn.config import setting_names
    return setting_names(cls)


def test_every_quoted_default_is_the_configs():
    """A default the docs quote next to a setting is that setting's default in the config
    it belongs to."""
    found = list(quoted_defaults())
    assert len(found) >= 8, f"expected the docs to quote defaults; found {found}"
    wrong = wrong_defaults(found)
    assert not wrong, "\n".join(wrong)


def wrong_defaults(found) -> list[str]:
    wrong = []
    for where, line, classes, name, quoted in found:
        if not classes:
            wrong.append(f"{where}:{line}: `{name}` is no setting of the command named there")
        for cls in classes:
            _, default = leaf_default(cls, name)
            ok = (bool(default) == (quoted == "on")) if quoted in ("on", "off") else \
                default is not None and not isinstance(default, (list, str)) and \
                abs(float(default) - as_number(quoted)) <= 1e-9 * max(1.0, abs(float(default)))
            if not ok:
                wrong.append(f"{where}:{line}: `{name}` quoted as {quoted}; "
                             f"{cls.__name__}'s default is {default!r}")
    return wrong


def test_a_wrong_quote_is_caught(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("Every `--set eval_every=N` iterations (400 by default) it scores.\n\n"
                    "The discount (`AgentConfig.gamma` (0.9)) and `train-depth --set "
                    "no_such=1`.\n")
    found = list(quoted_defaults([page]))
    assert [(f[3], f[4]) for f in found] == [("eval_every", "400"), ("gamma", "0.9")]
    assert len(wrong_defaults(found)) == 2
    assert [q[2:] for q in quoted_settings([page])] == [(None, "eval_every", "N"),
                                                       ("train-depth", "no_such", "1")]
    assert configs_for("no_such", "train-depth") == []


# -- reading times -----------------------------------------------------------------------
WORDS_PER_MINUTE = 120     # docs/README.md: half the 238 of silent reading of non-fiction


def words(path: Path) -> int:
    """Words of a page: its whitespace-separated tokens, code and tables included."""
    return len(path.read_text(encoding="utf-8").split())


def reading_minutes(paths) -> float:
    return sum(words(p) for p in paths) / WORDS_PER_MINUTE


def announced_reading_times():
    """(step, [pages], minutes announced) for each row of the learning path's table that
    announces "N min read" for the pages its "read" column links."""
    guide = ROOT / "docs" / "README.md"
    for line in guide.read_text(encoding="utf-8").split("\n"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        said = re.search(r"(\d+) min read", line)
        if len(cells) < 4 or not said:
            continue
        pages = [(guide.parent / t.partition("#")[0]).resolve()
                 for _, t in LINK.findall(cells[1]) if t.partition("#")[0].endswith(".md")]
        yield cells[0], list(dict.fromkeys(pages)), int(said.group(1))


def test_reading_times_are_the_word_counts_at_the_stated_pace():
    """The learning path's "N min read" are the linked pages' words at the pace the page
    states (within 15%, or 2 min, so that an edit of a few lines needs no new figure)."""
    guide = (ROOT / "docs" / "README.md").read_text(encoding="utf-8")
    assert f"{WORDS_PER_MINUTE} words a minute" in guide
    rows, wrong = list(announced_reading_times()), []
    assert len(rows) >= 5, rows
    for step, pages, minutes in rows:
        measured = reading_minutes(pages)
        if abs(minutes - measured) > max(2.0, 0.15 * measured):
            wrong.append(f"{step}: announces {minutes} min read; "
                         f"{', '.join(p.name for p in pages)} hold "
                         f"{sum(words(p) for p in pages)} words = {measured:.0f} min")
    assert not wrong, "\n".join(wrong)


def test_each_exercise_sheet_names_its_budget_and_time():
    """Each sheet has a **Budget.** paragraph: the budget it is run at and how long a run
    takes there; the times of the budgets it quotes are the ones the runner prints."""
    from minid3rqn.classroom.checks import EXERCISES
    from minid3rqn.classroom.runner import AGENT_BUDGETS, DEPTH_BUDGETS
    wrong = []
    for ex in EXERCISES.values():
        text = (ROOT / ex.doc).read_text(encoding="utf-8")
        said = re.search(r"\*\*Budget\.\*\*(.*?)\n\n", text, re.S)
        if not said:
            wrong.append(f"{ex.doc}: no **Budget.** paragraph")
            continue
        budget = " ".join(said.group(1).split())
        if not ex.trains:
            continue
        budgets = AGENT_BUDGETS if ex.trains == "agent" else DEPTH_BUDGETS
        first = re.match(r"\s*`small`[^:]*: about ([\d.]+) min", budget)
        if not first:
            wrong.append(f"{ex.doc}: the budget paragraph does not start with `small`'s time")
        elif ex.name != "depth-errors" and float(first.group(1)) != budgets["small"]["minutes"]:
            wrong.append(f"{ex.doc}: `small` about {first.group(1)} min; the runner says "
                         f"{budgets['small']['minutes']}")
        for name, minutes in re.findall(r"`--budget (\w+)` \([^)]*about ([\d.]+) min", budget):
            if float(minutes) != budgets[name]["minutes"]:
                wrong.append(f"{ex.doc}: `{name}` about {minutes} min; the runner says "
                             f"{budgets[name]['minutes']}")
    assert not wrong, "\n".join(wrong)
