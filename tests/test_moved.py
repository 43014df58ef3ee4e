"""Issue 37 moved radar_env's flat modules into sub-packages: the old paths still import for one release, as the
same module objects, each with one DeprecationWarning naming the new path (radar_env/_moved.py; the renamed runner
baselines/imm_cv_ct_runner.py by a one-file shim); the project's own code, tests, benchmarks, scripts and docs use
the new paths only."""

import ast
import re
import subprocess
import sys
from pathlib import Path

from radar_env._moved import MOVED

ROOT = Path(__file__).resolve().parents[1]

_OLD_NAMES = {"baselines.imm_cv_ct": "baselines.imm_cv_ct_runner", **MOVED}


def _run(code):
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_every_old_path_is_the_new_module_and_warns_once():
    code = f"""
import importlib, sys, warnings
moved = {_OLD_NAMES!r}
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    for old, new in moved.items():
        a = importlib.import_module(old)
        assert a is importlib.import_module(new) is sys.modules[old] is sys.modules[new], old
        assert a.__name__ == new and a.__spec__.name == new, (old, a.__spec__)
        importlib.import_module(old)                                  # again: no second warning
ours = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning) and " moved to " in str(w.message)]
assert sorted(ours) == sorted(f"{{o}} moved to {{n}}; the old path goes away in the next release"
                              for o, n in moved.items()), ours
assert {{w.filename for w in caught if " moved to " in str(w.message)}} == {{"<string>"}}   # points at the caller
print("ok")
"""
    assert _run(code).strip() == "ok"


def test_old_names_of_classes_and_functions_are_the_new_objects():
    code = """
import warnings
warnings.simplefilter("ignore", DeprecationWarning)
import radar_env.episode, radar_env.sim.episode
assert radar_env.episode.Episode is radar_env.sim.episode.Episode
from radar_env import kernels, numba_cache                     # the `from package import module` form
from radar_env.filters import kernels as new_kernels
from radar_env.common import numba_cache as new_cache
assert kernels is new_kernels and numba_cache is new_cache
from radar_env.env import RadarTrackEnv                        # the old Gymnasium entry point's module
from radar_env.envs.env import RadarTrackEnv as New
assert RadarTrackEnv is New
from baselines.imm_cv_ct import run_imm_cv_ct
import baselines.imm_cv_ct_runner as runner
assert run_imm_cv_ct is runner.run_imm_cv_ct
print("ok")
"""
    assert _run(code).strip() == "ok"


def test_old_filters_module_names_forward_with_a_warning():
    code = """
import warnings
import radar_env.filters as f
from radar_env.filters import kalman
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    assert f.transition_ct is kalman.transition_ct and f.imm_filter is kalman.imm_filter
    assert f.transition_ct is kalman.transition_ct                  # cached: no second warning
msgs = [str(w.message) for w in caught if w.category is DeprecationWarning]
assert msgs == ["radar_env.filters.transition_ct moved to radar_env.filters.kalman.transition_ct; the old path goes "
                "away in the next release", "radar_env.filters.imm_filter moved to radar_env.filters.kalman.imm_filter; "
                "the old path goes away in the next release"], msgs
for name in ("np", "_k", "no_such_name"):
    assert not hasattr(f, name), name
from radar_env.filters import tracking                               # sub-modules are not forwarded
assert tracking.__name__ == "radar_env.filters.tracking"
print("ok")
"""
    assert _run(code).strip() == "ok"


def test_gymnasium_registration_points_at_the_new_module():
    code = """
import warnings
warnings.simplefilter("error", DeprecationWarning)
import radar_env
from gymnasium.envs.registration import registry
spec = registry["RadarTrack-v0"]
assert spec.entry_point == "radar_env.envs.env:RadarTrackEnv", spec.entry_point
assert spec.vector_entry_point == "radar_env.envs.env:RadarTrackVectorEnv", spec.vector_entry_point
import sys
assert not any(m in sys.modules for m in ("radar_env.env", "radar_env.episode", "radar_env.kernels"))
print("ok")
"""
    assert _run(code).strip() == "ok"


def _project_py():
    for d in ("radar_env", "baselines", "agents", "tests", "benchmarks", "scripts"):
        yield from (p for p in sorted((ROOT / d).rglob("*.py")) if p.name != "test_moved.py" and p.name != "_moved.py"
                    and p.relative_to(ROOT).as_posix() != "baselines/imm_cv_ct.py")   # the aliases themselves


def _old_path_imports(files, root):
    """``(file, old module name)`` for every import of an old path in ``files`` (at any depth; relative imports
    resolved against the file's package below ``root``)."""
    old = set(_OLD_NAMES)
    bad = []
    for p in files:
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:                      # relative: resolved against the file's package
                    rel = p.relative_to(root).with_suffix("").parts
                    pkg = rel[:-1]
                    anchor = pkg[:len(pkg) - node.level + 1]
                    base = ".".join(anchor + ((base,) if base else ()))
                names = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            bad += [(p.relative_to(root).as_posix(), n) for n in names if n in old]
    return bad


def test_project_code_imports_no_old_path():
    files = list(_project_py())
    assert len(files) > 100                            # the scan saw the project
    assert _old_path_imports(files, ROOT) == []


def test_the_old_path_scan_resolves_relative_imports(tmp_path):
    (tmp_path / "baselines").mkdir()
    (tmp_path / "baselines" / "m.py").write_text("def f():\n    from . import imm_cv_ct as mod\n"
                                                  "    from .imm_cv_ct_runner import run\n")
    (tmp_path / "radar_env" / "sim").mkdir(parents=True)
    (tmp_path / "radar_env" / "sim" / "x.py").write_text("from .. import kernels\nfrom . import draws\n"
                                                          "import radar_env.episode\n")
    found = _old_path_imports(sorted(tmp_path.rglob("*.py")), tmp_path)
    assert sorted(found) == [("baselines/m.py", "baselines.imm_cv_ct"), ("radar_env/sim/x.py", "radar_env.episode"),
                             ("radar_env/sim/x.py", "radar_env.kernels")]


def test_project_text_names_no_old_path():
    """Docs, strings and comments too (README, docs/, pyproject, every .py and .md of the packages)."""
    old = sorted(_OLD_NAMES, key=len, reverse=True)
    pat = re.compile(r"(?<![\\w/.])(%s)\\b(?![.\\w]*_runner)" % "|".join(re.escape(o) for o in old))
    path_pat = re.compile(r"\\b(%s)\\.py\\b" % "|".join(re.escape(o.replace(".", "/")) for o in old))
    texts = [ROOT / "README.md", ROOT / "pyproject.toml", *sorted((ROOT / "docs").rglob("*.md")), *_project_py(),
             *(p for d in ("radar_env", "baselines", "agents") for p in sorted((ROOT / d).rglob("*.md")))]
    bad = [(str(p.relative_to(ROOT)), i, m.group(0)) for p in texts
           for i, line in enumerate(p.read_text().splitlines(), 1) for m in (*pat.finditer(line), *path_pat.finditer(line))]
    assert bad == []
