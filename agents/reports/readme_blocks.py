"""Replace generated blocks in README.md between ``<!-- name:start -->`` and ``<!-- name:end -->`` markers."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def _markers(name):
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def block_names(path=README):
    """Names of every generated block in ``path``, in order."""
    return re.findall(r"<!-- ([\w-]+):start -->", Path(path).read_text())


def read_block(name, path=README):
    """The text between the markers of block ``name`` (stripped); ``ValueError`` if the markers are missing."""
    path = Path(path)
    s = path.read_text()
    start, end = _markers(name)
    if start not in s or end not in s:
        raise ValueError(f"{path} has no {start} ... {end} block")
    return s[s.index(start) + len(start):s.index(end)].strip()


def replace_block(name, text, path=README):
    """Put ``text`` between the markers of block ``name``; ``ValueError`` if the markers are missing."""
    path = Path(path)
    s = path.read_text()
    start, end = _markers(name)
    if start not in s or end not in s:
        raise ValueError(f"{path} has no {start} ... {end} block")
    a, b = s.index(start) + len(start), s.index(end)
    path.write_text(s[:a] + "\n" + text.strip() + "\n" + s[b:])
