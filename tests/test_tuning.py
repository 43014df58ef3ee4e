"""The continuous tuner: interior and boundary optima of cheap functions, the tracker factories round trip,
tuned.json's schema, the tuning episodes, and the layering (baselines never import agents)."""

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from agents.evaluation.suites import EVAL_SEED_BASE, TUNING_SEEDS, draw_suite
from baselines import registry
from baselines import tuning as tu
from baselines.seeds import draw_random_episodes
from baselines.trackers import imm2_spec_from_params
from baselines.tuned_params import kf_q_m_s2_from_params, tuned_parameters
from radar_env.envs.env import EnvConfig
from radar_env.sim.episode import stack_episodes

ROOT = Path(__file__).resolve().parents[1]
BOX = (tu.Param("a_g", 1e-3, 10.0, "log", "lo", "hi"), tu.Param("p", 0.01, 0.999, "logit", "lo", "hi limit"))


def _bowl(a_opt, p_opt):
    return lambda d: (math.log(d["a_g"] / a_opt)) ** 2 + 10 * (d["p"] - p_opt) ** 2


def test_optimizer_finds_an_interior_optimum_and_says_so():
    res = tu.minimize_with_restarts(_bowl(0.3, 0.7), BOX, {"a_g": 5.0, "p": 0.2}, starts=3, seed=1)
    assert res["params"]["a_g"] == pytest.approx(0.3, rel=1e-2)
    assert res["params"]["p"] == pytest.approx(0.7, abs=1e-2)
    assert all(v["interior"] and v["at"] is None for v in res["parameters"].values())
    starts = [r for r in res["starts"] if r["kind"] == "start"]
    assert len(starts) == 3 and starts[0]["x0"] == pytest.approx({"a_g": 5.0, "p": 0.2})
    assert res["value"] == min(r["value"] for r in res["starts"])


def test_optimizer_detects_a_boundary_optimum_and_names_the_bound():
    res = tu.minimize_with_restarts(_bowl(30.0, 0.9999), BOX, {"a_g": 1.0, "p": 0.5}, starts=3, seed=2)
    a, p = res["parameters"]["a_g"], res["parameters"]["p"]
    assert a["at"] == "upper" and not a["interior"] and a["value"] == 10.0 and a["bound_means"] == "hi"
    assert p["at"] == "upper" and p["bound_means"] == "hi limit"


def test_optimizer_restarts_are_seeded():
    r1 = tu.minimize_with_restarts(_bowl(0.3, 0.7), BOX, {"a_g": 5.0, "p": 0.2}, seed=7)
    r2 = tu.minimize_with_restarts(_bowl(0.3, 0.7), BOX, {"a_g": 5.0, "p": 0.2}, seed=7)
    assert r1["starts"] == r2["starts"]


def test_non_finite_criterion_is_an_error_not_a_number():
    with pytest.raises(ValueError, match="criterion is nan"):
        tu.minimize_with_restarts(lambda d: float("nan"), BOX, {"a_g": 1.0, "p": 0.5})


@pytest.mark.parametrize("args", [("q", 0.0, 1.0, "log"), ("q", 2.0, 1.0, "log"), ("p", 0.1, 1.0, "logit"),
                                  ("q", 0.1, 1.0, "linear")])
def test_param_rejects_bad_bounds_or_space(args):
    with pytest.raises(ValueError, match=f"Param '{args[0]}'"):
        tu.Param(*args, "lo", "hi")


# ------------------------------------------------------------------------------------------------ factories
@pytest.fixture(scope="module")
def few():
    eps = draw_random_episodes(4, seed=TUNING_SEEDS.start + 500)
    return eps, stack_episodes(eps)


def test_tracker_factories_round_trip_to_the_registered_trackers(few):
    eps, batch = few
    cfg = EnvConfig()
    tuned = tuned_parameters()
    for key, registered in (("kf", "kf_tuned"), ("imm2", "imm2")):
        params = {p.name: tuned[key][p.name] for p in tu.TUNED_TRACKERS[key].params}
        mine = tu.TUNED_TRACKERS[key].run(params, eps, cfg)
        theirs = registry.run_tracker(registered, eps)
        np.testing.assert_array_equal(mine.x, theirs.x)
        np.testing.assert_array_equal(mine.start_index, theirs.start_index)
    assert registry.tuned_imm2_spec() == imm2_spec_from_params(tuned["imm2"])
    assert registry.tuned_imm2_spec("imm2_grid") == imm2_spec_from_params(tu.IMM2_GRID_PARAMS)
    with pytest.raises(ValueError, match="'q_high_g' missing"):
        imm2_spec_from_params({"q_low_g": 0.01})


def test_tune_kf_on_a_few_episodes_finds_a_local_minimum(few):
    eps, batch = few
    cfg = EnvConfig()
    entry = tu.TUNED_TRACKERS["kf"]
    res = tu.tune(entry, eps, batch, cfg, starts=3, seed=0)
    q = res["q_g"]
    f = lambda q_g: tu.pooled_rmse(batch, entry.run({"q_g": q_g}, eps, cfg))  # noqa: E731
    assert f(q) == pytest.approx(res["pos_rmse_m"], rel=1e-12)
    assert res["pos_rmse_m"] <= min(f(q * 1.05), f(q / 1.05))
    assert len(res["optimizer"]["runs"]) >= 3


def test_imm_cv_ct_entry_is_skipped_with_a_reason_or_well_formed():
    entry, why = tu.tuned_tracker("imm_cv_ct")
    if entry is None:
        assert "imm_cv_ct" in why
    else:
        assert entry.params and set(entry.default_x0) == {p.name for p in entry.params}
    with pytest.raises(ValueError, match="unknown tuned tracker"):
        tu.tuned_tracker("nope")


# ------------------------------------------------------------------------------------------------ tuned.json
def test_tuned_json_schema_and_optima_inside_their_bounds():
    t = tuned_parameters()
    meta = t["tuning"]
    first, last = meta["seeds"]
    assert TUNING_SEEDS.start <= first <= last < TUNING_SEEDS.stop < EVAL_SEED_BASE
    assert meta["command"].startswith("python -m baselines.tuning") and meta["seconds"] > 0
    for key in ("kf", "imm2"):
        e = t[key]
        opt = e["optimizer"]
        names = [p.name for p in tu.TUNED_TRACKERS[key].params]
        assert sorted(opt["parameters"]) == sorted(names)
        assert len([r for r in opt["runs"] if r["kind"] == "start"]) >= 3
        assert math.isfinite(e["pos_rmse_m"]) and e["pos_rmse_m"] == min(r["value"] for r in opt["runs"])
        for n, p in opt["parameters"].items():
            assert p["lower"] <= e[n] <= p["upper"] and p["value"] == e[n]
            assert p["interior"] == (p["at"] is None)
            assert p["interior"] or p["bound_means"]
    g = t["imm2_grid"]
    assert {k: g[k] for k in tu.IMM2_GRID_PARAMS} == tu.IMM2_GRID_PARAMS and math.isfinite(g["pos_rmse_m"])
    # the continuous optimum is at least as good as the old grid's on the same episodes
    assert t["imm2"]["pos_rmse_m"] <= g["pos_rmse_m"]
    assert kf_q_m_s2_from_params(t["kf"]) > 0


# ------------------------------------------------------------------------------------------------ seeds, layers
def test_tuning_episodes_are_the_random_suite_on_tuning_seeds_bit_for_bit():
    a = stack_episodes(draw_random_episodes(3))
    b = stack_episodes(draw_suite("random", 3, seed=TUNING_SEEDS.start))
    for f in ("t_s", "truth", "z_m", "R_m2", "detected", "site_xy_m"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    with pytest.raises(ValueError, match="runs must be"):
        draw_random_episodes(0)


@pytest.mark.parametrize("package, forbidden", [("baselines", ("agents",)), ("radar_env", ("agents", "baselines"))])
def test_layers_only_look_down(package, forbidden):
    """baselines never import agents; radar_env imports neither (the old tuning imported agents.evaluation.suites)."""
    bad = []
    for path in sorted((ROOT / package).glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            bad += [f"{path.name}: {m}" for m in mods if m.split(".")[0] in forbidden]
    assert bad == []
