"""End-to-end training by backpropagation (agents/training/backprop.py) and its recurrent policies
(agents/policies/recurrent.py): the numpy GRU equals torch's cell to 1e-12; the untrained policy is kf_tuned; the
trainer's lockstep observations are the env's own, bit for bit, for the same actions; the gradient through the
lockstep equals finite differences; acting step by step in RadarTrack-v0 gives the batched evaluation's estimates
to 1e-9; checkpoints load without pickle and bad ones are refused; a run folder is complete, resumes after a kill
and refuses another configuration; the CLI refuses what does not apply."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

import radar_env  # noqa: E402,F401 - registers RadarTrack-v0
from agents.policies.loading import load_policy  # noqa: E402
from agents.policies.recurrent import (RecurrentQPolicy, gru_cell, load_recurrent_policy,  # noqa: E402
                                       save_recurrent_policy)
from agents.training import backprop as bp  # noqa: E402
from agents.training.runs import load_hyperparams  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from baselines.trackers import run_q_policy  # noqa: E402
from baselines.tuned_params import tuned_parameters  # noqa: E402
from radar_env.envs.core import draw_setup_and_episode  # noqa: E402
from radar_env.common.units import G0_M_S2  # noqa: E402


def _hp(**over):
    hp = load_hyperparams("backprop")
    hp.update(batch_episodes=4, chunk_looks=12, hidden_size=8, n_steps=3, eval_every=2,
              eval_scenarios={"random": 3, "random_radars": 2})
    hp.update(over)
    return hp


def _model(hp=None, seed=0, scale=0.3, head=None):
    """A CV model with random (non-zero) output weights, so that q varies with the observation."""
    hp = dict(hp or _hp())
    if head is not None:
        hp["head"] = head
    hp, _, cfg = bp.check_hp(hp)
    torch.manual_seed(seed)
    model = bp.make_model(hp, cfg)
    with torch.no_grad():
        model.out.weight.normal_(0.0, scale)
    return model, cfg, hp


# ------------------------------------------------------------------------------------------------ the network
@pytest.mark.parametrize("head", [[], [6, 5]], ids=["gru", "gru+head"])
def test_numpy_gru_equals_torch_gru(head):
    model, cfg, _ = _model(head=head)
    pol = model.inference_policy(cfg)
    rng = np.random.default_rng(0)
    n, F = 7, model.input_size
    h_t = torch.zeros((n, model.hidden_size), dtype=torch.float64)
    h_n = pol.initial_state(n)
    worst = 0.0
    for _ in range(60):
        obs = rng.uniform(-1.0, 1.0, (n, F))
        with torch.no_grad():
            a_t, h_t = model.action(torch.tensor(obs), h_t)
            q_t = model.q_of_action(a_t)
        a_n, h_n = pol.act(obs, h_n)
        worst = max(worst, np.max(np.abs(a_n - a_t.numpy())), np.max(np.abs(h_n - h_t.numpy())),
                    np.max(np.abs(pol.q_of_actions(a_n) / q_t.numpy() - 1.0)))
    assert worst < 1e-12
    # the cell alone, against torch.nn.GRUCell with other weights
    cell = torch.nn.GRUCell(3, 4, dtype=torch.float64)
    x, h = torch.randn(5, 3, dtype=torch.float64), torch.randn(5, 4, dtype=torch.float64)
    ref = cell(x, h).detach().numpy()
    got = gru_cell(x.numpy(), h.numpy(), *(p.detach().numpy() for p in (cell.weight_ih, cell.weight_hh, cell.bias_ih,
                                                                         cell.bias_hh)))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14)


def test_untrained_policy_is_kf_tuned():
    hp, _, cfg = bp.check_hp(_hp())
    model = bp.make_model(hp, cfg)
    q0 = tuned_parameters()["kf"]["q_g"] * G0_M_S2
    obs = torch.tensor(np.random.default_rng(1).uniform(-1, 1, (9, model.input_size)))
    with torch.no_grad():
        a, _ = model.action(obs, torch.randn(9, model.hidden_size, dtype=torch.float64))
        np.testing.assert_allclose(model.q_of_action(a).numpy(), q0, rtol=1e-12)
    eps = [draw_setup_and_episode("random", None, None, np.random.default_rng(s)) for s in range(4)]
    run = run_q_policy(eps, model.inference_policy(cfg), "bp", cfg)
    ref = run_tracker("kf_tuned", eps, cfg)
    m = np.isfinite(ref.x)
    np.testing.assert_allclose(run.x[m], ref.x[m], rtol=1e-10, atol=1e-6)


def test_model_refuses_an_initial_q_outside_the_action_range():
    with pytest.raises(ValueError, match="q_init_m_s2"):
        bp.CVQModel(5, 4, [], np.array([1.0, 10.0]), 20.0)


# ------------------------------------------------------------------------------------------------ the lockstep
class _Recording(bp.CVQModel):
    """A CV model that records, per look, the observation it read and the action it chose."""

    def step(self, looks, j, obs):
        self.seen.append(obs.numpy().copy())
        x, q = super().step(looks, j, obs)
        self.actions.append(self.last_a.copy())
        self.active.append(looks.scored[j].numpy().copy())
        return x, q

    def action(self, obs, h):
        a, h = super().action(obs, h)
        self.last_a = a.detach().numpy().copy()
        return a, h


class _RecordingCompiled(bp.CVQModel):
    """The same records from the compiled chunk (chain="compiled"): the per-look head's action (a (B, H) state: the
    pass without a graph, whose q the Tracker steps with) and the observation array as the network read it."""

    def chunk_forward(self, tracker, layout, obs, looks):
        self._obs = obs
        self.active.extend(looks.scored.numpy().copy())
        return super().chunk_forward(tracker, layout, obs, looks)

    def _head(self, h):
        a = super()._head(h)
        if h.dim() == 2:
            self.seen.append(self._obs.astype(np.float64))
            self.actions.append(a.detach().numpy().copy())
        return a


@pytest.mark.parametrize("chain", bp.CHAINS)
def test_lockstep_observations_equal_the_env(chain):
    hp, env_kwargs, cfg = bp.check_hp(_hp(chunk_looks=25))
    torch.manual_seed(3)
    ref = bp.make_model(hp, cfg)
    model = (_Recording if chain == "torch" else _RecordingCompiled)(
        ref.input_size, ref.hidden_size, [], ref.levels_m_s2, tuned_parameters()["kf"]["q_g"] * G0_M_S2, chain=chain)
    model.load_state_dict(ref.state_dict())
    with torch.no_grad():
        model.out.weight.normal_(0.0, 0.2)
    model.seen, model.actions, model.active = [], [], []
    seeds = [11, 12, 13]
    trainer = bp.StreamingTrainer(model, cfg, len(seeds), hp["chunk_looks"], 0,
                                  rngs=[np.random.default_rng(s) for s in seeds])
    first_obs = trainer.obs.copy()
    for _ in range(12):                    # several chunks: rows finish episodes and start new ones
        trainer.chunk()
    assert trainer.episodes_done >= 2
    seen, acts, active = np.array(model.seen), np.array(model.actions), np.array(model.active)
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in env_kwargs.items()}
    kw["random_config"] = env_kwargs["random_config"]
    compared = 0
    for r, s in enumerate(seeds):
        env = gym.make("RadarTrack-v0", **kw)
        obs, _ = env.reset(seed=s)
        assert np.array_equal(obs, first_obs[r])
        for t in np.flatnonzero(active[:, r]):
            assert np.array_equal(seen[t, r].astype(np.float32), obs), (r, t)   # the obs the network read
            obs, _, term, trunc, _ = env.step(np.array([acts[t, r]]))
            compared += 1
            if term:                       # the env ends an episode at a lost track; the trainer plays on
                break
            if trunc:                      # the row's next episode: the env's next reset on the same generator
                obs, _ = env.reset()
    assert compared > 3 * 100


@pytest.mark.parametrize("chain", bp.CHAINS)
def test_lockstep_gradient_equals_finite_differences(chain):
    """With the output layer's weight at zero, q does not depend on the observation, so the loss of one chunk is a
    function of the output bias alone: autograd through the lockstep equals central differences."""
    hp, _, cfg = bp.check_hp(_hp(chunk_looks=30, batch_episodes=3, chain=chain))

    def chunk_loss(bias, grad=False):
        torch.manual_seed(0)
        model = bp.make_model(hp, cfg)
        with torch.no_grad():
            model.out.bias.fill_(bias)
        trainer = bp.StreamingTrainer(model, cfg, 3, hp["chunk_looks"], 5)
        loss, _ = trainer.chunk()
        if grad:
            loss.backward()
            return float(loss.detach()), float(model.out.bias.grad[0])
        return float(loss.detach())

    b0 = 0.2
    _, g = chunk_loss(b0, grad=True)
    h = 1e-5
    fd = (chunk_loss(b0 + h) - chunk_loss(b0 - h)) / (2 * h)
    assert g != 0.0 and math.isclose(g, fd, rel_tol=1e-5)


@pytest.mark.parametrize("rdot,head", [(False, []), (True, [6, 5])], ids=["position", "range_rate+head"])
def test_compiled_chunk_equals_the_torch_lockstep(rdot, head):
    """chain="compiled" against the reference chain="torch" over several chunks (rows finish episodes and start new
    ones): the same loss and gradient (1e-10 relative), the same observations; the q the Tracker stepped with equals
    the q the gradient is taken at to 1e-12 relative."""
    # the evaluation's random flights (~165 looks): rows finish episodes within the test's chunks
    env = {k: v for k, v in load_hyperparams("backprop")["env_kwargs"].items() if k not in ("scenario", "random_config")}
    over = {"chunk_looks": 30, "batch_episodes": 5, "head": head, "env_kwargs": {**env, "radial_velocity": rdot}}
    res = {}
    for chain in bp.CHAINS:
        model, cfg, hp = _model(_hp(chain=chain, **over), seed=4, scale=0.5)
        trainer = bp.StreamingTrainer(model, cfg, 5, 30, 7)
        out = []
        for _ in range(8):
            model.zero_grad()
            loss, _ = trainer.chunk()
            loss.backward()
            out.append((float(loss.detach()), [p.grad.clone() for p in model.parameters()], trainer.obs.copy(),
                        model.chunk_q))
        res[chain] = out
    assert trainer.episodes_done >= 2 and trainer.tracker.radial_velocity == rdot
    for (lt, gt, ot, _), (lc, gc, oc, (q_tracker, q_chain)) in zip(res["torch"], res["compiled"]):
        assert abs(lc / lt - 1.0) < 1e-10
        for a, b in zip(gc, gt):
            assert float((a - b).abs().max()) <= 1e-10 * float(b.abs().max())
        np.testing.assert_allclose(oc, ot, rtol=1e-5, atol=1e-6)     # float32 observations
        np.testing.assert_allclose(q_chain, q_tracker, rtol=1e-12, atol=0)


def test_chunk_looks_equal_the_full_store():
    """backprop.chunk_looks (Tracker.look_window: the chunk's looks only) equals looks_from_arrays over look_data."""
    from radar_env.filters import torch_chain as tc
    model, cfg, _ = _model(_hp(), scale=0.5)
    trainer = bp.StreamingTrainer(model, cfg, 4, 30, 2)
    for _ in range(6):
        tr = trainer.tracker
        k0 = tr.k.copy()
        cut = np.minimum(tr.n_looks, k0 + 30)
        got = bp.chunk_looks(tr, k0, cut)
        get = tr.look_data
        ref = tc.looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"), cut, k0,
                                   tr.t_last)
        for f in ref._fields:
            a, b = getattr(got, f), getattr(ref, f)
            if f == "rdot":
                assert a is None and b is None
            elif torch.is_tensor(b):
                assert a.dtype == b.dtype and torch.equal(torch.nan_to_num(a), torch.nan_to_num(b)), f
            else:
                assert np.array_equal(a, b), f
        trainer.chunk()


# ------------------------------------------------------------------------------------------------ acting in the env
def test_env_acting_equals_the_batched_evaluation(tmp_path):
    model, cfg, hp = _model(scale=0.2)
    path = save_recurrent_policy(tmp_path, model.policy_weights(), model.policy_config(cfg), hp["env_kwargs"])
    policy, cfg2 = load_policy(path)
    assert isinstance(policy, RecurrentQPolicy) and cfg2 == cfg
    seeds = [21, 22, 23, 24]
    eps = [draw_setup_and_episode(cfg.scenario, cfg.radar, cfg.random_scenario_config, np.random.default_rng(s),
                                  cfg.warmup_scans) for s in seeds]
    run = run_q_policy(eps, policy, "bp", cfg)
    q = run.q_m_s2[np.isfinite(run.q_m_s2)]
    assert q.std() / q.mean() > 0.05                       # the policy does vary q
    env = gym.make("RadarTrack-v0", **{k: (tuple(v) if isinstance(v, list) else v) for k, v in hp["env_kwargs"].items()})
    worst, n = 0.0, 0
    for r, s in enumerate(seeds):
        obs, info = env.reset(seed=s)
        state, start = None, True
        k = int(run.start_index[r])
        while True:
            action, state = policy.predict(obs, state, episode_start=start)
            obs, _, term, trunc, info = env.step(action)
            start = False
            est = run.x[r, k]
            worst = max(worst, float(np.max(np.abs(info["estimate"] - est) / (np.abs(est) + 1.0))))
            assert info["q_m_s2"] == pytest.approx(run.q_m_s2[r, k], rel=1e-12)
            k, n = k + 1, n + 1
            if term or trunc:
                break
        assert k == eps[r].n_looks or term      # the env ends an episode early at a lost track, not later
    assert n > 300 and worst < 1e-9


def test_predict_carries_and_clears_the_state():
    model, cfg, _ = _model(scale=0.5)
    pol = model.inference_policy(cfg)
    obs = np.random.default_rng(2).uniform(-1, 1, (5, 3, model.input_size))
    a1, s = pol.predict(obs[0], None, episode_start=np.ones(3, bool))
    a2, s2 = pol.predict(obs[1], s, episode_start=np.array([False, True, False]))
    fresh, _ = pol.predict(obs[1][1], None)
    assert a1.shape == (3, 1) and fresh.shape == (1,)
    assert a2[1, 0] == pytest.approx(fresh[0], abs=1e-12)     # row 1 started again: no memory of obs[0]
    again, _ = pol.predict(obs[1], s, episode_start=False)
    assert again[0, 0] == a2[0, 0] and abs(again[1, 0] - a2[1, 0]) > 1e-6
    assert np.all(np.abs(a2) <= 1.0)


# ------------------------------------------------------------------------------------------------ checkpoints
def test_checkpoint_round_trip_and_refusals(tmp_path):
    model, cfg, hp = _model()
    path = save_recurrent_policy(tmp_path / "ok", model.policy_weights(), model.policy_config(cfg), hp["env_kwargs"])
    with np.load(path, allow_pickle=False) as z:            # plain arrays: no pickle needed (nor allowed)
        assert set(z.files) == set(model.policy_weights())
    pol, cfg2 = load_recurrent_policy(path)
    for k, v in model.policy_weights().items():
        assert np.array_equal(pol.w[k], v)
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["model"] == "cv" and meta["input_features"] == list(cfg.features)

    def broken(name, edit):
        d = tmp_path / name
        p = save_recurrent_policy(d, model.policy_weights(), model.policy_config(cfg), hp["env_kwargs"])
        edit(d)
        return p

    def weights(d, **w):
        arrays = dict(model.policy_weights(), **w)
        np.savez(d / "policy.npz", **arrays)

    def meta_edit(d, **kv):
        m = json.loads((d / "policy.json").read_text())
        m.update(kv)
        (d / "policy.json").write_text(json.dumps(m))

    def env_edit(d, **kv):
        e = json.loads((d / "env_config.json").read_text())
        e.update(kv)
        (d / "env_config.json").write_text(json.dumps(e))

    w = model.policy_weights()
    cases = {
        "nan": (lambda d: weights(d, **{"out.bias": np.array([np.nan])}), "finite"),
        "shape": (lambda d: weights(d, **{"out.weight": np.zeros((1, 3))}), "shape"),
        "object": (lambda d: np.savez(d / "policy.npz", **dict(w, **{"out.bias": np.array([None], dtype=object)})),
                   "not a numpy .npz of plain arrays"),
        "format": (lambda d: meta_edit(d, format="other"), "not a recurrent-policy config"),
        "kind": (lambda d: meta_edit(d, model="imm_cv_ct"), "model 'imm_cv_ct'"),
        "features": (lambda d: env_edit(d, features=["nis", "dt_s"]), "inputs"),
        "discrete": (lambda d: env_edit(d, action_type="discrete"), "continuous"),
        "q_levels": (lambda d: env_edit(d, q_levels_g=[0.001, 0.01, 0.1, 1.0]), "trained with q from"),
        "no_meta": (lambda d: (d / "policy.json").unlink(), "no policy.json"),
    }
    for name, (edit, msg) in cases.items():
        with pytest.raises(ValueError, match=msg):
            load_policy(broken(name, edit))


# ------------------------------------------------------------------------------------------------ the trainer
def test_check_hp_refusals():
    with pytest.raises(ValueError, match="--hp nope"):
        bp.check_hp(_hp(nope=1))
    with pytest.raises(ValueError, match="--hp chunk_looks"):
        bp.check_hp(_hp(chunk_looks=0))
    for head in ([2 ** 62], [0], [8] * 9, [8.0]):        # an overflowing width was a RuntimeError from torch
        with pytest.raises(ValueError, match=r"--hp head: must be a list of at most 8 layer widths in \[1, 4096\]"):
            bp.check_hp(_hp(head=head))
    with pytest.raises(ValueError, match="--hp tracker"):
        bp.check_hp(_hp(tracker="nope"))
    with pytest.raises(ValueError, match="select_on"):
        bp.check_hp(_hp(select_on=["bizup2002"]))
    for ek, msg in (({"scenario": "bizup2002"}, "random scenario generators"),
                    ({"action_type": "discrete"}, "continuous"), ({"frame_stack": 4}, "frame_stack"),
                    ({"features": ["nis", "imm_ct_prob"]}, r"features \['imm_ct_prob'\] are not supported")):
        with pytest.raises(ValueError, match=msg):
            bp.check_hp(_hp(env_kwargs={**_hp()["env_kwargs"], **ek}))
    hp = _hp()
    del hp["learning_rate"]
    with pytest.raises(ValueError, match="missing"):
        bp.check_hp(hp)
    with pytest.raises(ValueError, match="--hp chain"):
        bp.check_hp(_hp(chain="numba"))
    # chain is optional (the recipes' files leave it out, so that their configs, which a resume compares, are as
    # before): absent, the model compiles; "torch" is the reference lockstep
    assert "chain" not in load_hyperparams("backprop") and "chain" not in _hp()
    hp, _, cfg = bp.check_hp(_hp())
    assert "chain" not in hp and bp.make_model(hp, cfg).chain == "compiled"
    hp, _, cfg = bp.check_hp(_hp(chain="torch"))
    assert bp.make_model(hp, cfg).chain == "torch"


def test_training_run_folder_resume_and_refusal(tmp_path):
    hp = _hp(n_steps=4, eval_every=2)

    class Kill(Exception):
        pass

    def kill_at(step):
        def f(row):
            if row["timesteps"] == step:
                raise Kill
        return f

    with pytest.raises(Kill):
        bp.train_backprop(hp, seed=3, out=tmp_path, progress=False, verbose=0, run_name="r", on_selection=kill_at(2))
    part = tmp_path / "r.partial"
    assert (part / "FAILED").is_file() and (part / "checkpoints" / "last.json").is_file()
    with np.load(part / "best" / "policy.npz") as z:
        best_before = {k: z[k] for k in z.files}
    np.savez(part / "best" / "policy.npz", **{k: v + 1.0 for k, v in best_before.items()})   # a stale best/
    assert json.loads((part / "checkpoints" / "last.json").read_text())["step"] == 2   # saved before the report
    # another configuration under the same name is refused in one line
    with pytest.raises(ValueError, match="another configuration") as e:
        bp.train_backprop({**hp, "learning_rate": 1e-4}, seed=3, out=tmp_path, progress=False, verbose=0,
                          run_name="r")
    assert "\n" not in str(e.value)
    # a damaged checkpoint is refused in one line naming it; intact again, it resumes
    npz = part / "checkpoints" / "last.npz"
    good = npz.read_bytes()
    with np.load(npz) as z:
        wrong_shape = {k: (np.zeros(3) if k.startswith("model/") else z[k]) for k in z.files}
    np.savez(npz, **wrong_shape)
    damaged = [npz.read_bytes(), good[: len(good) // 2], b"not a checkpoint"]
    for damage in damaged:
        npz.write_bytes(damage)
        with pytest.raises(ValueError, match=r"^--name: the checkpoint .*last\.npz cannot be resumed \(.*\); remove "
                           ) as e:
            bp.train_backprop(hp, seed=3, out=tmp_path, progress=False, verbose=0, run_name="r")
        assert "\n" not in str(e.value)
    npz.write_bytes(good)
    rows = []       # resumed with the other chain (how it runs, not what it computes: bp.RESUME_IGNORES)
    run = bp.train_backprop({**hp, "chain": "torch"}, seed=3, out=tmp_path, progress=False, verbose=0, run_name="r",
                            on_selection=rows.append)
    assert run == tmp_path / "r" and not part.exists()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["steps"] == 4 and summary["resumed_at"] == [2] and not (run / "FAILED").exists()
    assert [r["timesteps"] for r in rows] == [4]
    assert [r["timesteps"] for r in summary["selection_history"]] == [0, 2, 4]
    for f in ("config.json", "args.json", "command.txt", "env_config.json", "policy.npz", "policy.json",
              "best/policy.npz", "best/selection.json", "checkpoints/last.npz"):
        assert (run / f).is_file(), f
    assert list((run / "tb").glob("events.*"))
    pol, cfg = load_policy(run / "best" / "policy.npz")
    best = min(summary["selection_history"], key=lambda r: r["selection_ratio"])
    assert json.loads((run / "best" / "selection.json").read_text())["timesteps"] == best["timesteps"]
    if best["timesteps"] <= 2:       # best/ rewritten from the checkpoint at the resume
        assert all(np.array_equal(pol.w[k], v) for k, v in best_before.items())
    assert np.isfinite(summary["episodes_per_s"]) and summary["row_looks"] > 0
    with pytest.raises(ValueError, match="already exists"):
        bp.train_backprop(hp, seed=3, out=tmp_path, progress=False, verbose=0, run_name="r")


def test_training_is_reproducible(tmp_path):
    hp = _hp(n_steps=2, eval_every=2)
    a = bp.train_backprop(hp, seed=1, out=tmp_path, progress=False, verbose=0, run_name="a")
    b = bp.train_backprop(hp, seed=1, out=tmp_path, progress=False, verbose=0, run_name="b")
    with np.load(a / "policy.npz") as za, np.load(b / "policy.npz") as zb:
        assert all(np.array_equal(za[k], zb[k]) for k in za.files)
    assert bp.check_hp(hp)[0]["n_steps"] == 2


def test_train_cli_method_backprop(tmp_path, capsys):
    from agents.training.train import main
    for argv, msg in ((["--method", "backprop", "--algo", "ppo"], "--algo applies to --method ppo"),
                      (["--method", "backprop", "--timesteps", "5"], "--timesteps applies"),
                      (["--method", "backprop", "--hp", "hidden_size=0"], "--hp hidden_size"),
                      (["--method", "backprop", "--tracker", "nope"], "--tracker: unknown model"),
                      (["--method", "backprop", "--seed", "950000"], "--seed"),
                      (["--algo", "ppo", "--tracker", "cv"], "--tracker applies"),
                      ([], "--algo is required")):
        with pytest.raises(SystemExit) as e:
            main(argv + ["--out", str(tmp_path)])
        assert msg in str(e.value), (argv, str(e.value))
    run = main(["--method", "backprop", "--out", str(tmp_path), "--name", "cli", "--no-progress", "--quiet",
                "--hp", "n_steps=1", "--hp", "batch_episodes=2", "--hp", "hidden_size=4", "--hp", "chunk_looks=5",
                "--hp", 'eval_scenarios={"random": 2, "random_radars": 2}'])
    assert (run / "policy.npz").is_file()
    assert "--method backprop" in (run / "command.txt").read_text()
    from agents.policies.learned import load_learned     # the run folder in the learned-tracker layout
    lt = load_learned(run)
    assert (lt.kind, lt.name, lt.file) == ("gru_q_policy", "cli", run / "policy.npz")
    training = json.loads((run / "training.json").read_text())
    assert training["command"] == (run / "command.txt").read_text().strip() and training["summary"]["steps"] == 1
    assert json.loads((run / "choice.json").read_text())["chosen"] == "final"


# ------------------------------------------------------------------------------------------------ a policy everywhere
def test_evaluate_cli_runs_a_recurrent_policy_as_policy_and_policy_bp(tmp_path):
    from agents.evaluation.evaluate import main
    model, cfg, hp = _model(scale=0.2)
    path = save_recurrent_policy(tmp_path / "p", model.policy_weights(), model.policy_config(cfg), hp["env_kwargs"])
    out = tmp_path / "r.json"
    res = main(["--policy", str(path), "--policy-bp", str(path), "--trackers", "policy,policy_bp,imm2", "--scenario",
                "random", "--runs", "3", "--no-plots", "--quiet", "--json", str(out)])
    t = res["random"]["trackers"]
    assert t["policy"]["pos_rmse_m"] == t["policy_bp"]["pos_rmse_m"] and np.isfinite(t["policy"]["pos_rmse_m"])
    assert json.loads(out.read_text())["meta"]["policy_bp"] == str(path)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(SystemExit, match="--policy-bp"):
        main(["--policy-bp", str(bad), "--trackers", "policy_bp", "--scenario", "random", "--runs", "2",
              "--no-plots", "--quiet"])


def test_ray_blob_and_shipping_carry_the_recurrent_policys_files(tmp_path):
    from agents.evaluation.parallel import _policy_blob, _policy_in_worker
    from agents.policies.bundle import ship_policy
    model, cfg, hp = _model()
    path = save_recurrent_policy(tmp_path / "p", model.policy_weights(), model.policy_config(cfg), hp["env_kwargs"])
    blob = _policy_blob(path)
    assert list(blob) == ["policy.npz", "policy.json", "env_config.json"]
    pol, cfg2 = _policy_in_worker(blob)
    assert isinstance(pol, RecurrentQPolicy) and cfg2 == cfg
    shipped = ship_policy(path, tmp_path / "ship")
    pol2, _ = load_policy(shipped)
    assert all(np.array_equal(pol2.w[k], v) for k, v in pol.w.items())


def test_sweep_config_for_backprop(tmp_path):
    from agents.training.sweep import _budget, load_sweep_config
    cfg = load_sweep_config("agents/training/sweeps/backprop_seeds.toml")
    assert cfg["algo"] == "backprop" and len(cfg["space"]["seed"]) >= 3
    assert _budget("backprop", cfg["hp"]) == (cfg["hp"]["n_steps"], cfg["hp"]["eval_every"])
    bp.check_hp(cfg["hp"])
    bad = tmp_path / "s.toml"
    bad.write_text('[sweep]\nmethod = "backprop"\nalgo = "ppo"\n[space]\nseed = [1]\n')
    with pytest.raises(ValueError, match="algo applies"):
        load_sweep_config(bad)
    bad.write_text('[sweep]\nmethod = "sgd"\n[space]\nseed = [1]\n')
    with pytest.raises(ValueError, match="method"):
        load_sweep_config(bad)


def test_bench_backprop_runs_with_tiny_settings(tmp_path):
    import importlib.util
    import sys
    from pathlib import Path
    spec = importlib.util.spec_from_file_location(
        "bench_backprop", Path(__file__).resolve().parents[1] / "benchmarks" / "bench_backprop.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    out = tmp_path / "b.json"
    res = mod.main(["--batch", "4", "--chunk", "5", "--hidden", "4", "--steps", "2", "--flights", "random",
                    "--json", str(out)])
    r = res["results"][0]
    assert r["row_looks_per_s"] > 0 and 0 < r["numba_share"] < 1 and json.loads(out.read_text())["results"]
    with pytest.raises(SystemExit):
        mod.main(["--flights", "nope"])
    r = mod.main(["--batch", "4", "--chunk", "5", "--hidden", "4", "--flights", "random", "--compare", "2",
                  "--json", str(out)])
    assert set(r["s_per_step"]) == {"main", "torch", "compiled"} and r["ratio_main"] > 0 and r["ratio_torch"] > 0
    assert len(r["times"]["compiled"]) == 2 and json.loads(out.read_text())["ratio_main"] == r["ratio_main"]


def test_numpy_inference_of_a_row_does_not_depend_on_its_batch():
    """BLAS rounds a one-row product differently from a many-row one; the policy's linear layers must not (a row's
    q would depend on the episodes sharing its batch), nor on the CPU: each output is summed over its inputs in
    order, whatever the batch's size (the compiled layer takes four rows at a time) and the weights' memory order."""
    from agents.policies.recurrent import layer_weights, linear
    rng = np.random.default_rng(7)
    for F, H in ((27, 96), (32, 96), (32, 1)):
        W = rng.normal(size=(H, F))
        x = rng.normal(size=(200, F))
        full = linear(x, W)
        assert np.allclose(full, x @ W.T, rtol=1e-12, atol=1e-12)
        for i in (0, 77, 199):
            assert np.array_equal(linear(x[i:i + 1], W)[0], full[i])
        assert np.array_equal(linear(x, layer_weights({"w": W})["w"]), full)
    # the compiled layer takes four rows and four inputs at a time and pads a narrow output to 16 columns: every
    # remainder of rows and inputs, and widths on either side of the padding, equal the sequential sum to the bit
    shapes = [(n, 37, 50) for n in (1, 3, 4, 5, 9, 64)] + [(7, F, H) for F in (1, 3, 4, 6, 128)
                                                           for H in (1, 2, 9, 12, 16, 50, 64, 66)]
    for n, F, H in shapes:
        x, W = rng.normal(size=(n, F)), rng.normal(size=(H, F))
        x[0, 0], W[0, 0] = -0.0, 0.0            # a signed zero's sum as the plain loop's
        seq = np.zeros((n, H))
        for f in range(F):                      # the sequential sum, term by term
            seq = seq + x[:, f:f + 1] * W[None, :, f]
        y = linear(x, W)
        assert y.shape == (n, H) and np.array_equal(y.view(np.int64), seq.view(np.int64)), (n, F, H)
        assert all(np.array_equal(linear(x[i:i + 1], W)[0], y[i]) for i in range(n))
        assert np.allclose(y, x @ W.T, rtol=1e-12, atol=1e-12)
        assert linear(x[:, :0], W[:, :0]).shape == (n, H) and not linear(x[:, :0], W[:, :0]).any()
