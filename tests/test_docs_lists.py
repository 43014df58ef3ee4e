"""The hand-written descriptions in the docs cover what the code has, no more and no less: a row of
docs/trackers.md per built-in tracker, a bullet of docs/evaluation.md's "The figures" per figure kind (the names and
counts themselves are generated blocks, tests/test_readme_blocks.py)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_trackers_md_has_a_row_per_built_in_tracker():
    from baselines.registry import tracker_names
    rows = [line.split("|")[1] for line in (ROOT / "docs" / "trackers.md").read_text().splitlines()
            if line.startswith("| `")]
    documented = set(re.findall(r"`([\w-]+)`", " ".join(rows)))
    names = set(tracker_names())
    assert not names - documented, f"built-in trackers without a row in docs/trackers.md: {sorted(names - documented)}"
    assert not documented - names, f"rows of docs/trackers.md that name no built-in tracker: {sorted(documented - names)}"


def test_evaluation_md_describes_every_figure_kind():
    from agents.evaluation.plots import FIGURE_KINDS
    s = (ROOT / "docs" / "evaluation.md").read_text()
    section = s[s.index("### The figures"):]
    section = section[:section.index("\n#")] if "\n#" in section else section
    bullets = set(re.findall(r"^\* `<suite>_(\w+)\.png`", section, flags=re.M))
    assert bullets == set(FIGURE_KINDS), (
        f"docs/evaluation.md 'The figures': bullets {sorted(bullets)}, agents.evaluation.plots.FIGURE_KINDS "
        f"{sorted(FIGURE_KINDS)}")
