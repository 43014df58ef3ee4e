"""The turn-aware q-policy of --method backprop (``--hp turn_rate_max_deg_s``: the GRU also sets the turn rate of a
coordinated-turn prediction) and ``--hp init_from`` (start from a trained q-policy): the numpy policy equals the torch
model (q and omega, the gain folded into the saved weights); the torch lockstep's estimates equal the evaluation's
numba chain with the same turn rates; with its turn output at zero a model started from policy_bp filters exactly as
policy_bp; the loader and the CLI refuse what does not fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.policies.learned import load_learned  # noqa: E402
from agents.policies.recurrent import RecurrentQPolicy, load_recurrent_policy  # noqa: E402
from agents.training import backprop as bp  # noqa: E402
from agents.training.runs import load_hyperparams  # noqa: E402
from baselines.trackers import run_q_policy  # noqa: E402
from radar_env.envs.core import draw_setup_and_episode  # noqa: E402

W_MAX_DEG = 20.0


def _hp(**over):
    hp = load_hyperparams("backprop")
    hp.update(batch_episodes=3, chunk_looks=12, hidden_size=8, n_steps=2, eval_every=1,
              eval_scenarios={"random": 2, "random_radars": 2}, turn_rate_max_deg_s=W_MAX_DEG, turn_gain=0.5)
    hp.update(over)
    return hp


def _model(seed=0, scale=0.3, **over):
    hp, _, cfg = bp.check_hp(_hp(**over))
    torch.manual_seed(seed)
    model = bp.make_model(hp, cfg)
    with torch.no_grad():
        model.out.weight.normal_(0.0, scale)
    return model, cfg, hp


def _episodes(n=4, seed=0):
    return [draw_setup_and_episode("random", None, None, np.random.default_rng(seed + s)) for s in range(n)]


def test_numpy_turn_policy_equals_the_torch_model():
    model, cfg, _ = _model()
    assert model.n_out == 2 and model.chain == "torch"
    pol = model.inference_policy(cfg)
    assert pol.turn_aware and math.isclose(pol.turn_rate_max_rad_s, math.radians(W_MAX_DEG))
    rng = np.random.default_rng(0)
    n = 5
    h_t = torch.zeros((n, model.hidden_size), dtype=torch.float64)
    pol.reset(np.arange(n))
    worst = 0.0
    for _ in range(30):
        obs = rng.uniform(-1.0, 1.0, (n, model.input_size))
        with torch.no_grad():
            a, h_t = model.action(torch.tensor(obs), h_t)
            q_t, w_t = model.q_of_action(a[:, 0]).numpy(), model.w_max * a[:, 1].numpy()
        q_n, w_n = pol(obs, np.arange(n))
        worst = max(worst, np.max(np.abs(q_n / q_t - 1.0)), np.max(np.abs(w_n - w_t)))
    assert worst < 1e-12
    assert np.abs(w_n).max() > 1e-3       # the turn output is in play (the test can fail)


def test_turn_lockstep_equals_the_evaluation_chain():
    """forward_episodes (the torch chain stepped with the model's q and omega, the numba Tracker beside it) against
    run_q_policy (the evaluation: numba chain with the numpy policy's q and omega)."""
    model, cfg, _ = _model(seed=1, scale=0.5)
    eps = _episodes(3, seed=10)
    with torch.no_grad():
        x, looks = bp.forward_episodes(model, eps, cfg)
    run = run_q_policy(eps, model.inference_policy(cfg), "turn", cfg)
    w = run.extra["policy_turn_rate_deg_s"]
    assert np.nanmax(np.abs(w)) > 1.0
    x = x.numpy()
    compared = 0
    for b in range(len(eps)):
        k = looks.look_index[b]
        ok = looks.scored.numpy()[:, b]
        ref = run.x[b, k[ok]]
        np.testing.assert_allclose(x[b, ok, :2], ref[:, :2], rtol=0, atol=1e-6)
        compared += int(ok.sum())
    assert compared > 50


def test_start_from_policy_bp_with_zero_turn_is_policy_bp(tmp_path):
    lt = load_learned("policy_bp")
    hp, _, cfg = bp.check_hp(_hp(hidden_size=lt.policy.hidden_size, head=list(lt.policy.arch.get("head", [])),
                                 env_kwargs=_env_kwargs(lt)))
    model = bp.make_model(hp, cfg)
    model.start_from(str(lt.folder / "policy.npz"), cfg)
    eps = _episodes(4, seed=20)
    mine = run_q_policy(eps, model.inference_policy(cfg), "turn0", cfg)
    ref = run_q_policy(eps, lt.policy, "policy_bp", lt.env_config)
    assert np.array_equal(mine.q_m_s2, ref.q_m_s2, equal_nan=True)
    assert np.nanmax(np.abs(mine.extra["policy_turn_rate_deg_s"])) == 0.0
    np.testing.assert_allclose(mine.x, ref.x, rtol=1e-12, atol=1e-9)
    # saved and loaded without pickle: the same policy
    model.save_policy(tmp_path / "p", cfg, hp["env_kwargs"])
    pol, _ = load_recurrent_policy(tmp_path / "p" / "policy.npz")
    assert pol.turn_aware
    again = run_q_policy(eps, pol, "turn0", cfg)
    assert np.array_equal(again.x, mine.x, equal_nan=True)
    # a turn-aware policy continues a turn-aware model (its rows, its gain unfolded) but not a q-only one
    with torch.no_grad():
        model.out.weight[1].normal_(0.0, 0.3)
    model.save_policy(tmp_path / "t", cfg, hp["env_kwargs"])
    other = bp.make_model(dict(hp, turn_gain=0.25), cfg)
    other.start_from(str(tmp_path / "t" / "policy.npz"), cfg)
    for k, v in model.policy_weights().items():
        np.testing.assert_allclose(other.policy_weights()[k], v, rtol=1e-14, atol=1e-15)
    q_only = bp.make_model({k: v for k, v in hp.items() if k not in ("turn_rate_max_deg_s", "turn_gain")}, cfg)
    with pytest.raises(ValueError, match="turn-aware policy; this model outputs q only"):
        q_only.start_from(str(tmp_path / "t" / "policy.npz"), cfg)


def _env_kwargs(lt):
    import json
    return json.loads((lt.folder / "env_config.json").read_text())


def test_refusals(tmp_path):
    lt = load_learned("policy_bp")
    hp, _, cfg = bp.check_hp(_hp(env_kwargs=_env_kwargs(lt)))     # GRU 8: not policy_bp's
    model = bp.make_model(hp, cfg)
    with pytest.raises(ValueError, match="--hp init_from: .*GRU"):
        model.start_from(str(lt.folder / "policy.npz"), cfg)
    with pytest.raises(ValueError, match="--hp init_from: policy file"):
        model.start_from(str(tmp_path / "none.npz"), cfg)
    for k, v in (("turn_rate_max_deg_s", -1.0), ("turn_rate_max_deg_s", 200.0), ("turn_gain", 0.0),
                 ("init_from", "")):
        with pytest.raises(ValueError, match=f"--hp {k}"):
            bp.check_hp(_hp(**{k: v}))
    imm = load_hyperparams("backprop_imm_cv_ct")
    with pytest.raises(ValueError, match="--hp turn_rate_max_deg_s: an option of the CV q-policy"):
        bp.check_hp({**imm, "turn_rate_max_deg_s": 10.0})
    with pytest.raises(ValueError, match="turn_rate_max_rad_s"):
        bp.CVQModel(5, 4, [], np.array([1.0, 10.0]), 2.0, turn_rate_max_rad_s=4.0)
    # the numpy policy: outputs and bound must agree; the env's action cannot carry a turn rate
    model, cfg, _ = _model()
    w = model.policy_weights()
    with pytest.raises(ValueError, match="n_out"):
        RecurrentQPolicy(w, model.architecture(), cfg.q_levels_g)
    pol = model.inference_policy(cfg)
    with pytest.raises(ValueError, match="turn-aware"):
        pol.predict(np.zeros(model.input_size))
    # a policy.json whose model and outputs disagree
    model.save_policy(tmp_path / "q", cfg, bp.check_hp(_hp())[1])
    import json
    meta = json.loads((tmp_path / "q" / "policy.json").read_text())
    meta["model"] = "cv"
    (tmp_path / "q" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="output"):
        load_recurrent_policy(tmp_path / "q" / "policy.npz")
    meta["model"], meta["turn_rate_max_rad_s"] = "cv_turn", 10.0
    (tmp_path / "q" / "policy.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="turn_rate_max_rad_s"):
        load_recurrent_policy(tmp_path / "q" / "policy.npz")


def test_turn_training_runs_and_its_folder_loads(tmp_path):
    run = bp.train_backprop(_hp(), seed=0, out=tmp_path, progress=False, verbose=0, run_name="turn")
    lt = load_learned(str(run))
    assert lt.policy.turn_aware
    eps = _episodes(2, seed=30)
    r = run_q_policy(eps, lt.policy, "turn", lt.env_config)
    assert np.isfinite(r.x[np.isfinite(r.q_m_s2)]).all()


def test_stonesoup_q_policy_refuses_a_turn_aware_policy(tmp_path):
    pytest.importorskip("stonesoup")
    from agents.policies.stonesoup_qpolicy import load_q_policy
    run = bp.train_backprop(_hp(n_steps=1), seed=0, out=tmp_path, progress=False, verbose=0, run_name="turn")
    with pytest.raises(ValueError, match="turn-aware"):
        load_q_policy(str(run))
