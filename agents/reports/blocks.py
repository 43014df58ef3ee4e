"""The generated blocks' file I/O: where a block lives (README.md or docs/*.md, between ``<!-- name:start -->`` and
``<!-- name:end -->``), its text, and writing it. The reports write their blocks through this module; the renderers
and the regenerating command are :mod:`agents.reports.readme_blocks`, which imports the reports (so the reports do
not import it)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def pages():
    """The Markdown pages that may hold generated blocks: README.md and every docs/*.md."""
    return [README] + sorted((ROOT / "docs").glob("*.md"))


def _markers(name):
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def block_names(path=None):
    """Names of every generated block in ``path`` (default: all :func:`pages`), in order."""
    return [n for p in ([path] if path is not None else pages())
            for n in re.findall(r"<!-- ([\w-]+):start -->", Path(p).read_text())]


def block_file(name):
    """The page holding block ``name``; ``ValueError`` if no page or more than one holds it."""
    start, end = _markers(name)
    hits = [p for p in pages() if start in (s := p.read_text()) and end in s]
    if len(hits) != 1:
        raise ValueError(f"block {name!r}: expected in exactly one of README.md, docs/*.md; found in "
                         f"{[str(p.relative_to(ROOT)) for p in hits] or 'none'} ({start} ... {end})")
    return hits[0]


def read_block(name, path=None):
    """The text between the markers of block ``name`` (stripped), in ``path`` (default: the page holding it);
    ``ValueError`` if the markers are missing."""
    path = block_file(name) if path is None else Path(path)
    s = path.read_text()
    start, end = _markers(name)
    if start not in s or end not in s:
        raise ValueError(f"{path} has no {start} ... {end} block")
    return s[s.index(start) + len(start):s.index(end)].strip()


def replace_block(name, text, path=None):
    """Put ``text`` between the markers of block ``name`` in ``path`` (default: the page holding it); ``ValueError``
    if the markers are missing."""
    path = block_file(name) if path is None else Path(path)
    s = path.read_text()
    start, end = _markers(name)
    if start not in s or end not in s:
        raise ValueError(f"{path} has no {start} ... {end} block")
    a, b = s.index(start) + len(start), s.index(end)
    path.write_text(s[:a] + "\n" + text.strip() + "\n" + s[b:])


def check_report_options(args, suites=None):
    """A report's command-line options checked before any work, each refusal one ``SystemExit`` line naming the
    option: ``--docs`` an existing folder, ``--seed`` >= 0, ``--family-runs`` >= 1, ``--suites`` among ``suites``
    (the attributes a report has)."""
    docs = getattr(args, "docs", None)
    if docs is not None and not Path(docs).is_dir():
        raise SystemExit(f"error: --docs: {str(docs)!r} is not an existing folder (the report writes its JSON, "
                         "pages and figures there)")
    if getattr(args, "seed", 0) < 0:
        raise SystemExit(f"error: --seed: must be an integer >= 0, got {args.seed}")
    if getattr(args, "family_runs", 1) < 1:
        raise SystemExit(f"error: --family-runs: must be an integer >= 1, got {args.family_runs}")
    if suites is not None and getattr(args, "suites", None) is not None:
        names = [s.strip() for s in args.suites.split(",") if s.strip()]
        bad = [s for s in names if s not in suites]
        if bad or not names:
            raise SystemExit(f"error: --suites: {bad or args.suites!r} not among {list(suites)}")


if __name__ == "__main__":
    raise SystemExit("error: agents.reports.blocks is the generated blocks' file I/O; run: python -m "
                     "agents.reports.readme_blocks")
