"""Layers only look down: radar_env (simulation, filters, env) knows nothing of baselines or agents, baselines
never imports agents, the simulation and filter modules import without gymnasium, and only
radar_env.filters.torch_chain (the differentiable chain), radar_env.filters.torch_imm (the IMM built from its
blocks) and radar_env.filters.compiled_chain (the chain's compiled CV copy) need torch: radar_env and baselines import without it. Inside radar_env the sub-packages are floors
(common < sim < filters < envs): each imports only the ones below it (test_radar_env_floors)."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Runs in a fresh interpreter where any import of a package fails, as on a machine without it installed.
_BLOCK = """
import importlib.abc, sys
class _Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == {pkg!r} or name.startswith({pkg!r} + "."):
            raise ImportError(f"No module named {{name!r}} (blocked by the test)")
        return None
sys.meta_path.insert(0, _Blocked())
"""
_NO_GYM = _BLOCK.format(pkg="gymnasium")
_NO_TORCH = _BLOCK.format(pkg="torch")

GYM_FREE = ("radar_env", "radar_env.filters.kalman", "radar_env.filters.tracking", "radar_env.sim.scenario",
            "radar_env.sim.episode", "radar_env.sim.radar", "radar_env.filters.features", "radar_env.envs.observation",
            "radar_env.sim.catalog", "radar_env.envs.config", "radar_env.envs.core", "baselines.trackers",
            "baselines.registry", "baselines.policies", "baselines.alpha_beta", "baselines.konle",
            "baselines.imm_cv_ct_runner", "baselines.hindsight", "baselines.user_trackers", "baselines.seeds",
            "baselines.tuning", "radar_env.sim.draws", "radar_env.filters.kernels", "radar_env.filters.imm_cv_ct",
            "radar_env.envs.imm_env", "radar_env.envs.imm_core", "radar_env.envs.detectors", "radar_env.sim.looks",
            "radar_env.sim.motion", "radar_env.sim.adsb_scenarios", "radar_env.common.numba_cache")


def _run(code, block=_NO_GYM):
    return subprocess.run([sys.executable, "-c", block + code], capture_output=True, text=True, timeout=120,
                          cwd=ROOT)


def test_simulation_and_filter_modules_import_without_gymnasium():
    code = ("import importlib\n"
            f"for m in {GYM_FREE!r}:\n"
            "    importlib.import_module(m)\n"
            "assert not any(m == 'gymnasium' or m.startswith('gymnasium.') for m in sys.modules)\n"
            # and they run: draw an episode and start its track
            "import numpy as np\n"
            "from radar_env.sim.catalog import make_setup\n"
            "from radar_env.sim.episode import draw_episode\n"
            "from radar_env.filters.tracking import TrackStart\n"
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
    res = _run("import radar_env.envs.env\n")
    assert res.returncode != 0 and "gymnasium" in res.stderr


def test_block_is_effective():
    # the finder really blocks gymnasium and torch (else the tests above and below prove nothing)
    for block, pkg in ((_NO_GYM, "gymnasium"), (_NO_TORCH, "torch")):
        res = _run(f"import {pkg}\n", block)
        assert res.returncode != 0 and "blocked by the test" in res.stderr


def test_torch_chain_imports_without_gymnasium():
    pytest.importorskip("torch")
    res = _run("import radar_env.filters.torch_chain\n"
               "assert not any(m == 'gymnasium' or m.startswith('gymnasium.') for m in sys.modules)\nprint('ok')\n")
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_radar_env_and_baselines_import_without_torch():
    code = ("import importlib\n"
            f"for m in {GYM_FREE + ('radar_env.envs.env',)!r}:\n"
            "    importlib.import_module(m)\n"
            "assert not any(m == 'torch' or m.startswith('torch.') for m in sys.modules)\nprint('ok')\n")
    res = _run(code, _NO_TORCH)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"
    res = _run("import radar_env.filters.torch_chain\n", _NO_TORCH)
    assert res.returncode != 0 and "torch" in res.stderr


def test_only_torch_chain_imports_torch_in_radar_env():
    users = {str(p.relative_to(ROOT)) for p in _files("radar_env") if "torch" in _imported_modules(p)}
    # the differentiable chain, the IMM built on it and the chain's compiled CV copy (its autograd Function)
    assert users == {"radar_env/filters/torch_chain.py", "radar_env/filters/torch_imm.py",
                     "radar_env/filters/compiled_chain.py"}


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
    f.write_text("def g():\n    from agents.evaluation.suites import draw_suite\n    import baselines.trackers\n")
    assert {"agents", "baselines"} <= _imported_modules(f)


# ------------------------------------------------------------------------------------------------ module graph
PACKAGES = ("radar_env", "baselines", "agents")
AGENTS_LAYERS = ("agents.policies", "agents.evaluation", "agents.training", "agents.reports", "agents.cli")
"""The agents sub-packages, lowest first: each may import only the ones before it (and radar_env, baselines)."""


def _module_name(path):
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _module_graph():
    """``{module: {modules it imports}}`` over the three packages: every import at any depth (function-level ones
    too), resolved to the most specific module of the project that exists as a file."""
    files = {_module_name(p): p for pkg in PACKAGES for p in _files(pkg)}

    def resolve(name):
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for mod, path in files.items():
        pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps |= {resolve(a.name) for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = pkg.split(".")[:len(pkg.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                for a in node.names:      # `from pkg import submodule` imports the submodule
                    deps.add(resolve(f"{base}.{a.name}") if f"{base}.{a.name}" in files else resolve(base))
        graph[mod] = {d for d in deps if d and d != mod}
    return graph


def _cycles(graph):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_two_modules_import_each_other():
    """No import cycle among the project's modules (packages' __init__ re-exports excluded: a package importing
    its own submodules is how it exposes them)."""
    graph = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in _module_graph().items()}
    assert _cycles(graph) == []


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_agents_sub_packages_look_down_only():
    graph = _module_graph()
    layer = {name: i for i, name in enumerate(AGENTS_LAYERS)}

    def layer_of(mod):
        return next((layer[p] for p in layer if mod == p or mod.startswith(p + ".")), None)

    bad = [(m, d) for m, deps in graph.items() if layer_of(m) is not None for d in deps
           if layer_of(d) is not None and layer_of(d) > layer_of(m)]
    assert bad == []
    top = {p.name for p in (ROOT / "agents").iterdir() if p.suffix == ".py" or (p / "__init__.py").is_file()}
    assert top == {"__init__.py", "cli.py", "policies", "training", "evaluation", "reports"}


# ------------------------------------------------------------------------------------------- radar_env's floors
FLOORS = ("radar_env.common", "radar_env.sim", "radar_env.filters", "radar_env.envs")
"""radar_env's sub-packages, lowest first: a module of one may import only its own floor and those below it."""
BESIDE = {"radar_env.render": ("radar_env.common",), "radar_env.applications": ("radar_env.common",)}
"""Top-level modules beside the floors and the floors they may import (the env layer renders: envs imports render)."""
ANYWHERE = {"radar_env._moved"}
"""Importable from any floor: the old-path aliases (standard library only)."""
GYM_LAYER = {"radar_env", "radar_env.envs.env", "radar_env.envs.single_env", "radar_env.envs.vector_env",
             "radar_env.envs.reference"}
"""The only radar_env modules that import gymnasium (``radar_env`` itself: the registration, inside a try;
``reference``: the reference page's generator, which builds every registered env)."""
TORCH_MODULES = {"radar_env.filters.torch_chain", "radar_env.filters.torch_imm", "radar_env.filters.compiled_chain"}


def _floor(mod):
    return next((i for i, p in enumerate(FLOORS) if mod == p or mod.startswith(p + ".")), None)


def _floor_violations(graph, external):
    """``(module, import, rule)`` for each import of ``graph`` (``{module: {project modules}}``) and ``external``
    (``{module: {top-level third-party names}}``) that breaks a floor of radar_env."""
    bad = []
    for m, deps in graph.items():
        if not m.startswith("radar_env"):
            continue
        for d in sorted(deps):
            if not d.startswith("radar_env") or d in ANYWHERE:
                continue
            if _floor(m) is not None:
                if d == "radar_env.render" and FLOORS[_floor(m)] == "radar_env.envs":
                    continue                       # the env layer renders its frames
                if _floor(d) is None or _floor(d) > _floor(m):
                    bad.append((m, d, "imports an upper floor"))
            elif m in BESIDE and (_floor(d) is None or FLOORS[_floor(d)] not in BESIDE[m]):
                bad.append((m, d, "imports above its floors"))
    for m, names in external.items():
        if not m.startswith("radar_env"):
            continue
        if "gymnasium" in names and m not in GYM_LAYER:
            bad.append((m, "gymnasium", "below the Gymnasium layer"))
        if "torch" in names and m not in TORCH_MODULES:
            bad.append((m, "torch", "not a torch module"))
    return sorted(bad)


def _external_imports():
    return {_module_name(p): _imported_modules(p) for p in _files("radar_env")}


def test_radar_env_floors():
    """sim imports nothing of filters or envs, filters nothing of envs, common nothing of the others; nothing
    below the Gymnasium layer imports gymnasium; only the torch modules import torch."""
    graph, external = _module_graph(), _external_imports()
    # the scan sees the package: known edges down the chain (else an empty graph would pass)
    for m, d in (("radar_env.filters.kernels", "radar_env.sim.looks"), ("radar_env.filters.tracking",
                 "radar_env.filters.features"), ("radar_env.envs.core", "radar_env.sim.draws"),
                 ("radar_env.sim.scenario", "radar_env.sim.motion"), ("radar_env.envs.single_env", "radar_env.render"),
                 ("radar_env.envs.config", "radar_env.filters.tracking")):
        assert d in graph[m], (m, d)
    assert "gymnasium" in external["radar_env.envs.single_env"] and "torch" in external["radar_env.filters.torch_imm"]
    assert {_floor(m) for m in graph if m.startswith("radar_env.")} >= {0, 1, 2, 3}
    assert _floor_violations(graph, external) == []


def test_floor_check_catches_upward_imports():
    """The check fails on a synthetic graph with one breach of each rule."""
    graph = {"radar_env.sim.episode": {"radar_env.filters.kernels", "radar_env.common.units"},
             "radar_env.filters.tracking": {"radar_env.envs.config", "radar_env._moved"},
             "radar_env.common.units": {"radar_env.sim.radar"},
             "radar_env.render": {"radar_env.envs.core"},
             "radar_env.envs.single_env": {"radar_env.render", "radar_env.filters.kernels"}}
    external = {"radar_env.envs.config": {"gymnasium"}, "radar_env.sim.draws": {"torch", "numpy"},
                "radar_env.envs.env": {"gymnasium"}, "radar_env.filters.torch_chain": {"torch"}}
    assert _floor_violations(graph, external) == [
        ("radar_env.common.units", "radar_env.sim.radar", "imports an upper floor"),
        ("radar_env.envs.config", "gymnasium", "below the Gymnasium layer"),
        ("radar_env.filters.tracking", "radar_env.envs.config", "imports an upper floor"),
        ("radar_env.render", "radar_env.envs.core", "imports above its floors"),
        ("radar_env.sim.draws", "torch", "not a torch module"),
        ("radar_env.sim.episode", "radar_env.filters.kernels", "imports an upper floor"),
    ]


def test_radar_env_folders_read_like_the_chain():
    top = {p.name for p in (ROOT / "radar_env").iterdir() if p.suffix == ".py" or (p / "__init__.py").is_file()}
    assert top == {"__init__.py", "_moved.py", "common", "sim", "filters", "envs", "applications.py", "render.py"}
    for pkg in ("common", "sim", "filters", "envs"):   # each floor says what lives there and what it may import
        doc = ast.get_docstring(ast.parse((ROOT / "radar_env" / pkg / "__init__.py").read_text()))
        assert doc and len(doc.splitlines()) == 2 and "import" in doc.splitlines()[1].lower(), pkg
