"""Writing the commands' output files without harm to anything else: never over an input, never through a link.

* :func:`check_output_file`: an output path (``--json``) that is a symbolic link, or that is one of the run's input
  files (a trajectory CSV, the policy, a tracker module), is refused before anything runs;
* :func:`write_text_replacing` / :func:`move_replacing`: the file is written beside its destination and renamed
  onto it (``os.replace``): a link found at the destination is replaced by the file, never followed, so nothing
  outside the output folder is written, and a reader never sees a half-written file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["check_output_file", "same_file", "write_text_replacing", "move_replacing"]


def same_file(a, b):
    """Whether paths ``a`` and ``b`` name the same existing file (any spelling, hard or symbolic links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output_file(option, path, inputs=()):
    """``ValueError`` (naming ``option``) if ``path`` is a symbolic link or the same file as one of ``inputs``."""
    p = Path(path)
    if p.is_symlink():
        raise ValueError(f"{option}: {str(path)!r} is a symbolic link; give a plain file path (outputs are never "
                         "written through links)")
    for f in inputs:
        if f is not None and same_file(p, f):
            raise ValueError(f"{option}: {str(path)!r} is an input of this run ({f}); give another file")


def _umask_mode():
    mask = os.umask(0o22)
    os.umask(mask)
    return 0o666 & ~mask


def write_text_replacing(path, text):
    """Write ``text`` to ``path`` by a temporary file in the same folder renamed onto it (a link at ``path`` is
    replaced, not followed); the file gets the permissions a plain ``open(path, "w")`` would give."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, _umask_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def move_replacing(src, dest):
    """Rename ``src`` onto ``dest`` (same file system): a link at ``dest`` is replaced, not followed."""
    os.chmod(src, _umask_mode())
    os.replace(src, dest)
