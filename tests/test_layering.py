"""Layers only look down: radar_env (simulation, filters, env) knows nothing of baselines or agents, baselines
never imports agents, and the simulation and filter modules import without gymnasium."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Runs in a fresh interpreter where any import of gymnasium fails, as on a machine without it installed.
_NO_GYM = """
import importlib.abc, sys
class _NoGymnasium(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "gymnasium" or name.startswith("gymnasium."):
            raise ImportError(f"No module named {name!r} (blocked by the test)")
        return None
sys.meta_path.insert(0, _NoGymnasium())
"""

GYM_FREE = ("radar_env", "radar_env.filters", "radar_env.tracking", "radar_env.scenario", "radar_env.episode",
            "radar_env.radar", "radar_env.features", "radar_env.observation", "radar_env.catalog",
            "radar_env.config", "radar_env.core", "baselines.trackers", "baselines.registry", "baselines.policies",
            "baselines.alpha_beta", "baselines.konle", "baselines.imm_cv_ct", "baselines.hindsight",
            "baselines.user_trackers", "baselines.seeds", "baselines.tuning", "radar_env.draws", "radar_env.kernels")


def _run(code):
    return subprocess.run([sys.executable, "-c", _NO_GYM + code], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)


def test_simulation_and_filter_modules_import_without_gymnasium():
    code = ("import importlib\n"
            f"for m in {GYM_FREE!r}:\n"
            "    importlib.import_module(m)\n"
            "assert not any(m == 'gymnasium' or m.startswith('gymnasium.') for m in sys.modules)\n"
            # and they run: draw an episode and start its track
            "import numpy as np\n"
            "from radar_env.catalog import make_setup\n"
            "from radar_env.episode import draw_episode\n"
            "from radar_env.tracking import TrackStart\n"
            "rng = np.random.default_rng(0)\n"
            "s = make_setup('bizup2002', rng)\n"
            "tr = TrackStart().tracker(1)\n"
            "out = tr.load([0], [draw_episode(s.scenario, s.radar, rng)])\n"
            "assert np.isfinite(out.x).all()\n"
            "print('ok')\n")
    res = _run(code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_the_gym_layer_says_it_needs_gymnasium():
    res = _run("import radar_env.env\n")
    assert res.returncode != 0 and "gymnasium" in res.stderr


def test_block_is_effective():
    # the finder really blocks gymnasium (else the tests above prove nothing)
    res = _run("import gymnasium\n")
    assert res.returncode != 0 and "blocked by the test" in res.stderr


def _imported_modules(path):
    """Top-level names of every module ``path`` imports, at any depth (module level, in functions, relative
    imports resolved to their package)."""
    pkg = path.parent.name
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            names.add(pkg if node.level else (node.module or "").split(".")[0])
    return names


def _files(package):
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("path", _files("baselines"), ids=lambda p: str(p.relative_to(ROOT)))
def test_baselines_never_import_agents(path):
    assert "agents" not in _imported_modules(path)


@pytest.mark.parametrize("path", _files("radar_env"), ids=lambda p: str(p.relative_to(ROOT)))
def test_radar_env_imports_neither_baselines_nor_agents(path):
    assert not _imported_modules(path) & {"baselines", "agents"}


def test_scan_sees_function_level_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def g():\n    from agents.suites import draw_suite\n    import baselines.trackers\n")
    assert {"agents", "baselines"} <= _imported_modules(f)
