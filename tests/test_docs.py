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
