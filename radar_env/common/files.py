"""Writing the commands' output files without harm to anything else: never over an input, never through a link.

* :func:`check_output_file`: an output path (``--json``) that exists and is not a regular file (a symbolic link, a
  device, a FIFO, a socket, a folder), or that is one of the run's input files (a trajectory CSV, the policy, a
  tracker module), is refused before anything runs; :func:`check_output_dir` likewise for an output folder
  (``--out``): an existing one must be a real directory, not a link or anything else;
* :func:`write_text_replacing` / :func:`move_replacing`: the file is written beside its destination and renamed
  onto it (``os.replace``): a link found at the destination is replaced by the file, never followed, so nothing
  outside the output folder is written, and a reader never sees a half-written file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["check_output_file", "check_output_dir", "file_type", "same_file", "write_text_replacing",
           "move_replacing"]


def file_type(path):
    """What exists at ``path`` (not following a link): None (nothing), ``"file"``, ``"directory"``,
    ``"symbolic link"``, ``"character device"``, ``"block device"``, ``"FIFO"``, ``"socket"``."""
    import stat
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError:
        return "unreadable path"
    for test, name in ((stat.S_ISREG, "file"), (stat.S_ISDIR, "directory"), (stat.S_ISLNK, "symbolic link"),
                       (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"), (stat.S_ISFIFO, "FIFO"),
                       (stat.S_ISSOCK, "socket")):
        if test(mode):
            return name
    return "special file"


def check_output_dir(option, path):
    """``ValueError`` (naming ``option``) if ``path`` exists and is not a real directory (a link, a file, a device,
    a FIFO, a socket): an output folder is never followed through a link nor made over another kind of file."""
    kind = file_type(path)
    if kind not in (None, "directory"):
        raise ValueError(f"{option}: {str(path)!r} exists and is a {kind}; give a directory path (outputs are "
                         "written into real directories only)")


def same_file(a, b):
    """Whether paths ``a`` and ``b`` name the same existing file (any spelling, hard or symbolic links)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_output_file(option, path, inputs=()):
    """``ValueError`` (naming ``option``) if ``path`` exists and is not a regular file (a symbolic link, a device,
    a FIFO, a socket, a folder) or is the same file as one of ``inputs``."""
    p = Path(path)
    kind = file_type(p)
    if kind == "symbolic link":
        raise ValueError(f"{option}: {str(path)!r} is a symbolic link; give a plain file path (outputs are never "
                         "written through links)")
    if kind not in (None, "file"):
        raise ValueError(f"{option}: {str(path)!r} exists and is a {kind}; only a new path or a regular file is "
                         "replaced")
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
    if file_type(path) not in (None, "file", "symbolic link"):     # a device or FIFO made since the check
        raise ValueError(f"{path}: exists and is a {file_type(path)}; not replaced")
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
    """Rename ``src`` onto ``dest`` (same file system): a link at ``dest`` is replaced, not followed; a device, FIFO
    or socket is not replaced (``ValueError``)."""
    if file_type(dest) not in (None, "file", "symbolic link"):
        raise ValueError(f"{dest}: exists and is a {file_type(dest)}; not replaced")
    os.chmod(src, _umask_mode())
    os.replace(src, dest)
