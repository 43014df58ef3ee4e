"""Window-correction ensembles (version 2 folders: several networks on standardised inputs over one base) and the
float32 forwards they may run in (agents.policies.window_correction, agents.policies.recurrent,
scripts/make_window_ensemble.py)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.policies import recurrent
from agents.policies import window_correction as wcm
from agents.policies.learned import BUNDLED_LEARNED, load_learned

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import make_window_ensemble as mwe  # noqa: E402

ARCH = {"input_size": wcm.feature_count(4), "layers": [8, 6], "covariance": True}
CFG = {"base": "policy_bp", "window_looks": 4, "scale_m": 300.0, "scale_m_s": 30.0, "architecture": ARCH}


def _member(seed):
    """Random weights for standardised inputs, and a standardisation with large means (as the features' are)."""
    rng = np.random.default_rng(seed)
    w = {k: rng.normal(scale=0.3, size=s) for k, s in wcm.network_shapes(ARCH).items()}
    n = ARCH["input_size"]
    return w, rng.normal(scale=50.0, size=n), rng.uniform(0.01, 3.0, size=n)


def _folded(w, mean, sd):
    """The single correction (version 1) of the same network: the standardisation folded into the first layer."""
    f = dict(w)
    f["layer.0.weight"] = w["layer.0.weight"] / sd
    f["layer.0.bias"] = w["layer.0.bias"] - f["layer.0.weight"] @ mean
    return f


def _env():
    return json.loads((BUNDLED_LEARNED["policy_bp"] / "env_config.json").read_text())


def _ensemble(tmp_path, seeds, name="ens", **cfg):
    members = [_member(s) for s in seeds]
    wcm.save_window_ensemble(tmp_path / name, members,
                             {**CFG, "precision": "float64", "base_precision": "float64", **cfg}, _env())
    return tmp_path / name, members


@pytest.fixture(scope="module")
def episodes():
    from agents.evaluation.suites import draw_suite
    return draw_suite("random_radars", 5, seed=900_000)


def _moves(lt, eps):
    """The corrected runs' moves and covariances at every corrected look, with the base run."""
    run = lt.run(eps)
    base = lt.policy.base_run(eps)
    ok = np.isfinite(run.extra["correction_m"])
    return run.x[ok][:, :2] - base.x[ok][:, :2], run.P[ok], run, base


def test_linear_in_float32_sums_in_order_and_is_batch_independent():
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=(7, 13)), rng.normal(size=(12, 13))
    y32 = recurrent.linear(x, w, np.float32)
    assert y32.dtype == np.float32
    x32, w32 = x.astype(np.float32), w.astype(np.float32)
    ref = np.zeros((7, 12), np.float32)
    for f in range(13):                    # one product at a time, in order, in float32
        ref += x32[:, f:f + 1] * w32[:, f][None]
    np.testing.assert_array_equal(y32, ref)
    for i in range(7):
        np.testing.assert_array_equal(recurrent.linear(x[i:i + 1], w, np.float32)[0], y32[i])
    np.testing.assert_allclose(y32, recurrent.linear(x, w), rtol=1e-5, atol=1e-5)


def test_a_float32_q_policy_acts_as_the_float64_one_to_float32_rounding():
    lt = load_learned("policy_bp")
    p64 = lt.policy
    p32 = p64.with_precision("float32")
    assert p32 is not p64 and p32.precision == "float32" and p64.precision == "float64"
    obs = np.random.default_rng(1).normal(size=(5, p64.input_size))
    a64, h64 = p64.act(obs, p64.initial_state(5))
    a32, h32 = p32.act(obs, p32.initial_state(5))
    assert a32.dtype == np.float32
    np.testing.assert_allclose(a32, a64, atol=1e-5)
    act, _ = p32.predict(obs[0])
    assert act.dtype == np.float64 and act.shape == (1,)
    same = p32.with_precision("float64")          # back to float64: the original policy's numbers, to the bit
    np.testing.assert_array_equal(same.levels_m_s2, p64.levels_m_s2)
    np.testing.assert_array_equal(same.act(obs, same.initial_state(5))[0], a64)
    with pytest.raises(ValueError, match="precision must be one of"):
        p64.with_precision("float16")


def test_one_member_in_float64_is_the_single_correction(tmp_path, episodes):
    d, [(w, mean, sd)] = _ensemble(tmp_path, [3])
    wcm.save_window_correction(tmp_path / "single", _folded(w, mean, sd), CFG, _env())
    dm, Pm, run, _ = _moves(load_learned(d), episodes)
    ds, Ps, single, _ = _moves(load_learned(tmp_path / "single"), episodes)
    np.testing.assert_allclose(dm, ds, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Pm, Ps, rtol=1e-9, atol=1e-9)
    assert np.array_equal(np.isfinite(run.x), np.isfinite(single.x))


def test_an_ensemble_moves_by_the_mean_and_reports_the_mixtures_covariance(tmp_path, episodes):
    d, members = _ensemble(tmp_path, [3, 4, 5])
    dm, Pm, run, base = _moves(load_learned(d), episodes)
    singles = []
    for j, (w, mean, sd) in enumerate(members):
        wcm.save_window_correction(tmp_path / f"s{j}", _folded(w, mean, sd), CFG, _env())
        singles.append(_moves(load_learned(tmp_path / f"s{j}"), episodes)[:2])
    moves = np.stack([s[0] for s in singles])
    np.testing.assert_allclose(dm, moves.mean(0), rtol=1e-9, atol=1e-9)
    e = moves - moves.mean(0)
    C = np.mean([s[1] for s in singles], 0)
    C[:, :2, :2] += np.einsum("mni,mnj->nij", e, e) / 3
    np.testing.assert_allclose(Pm, C, rtol=1e-9, atol=1e-9)
    assert np.array_equal(Pm, np.swapaxes(Pm, 1, 2)) and (np.linalg.eigvalsh(Pm) > 0).all()
    np.testing.assert_array_equal(run.x[..., 2:], base.x[..., 2:])          # velocities: the base's


def test_float32_forwards_give_the_float64_numbers_to_a_millimetre(tmp_path, episodes):
    d64, _ = _ensemble(tmp_path, [3, 4], "e64")
    d32, _ = _ensemble(tmp_path, [3, 4], "e32", precision="float32", base_precision="float32")
    lt32 = load_learned(d32)
    assert lt32.policy.base.precision == "float32" and lt32.policy.members[0].w["layer.0.weight"].dtype == np.float32
    r64, r32 = load_learned(d64).run(episodes), lt32.run(episodes)
    assert np.array_equal(np.isfinite(r64.x), np.isfinite(r32.x))
    ok = np.isfinite(r64.x)
    assert np.abs(r32.x[ok] - r64.x[ok]).max() < 1e-3 and not np.array_equal(r32.x[ok], r64.x[ok])


def test_float32_only_for_an_ensemble_on_standardised_inputs(tmp_path):
    """A single correction (its standardisation folded into the first layer: terms of thousands that cancel) has no
    precision to choose: it runs in float64."""
    w, mean, sd = _member(3)
    with pytest.raises(ValueError, match="belongs to an ensemble"):
        wcm.WindowCorrection(_folded(w, mean, sd), {**CFG, "precision": "float32"}, None, None)


@pytest.mark.parametrize("edit, match", [
    (lambda c, w: c.update(members=0), r"field 'members' must be an integer in \[1, 16\]"),
    (lambda c, w: c.update(members=3), r"member2\.layer\.0\.weight"),
    (lambda c, w: c.update(precision="half"), r"field 'precision' must be one of \['float64', 'float32'\]"),
    (lambda c, w: c.pop("base_precision"), r"field 'base_precision' must be one of"),
    (lambda c, w: c.update(version=3), r"version 3, need 'radar-track-window-correction' version 1 or 2"),
    (lambda c, w: w.update({"member1.input_sd": np.zeros(ARCH["input_size"])}), r"member1\.input_sd must be positive"),
    (lambda c, w: w.update({"member0.input_mean": np.full(ARCH["input_size"], np.nan)}), r"member0\.input_mean"),
])
def test_the_loader_refuses_a_bad_ensemble_in_one_line(tmp_path, edit, match):
    d, _ = _ensemble(tmp_path, [3, 4])
    cfg = json.loads((d / "policy.json").read_text())
    with np.load(d / "policy.npz") as z:
        w = {k: z[k] for k in z.files}
    edit(cfg, w)
    (d / "policy.json").write_text(json.dumps(cfg))
    np.savez(d / "policy.npz", **w)
    with pytest.raises(ValueError, match=match) as e:
        load_learned(d)
    assert "\n" not in str(e.value)


def test_base_precision_float32_needs_a_recurrent_q_policy_base(tmp_path):
    d, _ = _ensemble(tmp_path, [3], base="policy_imm_bp", base_precision="float32")
    with pytest.raises(ValueError, match="field 'base_precision' 'float32' needs a recurrent q-policy base"):
        load_learned(d)


def _run_folder(tmp_path, name, seed):
    """A window run's folder as make_window_ensemble reads it: best/ (folded) and checkpoints/last.npz."""
    w, mean, sd = _member(seed)
    wcm.save_window_correction(tmp_path / name / "best", _folded(w, mean, sd), CFG, _env())
    (tmp_path / name / "checkpoints").mkdir()
    np.savez(tmp_path / name / "checkpoints" / "last.npz", mean=mean, sd=sd)
    return tmp_path / name, (w, mean, sd)


def test_make_window_ensemble_unfolds_each_runs_network(tmp_path, episodes):
    runs = [_run_folder(tmp_path, f"run{j}", 10 + j) for j in range(2)]
    mwe.main([str(tmp_path / "out"), *(str(r) for r, _ in runs), "--precision", "float64",
              "--base-precision", "float64"])
    with np.load(tmp_path / "out" / "policy.npz") as z:
        for j, (_, (w, mean, sd)) in enumerate(runs):
            np.testing.assert_allclose(z[f"member{j}.input_mean"], mean, rtol=0)
            np.testing.assert_allclose(z[f"member{j}.layer.0.weight"], w["layer.0.weight"], rtol=1e-12)
            np.testing.assert_allclose(z[f"member{j}.layer.0.bias"], w["layer.0.bias"], rtol=1e-9, atol=1e-9)
    made = json.loads((tmp_path / "out" / "ensemble.json").read_text())
    assert [Path(m["run"]).name for m in made["members"]] == ["run0", "run1"]
    d, _ = _ensemble(tmp_path, [10, 11], "direct")
    np.testing.assert_allclose(_moves(load_learned(tmp_path / "out"), episodes)[0],
                               _moves(load_learned(d), episodes)[0], rtol=1e-9, atol=1e-9)


def _break_json_list(run):
    (run / "best" / "policy.json").write_text("[1]")


def _break_sd(run):
    with np.load(run / "checkpoints" / "last.npz") as z:
        np.savez(run / "checkpoints" / "last.npz", mean=z["mean"], sd=0 * z["sd"])


def _break_sd_shape(run):
    np.savez(run / "checkpoints" / "last.npz", mean=np.zeros(3), sd=np.ones(3))


def _break_weights(run):
    (run / "best" / "policy.npz").write_bytes(b"PK\x03\x04 truncated")


@pytest.mark.parametrize("damage, match", [
    (_break_json_list, r"best/policy.json: must hold a JSON object"),
    (_break_sd, r"last.npz: mean and sd must be finite and sd > 0"),
    (_break_sd_shape, r"last.npz: mean and sd must have the network's \d+ inputs, got shapes \(3,\)"),
    (_break_weights, r"best/policy.npz: not a numpy .npz of plain arrays, or damaged"),
])
def test_make_window_ensemble_refuses_a_damaged_run_in_one_line(tmp_path, damage, match):
    run, _ = _run_folder(tmp_path, "run0", 10)
    damage(run)
    with pytest.raises(SystemExit, match=match) as e:
        mwe.main([str(tmp_path / "out"), str(run)])
    assert "\n" not in str(e.value) and not (tmp_path / "out").exists()
    (tmp_path / "afile").write_text("")
    with pytest.raises(SystemExit, match=r"OUT: .* must name a folder"):
        mwe.main([str(tmp_path / "afile"), str(_run_folder(tmp_path, "run1", 11)[0])])


def test_make_window_ensemble_refuses_a_run_without_its_standardisation(tmp_path):
    run, _ = _run_folder(tmp_path, "run0", 10)
    np.savez(run / "checkpoints" / "last.npz", generator=np.zeros(3))
    with pytest.raises(SystemExit, match="no standardisation"):
        mwe.main([str(tmp_path / "out"), str(run)])
    assert not (tmp_path / "out").exists()


def test_the_bundled_ensemble_is_its_shipped_seeds_networks():
    """policy_window is the ensemble of the networks under seeds/ (ensemble.json's sha256), each unfolded: in float64
    every member gives its seed's outputs to 1e-9, and in float32 (the bundle's precision) to 1e-4 output units."""
    import hashlib
    from agents.policies.recurrent import layer_weights
    folder = BUNDLED_LEARNED["policy_window"]
    lt = load_learned("policy_window")
    made = json.loads((folder / "ensemble.json").read_text())
    seeds = sorted((folder / "seeds").iterdir())
    assert lt.policy.precision == lt.policy.base.precision == "float32" and len(lt.policy.members) == len(seeds) == 3
    assert [m["policy_npz_sha256"] for m in made["members"]] == [
        hashlib.sha256((s / "policy.npz").read_bytes()).hexdigest() for s in seeds]
    with np.load(folder / "policy.npz") as z:
        raw = {k: z[k] for k in z.files}
    for j, s in enumerate(seeds):
        single = load_learned(str(s)).policy
        m = wcm.ensemble_members(raw, lt.policy.config)[j]
        F = m["mean"] + m["sd"] * np.random.default_rng(j).standard_normal((512, m["mean"].size))
        a = wcm.network_forward(single.w, 2, F, True)
        b = wcm.network_forward(layer_weights(m["weights"]), 2, F, True, mean=m["mean"], sd=m["sd"])
        c = wcm.network_forward(lt.policy.members[j].w, 2, F, True, np.float32, m["mean"], m["sd"])
        for x, y, w in zip(a, b, c):
            np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-9 * np.abs(x).max())
            assert np.abs(w - x).max() < 1e-4


def test_the_env_wrapper_gives_the_bundled_ensembles_evaluation_numbers():
    """CorrectedEstimate with policy_window (three float32 networks, the float32 base acting, as the README's
    quickstart does) gives what its run gives on the same episode, every look."""
    import gymnasium as gym
    from agents.policies.checks import env_kwargs_from_json
    from radar_env.envs.core import draw_setup_and_episode
    lt = load_learned("policy_window")
    cfg = lt.env_config
    ep = draw_setup_and_episode(cfg.scenario, cfg.radar, cfg.random_scenario_config, np.random.default_rng(41),
                                cfg.warmup_scans)
    run = lt.run([ep])
    kw = env_kwargs_from_json(json.loads((lt.folder / "env_config.json").read_text()))
    env = wcm.CorrectedEstimate(gym.make("RadarTrack-v0", **kw), lt.policy)
    obs, info = env.reset(seed=41)
    k, state, start, n = int(run.start_index[0]) - 1, None, True, 0
    while True:
        action, state = lt.policy.base.predict(obs, state, episode_start=start)
        obs, _, term, trunc, info = env.step(action)
        start, k, n = False, k + 1, n + 1
        np.testing.assert_allclose(info["corrected_estimate"], run.x[0, k], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(info["corrected_covariance"], run.P[0, k], rtol=1e-9, atol=1e-9)
        if term or trunc:
            break
    assert n > 50


def test_make_window_ensemble_refuses_what_would_not_load(tmp_path):
    run, _ = _run_folder(tmp_path, "run0", 10)
    cfg = json.loads((run / "best" / "policy.json").read_text())
    (run / "best" / "policy.json").write_text(json.dumps({**cfg, "base": "policy_imm_bp"}))
    with pytest.raises(SystemExit, match="field 'base_precision' 'float32' needs a recurrent q-policy base"):
        mwe.main([str(tmp_path / "out"), str(run)])          # the default base precision, float32
    assert not (tmp_path / "out").exists()
    mwe.main([str(tmp_path / "out"), str(run), "--base-precision", "float64"])
    assert load_learned(tmp_path / "out").policy.base_precision == "float64"


def test_a_failed_build_leaves_an_existing_folder_as_it_was(tmp_path):
    """OUT may hold other files (the bundle's folder does): a build that would not load changes none of them."""
    run, _ = _run_folder(tmp_path, "run0", 10)
    out = tmp_path / "out"
    mwe.main([str(out), str(run), "--base-precision", "float64"])
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    cfg = json.loads((run / "best" / "policy.json").read_text())
    (run / "best" / "policy.json").write_text(json.dumps({**cfg, "base": "policy_imm_bp"}))
    with pytest.raises(SystemExit, match="needs a recurrent q-policy base"):
        mwe.main([str(out), str(run)])
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "run0"]          # no temporary folder left


def test_make_window_ensemble_refuses_runs_that_differ_or_repeat(tmp_path):
    a, _ = _run_folder(tmp_path, "run0", 10)
    b, _ = _run_folder(tmp_path, "run1", 11)
    cfg = json.loads((b / "best" / "policy.json").read_text())
    (b / "best" / "policy.json").write_text(json.dumps({**cfg, "scale_m": 200.0}))
    with pytest.raises(SystemExit, match=r"\['scale_m'\] differ from"):
        mwe.main([str(tmp_path / "out"), str(a), str(b)])
    with pytest.raises(SystemExit, match="a run is given twice"):
        mwe.main([str(tmp_path / "out"), str(a), str(tmp_path / "." / "run0")])


def test_an_ensemble_built_by_hand_is_checked_as_the_loader_checks(tmp_path):
    d, members = _ensemble(tmp_path, [3, 4])
    with np.load(d / "policy.npz") as z:
        w = {k: z[k] for k in z.files}
    cfg = json.loads((d / "policy.json").read_text())
    assert wcm.WindowCorrection(w, cfg, None, None).w is None          # an ensemble has no single network
    with pytest.raises(ValueError, match=r"field 'members' must be an integer in \[1, 16\], got None"):
        wcm.WindowCorrection(w, {k: v for k, v in cfg.items() if k != "members"}, None, None)
    single, _, _ = members[0]
    with pytest.raises(ValueError, match="belongs to an ensemble"):
        wcm.WindowCorrection(single, {**CFG, "base_precision": "float64"}, None, None)


def test_an_ensemble_cannot_start_a_training_run():
    from agents.training import window
    from agents.training.runs import load_hyperparams
    hp = load_hyperparams("window")
    with pytest.raises(ValueError, match="is an ensemble of window corrections"):
        window.init_weights(BUNDLED_LEARNED["policy_window"], hp, wcm.feature_count(24, (6, 8, 12, 16, 24), 12))


# --- covariance_scale: the ensemble's reported covariance times one fitted factor -----------------------------------

import calibrate_window_covariance as cwc  # noqa: E402

SMALL = {"scenarios": ["random", "random_broad"], "episodes": {"random": 4, "random_broad": 2},
         "first_leg_min_s": 0.0}


@pytest.mark.parametrize("seeds", [[3], [3, 4]])
def test_covariance_scale_multiplies_the_reported_covariance_only(tmp_path, episodes, seeds):
    d, _ = _ensemble(tmp_path, seeds, "plain")
    ds, _ = _ensemble(tmp_path, seeds, "scaled", covariance_scale=0.5)
    dm, Pm, run, _ = _moves(load_learned(d), episodes)
    dm2, Pm2, run2, _ = _moves(load_learned(ds), episodes)
    np.testing.assert_array_equal(run2.x, run.x)
    np.testing.assert_allclose(Pm2, 0.5 * Pm, rtol=1e-15, atol=0)
    unmoved = ~np.isfinite(run.extra["correction_m"])
    np.testing.assert_array_equal(run2.P[unmoved], run.P[unmoved])        # the base's, where nothing is corrected


@pytest.mark.parametrize("value, match", [
    (0.05, r"field 'covariance_scale' must be a number in \[0.1, 10\]"),
    (11, r"field 'covariance_scale' must be a number in \[0.1, 10\]"),
    (True, r"field 'covariance_scale' must be a number"),
    ("0.8", r"field 'covariance_scale' must be a number"),
])
def test_the_loader_refuses_a_bad_covariance_scale_in_one_line(tmp_path, value, match):
    d, _ = _ensemble(tmp_path, [3], covariance_scale=value)
    with pytest.raises(ValueError, match=match) as e:
        load_learned(d)
    assert "\n" not in str(e.value) and "policy.json" in str(e.value)


def test_covariance_scale_needs_an_ensemble_folder_and_a_covariance_head(tmp_path):
    w, mean, sd = _member(3)
    wcm.save_window_correction(tmp_path / "single", _folded(w, mean, sd), {**CFG, "covariance_scale": 0.8}, _env())
    with pytest.raises(ValueError, match="field 'covariance_scale' belongs to an ensemble"):
        load_learned(tmp_path / "single")
    arch = {**ARCH, "covariance": False}
    members = [({k: v for k, v in m[0].items() if k in wcm.network_shapes(arch)}, m[1], m[2]) for m in [_member(3)]]
    wcm.save_window_ensemble(tmp_path / "nohead", members, {**CFG, "architecture": arch, "precision": "float64",
                                                            "base_precision": "float64", "covariance_scale": 0.8},
                             _env())
    with pytest.raises(ValueError, match="field 'covariance_scale' needs a covariance head"):
        load_learned(tmp_path / "nohead")
    with np.load(tmp_path / "nohead" / "policy.npz") as z:          # built by hand: the same refusal
        w = {k: z[k] for k in z.files}
    cfg = json.loads((tmp_path / "nohead" / "policy.json").read_text())
    with pytest.raises(ValueError, match="field 'covariance_scale' needs a covariance head"):
        wcm.WindowCorrection(w, cfg, None, None)


def test_the_fitted_scale_gives_anees_one_on_its_flights_whatever_the_folders_scale(tmp_path):
    """c = mean NEES / 4 with scale 1; with c written, the NEES over the same looks, taken from the run by the
    metrics' own function, averages 4 (ANEES 1). A folder already scaled fits the same c."""
    from agents.evaluation.metrics import nees_values
    from agents.training.window import covariance_scale_fit, training_flights
    from radar_env.sim.episode import stack_episodes
    d, _ = _ensemble(tmp_path, [3, 4], "plain")
    fit = covariance_scale_fit(load_learned(d).policy, SMALL, 123)
    assert fit["looks"] > 500 and fit["invalid_looks"] == 0 and set(fit["suites"]) == {"random", "random_broad"}
    c = fit["covariance_scale"]
    assert c != 1.0
    ds, _ = _ensemble(tmp_path, [3, 4], "scaled", covariance_scale=c)
    again = covariance_scale_fit(load_learned(ds).policy, SMALL, 123)
    assert again["covariance_scale"] == c
    lt, nees = load_learned(ds), []
    for _, chunks in training_flights(SMALL, 123):
        for eps in chunks:
            run = lt.run(eps)
            moved = np.isfinite(run.extra["correction_m"])
            nees.append(nees_values((run.x - stack_episodes(eps).truth)[moved], run.P[moved]))
    nees = np.concatenate(nees)
    assert nees.size == fit["looks"]
    assert abs(nees.mean() / 4 - 1.0) < 1e-9


def test_covariance_scale_fit_refuses_a_suite_without_a_nees(tmp_path, monkeypatch):
    """A suite whose every moved look has a covariance that is not positive definite (e.g. every run failed) stops
    the fit in one line naming the suite, rather than fitting the scale on the other suites alone."""
    from agents.training import window
    d, _ = _ensemble(tmp_path, [3, 4], "plain")
    correction = load_learned(d).policy
    run, flights, suite = type(correction).run, window.training_flights, {}

    def marked(hp, seed):                   # the suite being fitted, for the run below
        for name, chunks in flights(hp, seed):
            suite["now"] = name
            yield name, chunks

    def broken_on_broad(self, eps, *a, **k):
        r = run(self, eps, *a, **k)
        if suite["now"] == "random_broad":
            r.P[...] = np.nan
        return r
    monkeypatch.setattr(window, "training_flights", marked)
    monkeypatch.setattr(type(correction), "run", broken_on_broad)
    with pytest.raises(ValueError, match="suite 'random_broad': no look the correction moves has a positive-defin"):
        window.covariance_scale_fit(correction, SMALL, 123)


def test_calibrate_script_writes_the_scale_and_its_record(tmp_path, capsys):
    import shutil
    folder = tmp_path / "window"
    shutil.copytree(BUNDLED_LEARNED["policy_window"], folder, ignore=shutil.ignore_patterns("seeds"))
    argv = [str(folder), "--seed", "123", "--episodes", json.dumps(SMALL["episodes"]), "--write"]
    before = json.loads((folder / "policy.json").read_text())
    fit = cwc.main(argv)
    meta = json.loads((folder / "policy.json").read_text())
    rec = json.loads((folder / "calibration.json").read_text())
    assert meta["covariance_scale"] == rec["covariance_scale"] == fit["covariance_scale"]
    assert {k: v for k, v in meta.items() if k != "covariance_scale"} == {
        k: v for k, v in before.items() if k != "covariance_scale"}                 # every other field kept
    assert rec["seed"] == 123 and rec["episodes"] == SMALL["episodes"] and rec["looks"] == fit["looks"]
    assert load_learned(folder).policy.covariance_scale == fit["covariance_scale"]
    assert "covariance_scale" in capsys.readouterr().out


@pytest.mark.parametrize("args, match", [
    (["--seed", "9999990"], r"--seed: the flights' seeds 9999990\.\.10300189 must lie in \[0, 10,000,000\)"),
    (["--seed", "9699900"], r"the flights' seeds 9699900\.\.10000099 must lie in"),   # the broad ones' end
    (["--seed", "-1"], "must lie in"),
    (["--seed", "1", "--episodes", '{"random": 0}'], r"random's flights must be an integer in \[1, 20000\]"),
    (["--seed", "1", "--episodes", '{"kim_lee_accel": 5}'], "suite 'kim_lee_accel' is not one of"),
    (["--seed", "1", "--episodes", "[1]"], "must be a non-empty JSON object"),
    (["--seed", "1", "--first-leg-min-s", "-5"], r"--first-leg-min-s must be in \[0, 600\] s"),
])
def test_calibrate_script_refuses_bad_arguments_in_one_line(tmp_path, args, match):
    d, _ = _ensemble(tmp_path, [3])
    with pytest.raises(SystemExit, match=match) as e:
        cwc.main([str(d), *args])
    assert "\n" not in str(e.value)


def test_calibrate_script_refuses_a_single_correction_and_writes_nothing_out_of_range(tmp_path, monkeypatch):
    w, mean, sd = _member(3)
    wcm.save_window_correction(tmp_path / "single", _folded(w, mean, sd), CFG, _env())
    with pytest.raises(SystemExit, match="not a window-correction ensemble .*scripts/make_window_ensemble.py"):
        cwc.main([str(tmp_path / "single"), "--seed", "1"])
    d, _ = _ensemble(tmp_path, [3])
    before = (d / "policy.json").read_text()
    monkeypatch.setattr(cwc, "covariance_scale_fit",
                        lambda *a: {"covariance_scale": 50.0, "looks": 1, "invalid_looks": 0, "suites": {}})
    with pytest.raises(SystemExit, match=r"covariance_scale' must be a number in \[0.1, 10\].*nothing written"):
        cwc.main([str(d), "--seed", "1", "--write"])
    assert (d / "policy.json").read_text() == before and not (d / "calibration.json").exists()


@pytest.mark.parametrize("folder", [BUNDLED_LEARNED["policy_window"],
                                    *sorted((BUNDLED_LEARNED["policy_window"] / "realisations").glob("*/"))],
                         ids=lambda f: f.name)
def test_the_bundled_scale_is_its_calibrations(folder):
    """policy_window's covariance_scale (and each other realisation's of its recipe) is calibration.json's, fitted for
    the networks it holds (sha256)."""
    import hashlib
    rec = json.loads((folder / "calibration.json").read_text())
    assert load_learned(folder).policy.covariance_scale == rec["covariance_scale"]
    assert rec["policy_npz_sha256"] == hashlib.sha256((folder / "policy.npz").read_bytes()).hexdigest()
    assert rec["looks"] == sum(s["looks"] for s in rec["suites"].values())


def test_make_window_ensemble_removes_a_stale_calibration(tmp_path):
    runs = [_run_folder(tmp_path, f"run{i}", 10 + i)[0] for i in range(2)]
    out = tmp_path / "ens"
    out.mkdir()
    (out / "calibration.json").write_text("{}")
    mwe.main([str(out), *map(str, runs), "--precision", "float64", "--base-precision", "float64"])
    assert not (out / "calibration.json").exists()
    assert "covariance_scale" not in json.loads((out / "policy.json").read_text())


def test_training_flights_chunks_are_drawn_as_before(monkeypatch):
    """Suites in order, chunks of 500 from the suite's first seed (broad ones 300,000 above), a suite's chunks its
    own even when drawn after the next suite was reached."""
    import agents.evaluation.suites as suites
    from agents.training import window
    calls = []
    monkeypatch.setattr(suites, "draw_suite", lambda gen, n, seed, random_config=None: calls.append((gen, n, seed)))
    hp = {"scenarios": ["random", "random_radars_broad"], "episodes": {"random": 1201, "random_radars_broad": 501},
          "first_leg_min_s": 0.0}
    suites_chunks = list(window.training_flights(hp, 1000))         # every suite reached before any chunk is drawn
    for _, chunks in suites_chunks:
        list(chunks)
    assert calls == [("random", 500, 1000), ("random", 500, 1500), ("random", 201, 2000),
                     ("random_radars", 500, 301000), ("random_radars", 1, 301500)]
