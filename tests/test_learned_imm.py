"""The learned IMM (agents/policies/learned_imm.py, agents/training/learned_imm.py): at its initial weights it is
imm_cv_ct with its tuned values (numpy inference and torch forward, to 1e-9, on drawn episodes of several
scenario kinds), and built around the bank of CT modes (``--hp imm=imm_ct_bank``) it is imm_ct_bank, with range rate
imm_ct_bank_rdot; with other weights the numpy GRU + numba per-look kernel equals the torch forward in lockstep to
1e-9 (estimate, covariance, mode probabilities, the parameters); every output inside its documented range; the
checkpoint round trip without pickle; a tiny training run end to end."""

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.evaluation.suites import draw_suite  # noqa: E402
from agents.policies import learned_imm as LI  # noqa: E402
from agents.training import backprop as bp  # noqa: E402
from agents.training.runs import load_hyperparams  # noqa: E402
from baselines import imm_cv_ct_runner as I  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402

TOL = 1e-9


def _short(eps, n):
    from test_torch_chain import _short as cut
    return [cut(e, min(e.n_looks, n)) for e in eps]


@pytest.fixture(scope="module")
def setup():
    hp = dict(load_hyperparams("backprop_imm_cv_ct"), hidden_size=16, chain="torch")    # forwards without training
    return bp.check_hp(hp)


@pytest.fixture(scope="module", params=["imm_cv_ct", "imm_ct_bank", "imm_ct_bank_rdot"])
def around(request):
    """The setup of a learned IMM around ``imm_cv_ct``, around the bank of CT modes (``--hp imm=imm_ct_bank``) and
    around the bank with range rate (the same with ``radial_velocity``: ``imm_ct_bank_rdot``), and the name of that
    classical tracker."""
    hp = dict(load_hyperparams("backprop_imm_cv_ct"), hidden_size=16, chain="torch",
              imm=request.param.removesuffix("_rdot"))
    if request.param.endswith("_rdot"):
        hp["env_kwargs"] = {**hp["env_kwargs"], "radial_velocity": True}
    return bp.check_hp(hp), request.param


@pytest.fixture(scope="module")
def episodes():
    eps = (draw_suite("random", 4, seed=31) + draw_suite("random_radars", 3, seed=31)
           + draw_suite("bizup2002", 1, seed=31) + draw_suite("adsb_dev", 1, seed=31)
           + draw_suite("adrian_flower", 1, seed=31))
    return _short(eps, 400)


def _rel(a, b):
    m = np.isfinite(b)
    assert np.array_equal(m, np.isfinite(a))
    return float(np.max(np.abs(a[m] - b[m]) / (np.abs(b[m]) + 1.0)))


def _rel_P(a, b):
    m = np.isfinite(b[..., 0, 0])
    assert np.array_equal(m, np.isfinite(a[..., 0, 0]))
    return float(np.max(np.abs(a[m] - b[m]) / np.abs(b[m]).max(axis=(-2, -1), keepdims=True)))


def _torch_run(model, eps, cfg):
    rec = []
    with torch.no_grad():
        x, looks = bp.forward_episodes(model, eps, cfg, lambda j: rec.append((model.record, model.delta)))
    m = looks.scored_mask.numpy()
    P = torch.stack([r.P for r, _ in rec]).permute(3, 0, 1, 2).numpy()
    mu = torch.stack([torch.exp(r.modes.log_mu[model._inverse]) for r, _ in rec]).permute(2, 0, 1).numpy()
    delta = torch.stack([d for _, d in rec], 1).numpy()
    return x.numpy(), P, mu, delta, looks, m


def test_initial_weights_are_imm_cv_ct(around, episodes):
    (hp, env_kwargs, cfg), name = around
    model = bp.make_model(hp, cfg)
    assert model.spec.is_bank == name.startswith("imm_ct_bank") and cfg.radial_velocity == name.endswith("_rdot")
    ref = run_tracker(name, episodes)
    got = model.inference(cfg, env_kwargs).run(episodes)
    assert _rel(got.x, ref.x) < TOL and _rel_P(got.P, ref.P) < TOL
    np.testing.assert_array_equal(got.start_index, ref.start_index)
    np.testing.assert_allclose(got.extra["maneuver_probability"], ref.extra["maneuver_probability"], atol=TOL)
    x, P, mu, delta, looks, m = _torch_run(model, episodes, cfg)
    assert _rel(x[m], looks.align(ref.x).numpy()[m]) < TOL
    assert _rel_P(P[m], looks.align(ref.P).numpy()[m]) < TOL
    assert np.all(delta == 0.0)
    vec = I.look_parameter_vector(I.tuned_imm_cv_ct_spec(name))
    for i, n in enumerate(I.LOOK_PARAMS):
        np.testing.assert_allclose(got.extra[f"param_{n}"][np.isfinite(got.extra[f"param_{n}"])], vec[i], rtol=1e-13)


def test_numpy_inference_equals_the_torch_forward(around, episodes):
    (hp, env_kwargs, cfg), name = around
    torch.manual_seed(3)
    model = bp.make_model(hp, cfg)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.4 * torch.randn_like(p))
    got = model.inference(cfg, env_kwargs).run(episodes)
    x, P, mu, delta, looks, m = _torch_run(model, episodes, cfg)
    ref = run_tracker(name, episodes)
    assert np.nanmax(np.abs(got.x - ref.x)) > 50.0                       # the parameters moved the estimate
    errs = {"x": _rel(x[m], looks.align(got.x).numpy()[m]), "P": _rel_P(P[m], looks.align(got.P).numpy()[m]),
            "mu_cv": float(np.max(np.abs(1.0 - mu[m][:, 0] - looks.align(got.extra["maneuver_probability"])
                                         .numpy()[m])))}
    phys = model.pmap.physical(delta[m])
    for i, n in enumerate(model.names):
        errs[n] = float(np.max(np.abs(phys[:, i] - looks.align(got.extra[f"param_{n}"]).numpy()[m]) / phys[:, i]))
    assert max(errs.values()) < TOL, errs
    spread = phys.max(0) / phys.min(0)
    assert np.all(spread > 1.01), spread                                # the network does vary them per look


def test_outputs_stay_inside_the_documented_ranges():
    spec = I.tuned_imm_cv_ct_spec()
    names = I.look_parameter_names(spec)
    pm = LI.ParamMap({n: getattr(spec, n) for n in names}, names)
    rng = np.random.default_rng(0)
    delta = np.concatenate([rng.normal(0, 30, (500, len(names))), np.full((1, len(names)), 1e6),
                            np.full((1, len(names)), -1e6), np.zeros((1, len(names)))])
    p = pm.physical(delta)
    assert np.all(p >= pm.lo) and np.all(p <= pm.hi)
    np.testing.assert_allclose(p[-1], I.look_parameter_vector(spec), rtol=1e-14)
    I.check_look_parameters(spec, p)                                     # the kernel accepts every one
    # torch's transform is numpy's
    s_t = pm.transformed(torch.as_tensor(delta), torch, pm.tensors(torch)).numpy()
    np.testing.assert_allclose(s_t, pm.transformed(delta), rtol=1e-14, atol=1e-13)   # (s is O(10))
    # monotone in each offset
    d = np.zeros((50, len(names)))
    d[:, 2] = np.linspace(-5, 5, 50)
    assert np.all(np.diff(pm.physical(d)[:, 2]) > 0)


def _saved_model(setup, directory, seed, scale):
    """A model whose output layer is moved by ``scale`` x N(0, 1), saved in ``directory``: ``(model, path)``."""
    hp, env_kwargs, cfg = setup
    torch.manual_seed(seed)
    model = bp.make_model(hp, cfg)
    with torch.no_grad():
        model.out.weight.add_(scale * torch.randn_like(model.out.weight))
    return model, model.save_policy(directory, cfg, env_kwargs)


def test_checkpoint_round_trip_without_pickle(setup, episodes, tmp_path):
    hp, env_kwargs, cfg = setup
    model, path = _saved_model(setup, tmp_path / "ck", 1, 0.1)
    assert LI.is_learned_imm_checkpoint(path) and not LI.is_learned_imm_checkpoint(tmp_path)
    with np.load(path, allow_pickle=False) as z:
        assert set(z.files) == set(LI.weight_shapes(model.architecture()))
    eps = episodes[:3]
    a = LI.run_learned_imm(eps, path)
    b = model.inference(cfg, env_kwargs).run(eps)
    np.testing.assert_array_equal(a.x, b.x)
    meta = json.loads((tmp_path / "ck" / "policy.json").read_text())
    meta["version"] = 99
    (tmp_path / "ck" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="version"):
        LI.load_learned_imm(path)
    with pytest.raises(ValueError, match="not a learned IMM checkpoint"):
        LI.load_learned_imm(tmp_path / "nothing" / "policy.npz")


def test_tiny_training_run(tmp_path, setup):
    """``train --method backprop --tracker imm_cv_ct`` end to end, with its default chain (the compiled look): the
    shared trainer runs the learned IMM; at step 0 it is its classical IMM (the validation's ratio is that IMM's); the
    output layer moves; the checkpoints are the learned IMM's format. Around the bank of CT modes with 6 rows and a GRU
    of 16, the shapes of test_compiled_look_equals_the_eager_look[bank]: one cold compile of the look serves both
    (inductor's cache), about a minute of the suite's time."""
    from agents.training.train import main
    run = main(["--method", "backprop", "--tracker", "imm_cv_ct", "--out", str(tmp_path), "--name", "t", "--seed", "5",
                "--no-progress", "--quiet", "--hp", "n_steps=2", "--hp", "batch_episodes=6", "--hp", "chunk_looks=8",
                "--hp", "eval_every=1", "--hp", "hidden_size=16", "--hp", 'eval_scenarios={"random": 3}',
                "--hp", 'select_on=["random"]', "--hp", 'imm="imm_ct_bank"'])
    s = json.loads((run / "summary.json").read_text())
    assert s["tracker"] == "imm_cv_ct" and s["steps"] == 2 and len(s["selection_history"]) == 3
    first = s["selection_history"][0]
    from agents.training.selection import pooled_rmse
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("random", 3, seed=900_000)
    ref = pooled_rmse(stack_episodes(eps), run_tracker("imm_ct_bank", eps))
    assert first["random_rmse_m"] == pytest.approx(ref, rel=1e-9)            # it starts as imm_cv_ct
    assert LI.is_learned_imm_checkpoint(run / "best" / "policy.npz") and LI.is_learned_imm_checkpoint(run)
    w = np.load(run / "policy.npz", allow_pickle=False)["out.weight"]
    assert np.any(w != 0.0)                                                   # the output layer moved
    config = json.loads((run / "config.json").read_text())
    assert config["tracker"] == "imm_cv_ct" and config["imm"] == "imm_ct_bank"


def test_a_learned_imm_runs_wherever_a_policy_runs(setup, tmp_path):
    """``--policy-imm-bp``: the evaluation, the generalisation's scorer and a Ray worker's blob run the learned IMM
    as its own ``run`` does (load_policy returns it as a tracker)."""
    from agents.evaluation.evaluate import main
    from agents.evaluation.parallel import _policy_blob, _policy_in_worker
    from agents.evaluation.runner import run_one
    from agents.policies.loading import load_policy
    _, path = _saved_model(setup, tmp_path / "imm", 2, 0.2)
    imm, cfg2 = load_policy(path)
    assert imm.is_tracker and cfg2 == imm.cfg
    eps = draw_suite("random", 3, seed=10_000_000)
    ref = imm.run(eps, "policy_imm_bp")
    got = run_one("policy_imm_bp", eps, imm, cfg2)
    np.testing.assert_array_equal(got.x, ref.x)
    blob = _policy_blob(path)
    assert list(blob) == ["policy.npz", "policy.json", "env_config.json"]
    w_imm, _ = _policy_in_worker(blob)
    np.testing.assert_array_equal(run_one("policy_imm_bp", eps, w_imm, None).x, ref.x)
    out = tmp_path / "r.json"
    res = main(["--policy-imm-bp", str(path), "--trackers", "policy_imm_bp,imm_cv_ct", "--scenario", "random",
                "--runs", "3", "--no-plots", "--quiet", "--json", str(out)])
    t = res["random"]["trackers"]
    from agents.evaluation.metrics import evaluate_run
    from radar_env.sim.episode import stack_episodes
    assert t["policy_imm_bp"]["pos_rmse_m"] == evaluate_run(stack_episodes(eps), ref)["pos_rmse_m"]
    assert t["policy_imm_bp"]["pos_rmse_m"] != t["imm_cv_ct"]["pos_rmse_m"]
    assert json.loads(out.read_text())["meta"]["policy_imm_bp"] == str(path)


@pytest.mark.parametrize("rdot, imm", [(True, "imm_cv_ct"), (False, "imm_ct_bank")], ids=["range_rate", "bank"])
def test_compiled_look_equals_the_eager_look(rdot, imm, monkeypatch):
    """``chain="compiled"`` (the default: :func:`agents.training.learned_imm.look_step` under ``torch.compile``)
    against ``chain="torch"`` (eager) from the same random weights, over 12 chunks of random flights seen by two
    sites scanning together (rows finish episodes and start new ones; the chunks hold simultaneous looks (dt = 0),
    missed looks, and CT modes near omega = 0 at each track start): every look of the compiled model runs compiled,
    in one graph; the same loss and gradient of every parameter to 1e-8 relative, the same estimates (the carried
    states that require a gradient at a chunk's start, which make the one graph, change no gradient). Two cases,
    each a cold compile of about a minute: imm_cv_ct's one CT mode with the range-rate update, and the bank of six
    CT modes (``--hp imm=imm_ct_bank``) on position only; together they run every operation of the look (the
    position-only IMM of one CT mode is the bank's code with other constants)."""
    from dataclasses import replace
    from agents.training import learned_imm as LM
    from test_torch_chain import TWO_SITES_SAME_TIME
    env = {k: v for k, v in load_hyperparams("backprop_imm_cv_ct")["env_kwargs"].items()
           if k not in ("scenario", "random_config")}
    res, seen = {}, {"dt0": 0, "missed": 0, "compiled_looks": 0, "looks": 0}
    compiled = LM._compiled

    def counted():                                             # every look of the compiled model runs compiled
        seen["compiled_looks"] += 1
        return compiled()
    monkeypatch.setattr(LM, "_compiled", counted)
    from torch._dynamo.utils import counters
    torch._dynamo.reset()
    counters.clear()
    for chain in ("torch", "compiled"):
        hp, _, cfg = bp.check_hp(dict(load_hyperparams("backprop_imm_cv_ct"), hidden_size=16, chain=chain, imm=imm,
                                      env_kwargs={**env, "radial_velocity": rdot}))
        cfg = replace(cfg, radar=TWO_SITES_SAME_TIME)      # the random flights seen by two sites scanning together
        torch.manual_seed(6)
        model = bp.make_model(hp, cfg)
        assert model.chain == chain and model.spec.is_bank == (imm == "imm_ct_bank")
        with torch.no_grad():
            model.out.weight.normal_(0.0, 0.3)
        trainer = bp.StreamingTrainer(model, cfg, 6, 40, 9)
        out = []
        for _ in range(12):
            model.zero_grad()
            loss, looks = trainer.chunk()
            loss.backward()
            out.append((float(loss.detach()), [p.grad.clone() for p in model.parameters()], model.record.x.detach()))
            s = looks.scored.numpy()
            seen["dt0"] += int((s & (looks.dt_s.numpy() == 0.0)).sum())
            seen["missed"] += int((s & ~looks.detected.numpy()).sum())
            seen["looks"] += looks.J if chain == "compiled" else 0
        res[chain] = out
    assert trainer.episodes_done >= 2 and seen["dt0"] > 0 and seen["missed"] > 0, seen
    assert trainer.tracker.radial_velocity == rdot and (looks.rdot is not None) == rdot
    assert seen["compiled_looks"] == seen["looks"] > 0         # the compiled path ran, at every look
    assert counters["stats"]["unique_graphs"] == 1, dict(counters["stats"])   # one graph: no recompile per chunk
    for (lt, gt, xt), (lc, gc, xc) in zip(res["torch"], res["compiled"]):
        assert abs(lc / lt - 1.0) < 1e-8
        for a, b in zip(gc, gt):
            assert float((a - b).abs().max()) <= 1e-8 * float(b.abs().max())
        assert float((xc - xt).abs().max()) <= 1e-8 * float(xt.abs().max())


def test_compiled_chain_needs_a_compiler(monkeypatch):
    """Without the C++ compiler torch.compile calls, ``chain="compiled"`` is refused when the model is built, in one
    line naming the hyperparameter and the way out; ``chain="torch"`` still builds."""
    from torch._inductor import config
    from agents.training import learned_imm as LM
    assert LM.compiler_available()                             # this machine's (the tests need one)
    monkeypatch.setattr(config.cpp, "cxx", (None, "no-such-compiler-xyz"))
    assert not LM.compiler_available()
    hp, _, cfg = bp.check_hp(dict(load_hyperparams("backprop_imm_cv_ct"), hidden_size=8))
    with pytest.raises(ValueError, match=r"--hp chain: 'compiled'.*C\+\+ compiler.*--hp chain=torch") as e:
        bp.make_model(hp, cfg)
    assert "\n" not in str(e.value) and "no-such-compiler-xyz" in str(e.value)
    assert bp.make_model(dict(hp, chain="torch"), cfg).chain == "torch"
