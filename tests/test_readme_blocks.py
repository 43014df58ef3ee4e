"""The generated blocks of README.md and docs/*.md equal what their renderers give from the committed JSON and the
code alone, so the text and the numbers cannot drift apart, and the paragraph above each block names the command
that makes it.

The renderers and commands are :data:`agents.reports.readme_blocks.RENDERERS` and ``COMMANDS``: the results'
blocks from ``docs/results.json`` and ``docs/bounds.json`` (``agents.reports.report``'s ``headline``,
``scores_table``, ``downstream_tables``, ``per_flight_table``) and ``docs/generalisation.json``
(``agents.reports.generalisation``'s tables), the evaluation's defaults (trackers, suites and their runs, figures per
suite, the first line it prints) from ``agents.evaluation``. ``python -m agents.reports.readme_blocks`` rewrites
every block.
"""

import pytest

from agents.reports.blocks import block_file, block_names, read_block, replace_block
from agents.reports.readme_blocks import COMMANDS, RENDERERS, main


def test_every_generated_block_has_a_renderer_and_a_command():
    names = block_names()      # README.md and every docs/*.md
    assert len(names) == len(set(names)), f"duplicate blocks: {names}"
    assert set(names) == set(RENDERERS) == set(COMMANDS)


@pytest.mark.parametrize("name", sorted(RENDERERS))
def test_generated_block_equals_renderer_output(name):
    assert read_block(name) == RENDERERS[name]().strip(), (
        f"block {name!r} ({block_file(name).name}) differs from its renderer's output on the committed JSON and "
        f"code; regenerate it: python -m agents.reports.readme_blocks")


def _paragraph_above(name):
    """The paragraph right above block ``name``'s start marker (blank lines between them skipped): its lines up to
    the blank line or block end before it."""
    s = block_file(name).read_text()
    lines = s[:s.index(f"<!-- {name}:start -->")].rstrip().split("\n")
    out = []
    for line in reversed(lines):
        if not line.strip() or line.strip().endswith(":end -->"):
            break
        out.append(line)
    return " ".join(reversed(out))


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_block_names_its_command(name):
    assert f"`{COMMANDS[name]}`" in _paragraph_above(name) + read_block(name), (
        f"block {name!r} ({block_file(name).name}): the paragraph above it does not name `{COMMANDS[name]}`")


def test_check_lists_nothing_on_the_committed_pages(capsys):
    main(["--check", "evaluation-defaults", "evaluation-first-line"])
    assert capsys.readouterr().out.startswith("0 of 2 block(s) differ")
    with pytest.raises(SystemExit, match="no renderer"):
        main(["--check", "no-such-block"])


def test_read_and_replace_block_round_trip(tmp_path):
    p = tmp_path / "R.md"
    p.write_text("a\n<!-- x:start -->\nold\n<!-- x:end -->\nb\n")
    replace_block("x", "  new text\n", p)
    assert read_block("x", p) == "new text"
    assert p.read_text() == "a\n<!-- x:start -->\nnew text\n<!-- x:end -->\nb\n"
    assert block_names(p) == ["x"]
    with pytest.raises(ValueError, match="y:start"):
        read_block("y", p)
    with pytest.raises(ValueError, match="y:start"):
        replace_block("y", "t", p)
