"""The policies' numpy export (agents/policies/numpy_policy.py) chooses exactly stable-baselines3's deterministic
actions: the bundled policy and its recipe seeds on observations of the evaluation itself and sampled in the Box,
every supported algorithm and activation, exact ties (the first action wins, as in SB3); the bundled policy then
loads without torch or SB3 and gives the evaluation bit for bit what SB3's predict gave."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")

from agents.policies import numpy_policy as npp  # noqa: E402
from agents.policies.bundle import BUNDLED_POLICY  # noqa: E402
from agents.policies.loading import load_model, load_policy, load_sb3_model, model_choose_q  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = [BUNDLED_POLICY] + sorted((BUNDLED_POLICY.parent / "recipe").glob("*/policy.zip"))


class _SpacesEnv(gym.Env):
    """An env with the given spaces and nothing else (SB3 models are built from an env's spaces)."""

    def __init__(self, action_space, n_obs=6):
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (n_obs,), dtype=np.float32)
        self.action_space = action_space

    def reset(self, seed=None, options=None):
        return np.zeros(self.observation_space.shape, np.float32), {}

    def step(self, action):
        return np.zeros(self.observation_space.shape, np.float32), 0.0, True, False, {}


DISCRETE, BOX = gym.spaces.Discrete(5), gym.spaces.Box(-2.0, 3.0, (2,), dtype=np.float32)


def _model(algo, space, activation=None, **kw):
    pk = {"net_arch": [16, 8], "activation_fn": activation or torch.nn.Tanh}
    m = getattr(sb3, algo)("MlpPolicy", _SpacesEnv(space), policy_kwargs=pk, device="cpu", seed=0, **kw)
    with torch.no_grad():          # weights large enough that the activations leave their linear range
        for p in m.policy.parameters():
            p.mul_(3.0)
    return m


def _obs(n=2000, seed=1):
    return npp._sample_observations(gym.spaces.Box(-1.0, 1.0, (6,), dtype=np.float32), n, seed)


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.parent.name)
def test_shipped_exports_are_current_and_act_as_sb3(path):
    pol = npp.load_export(path)
    assert pol is not None, f"{npp.export_path(path)} is missing or was exported from another zip"
    model = load_sb3_model(path, allow_pickle=True)
    ok, msg = npp.check_export(pol, model, n=4096, seed=7)
    assert ok, msg
    assert pol.observation_space == model.observation_space and pol.action_space == model.action_space


def test_bundled_policy_acts_as_sb3_on_the_evaluations_observations():
    """The observations the evaluation feeds the bundled policy (every look of two suites), through the same
    choose_q: the q chosen per look are equal, and so is the whole TrackRun (bit for bit)."""
    from agents.evaluation.suites import EVAL_SEED_BASE, draw_suite
    from baselines.trackers import run_q_policy
    choose_np, cfg = load_policy(BUNDLED_POLICY)
    choose_sb3 = model_choose_q(load_sb3_model(BUNDLED_POLICY, allow_pickle=True), cfg)
    seen = []

    def both(obs):
        q = choose_sb3(obs)
        seen.append((obs.copy(), q))
        return q

    for suite, runs in (("random", 20), ("random_radars", 8)):
        eps = draw_suite(suite, runs, seed=EVAL_SEED_BASE)
        a, b = run_q_policy(eps, both, "policy", cfg), run_q_policy(eps, choose_np, "policy", cfg)
        for f in ("x", "P", "q_m_s2"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f"{suite} {f}")
    obs = np.concatenate([o for o, _ in seen])
    assert obs.shape[0] > 5000, obs.shape
    np.testing.assert_array_equal(choose_np(obs), np.concatenate([q for _, q in seen]))


@pytest.mark.parametrize("algo,space", [("PPO", DISCRETE), ("PPO", BOX), ("A2C", DISCRETE), ("A2C", BOX),
                                        ("DQN", DISCRETE), ("SAC", BOX), ("TD3", BOX)])
@pytest.mark.parametrize("activation", ["tanh", "relu", "elu", "leaky_relu", "silu"])
def test_every_algorithm_and_activation_acts_as_sb3(algo, space, activation):
    import torch.nn as nn
    act = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU, "silu": nn.SiLU}[activation]
    model = _model(algo, space, act)
    arrays = npp.export_model(model)
    assert arrays is not None
    pol = npp.NumpyPolicy(arrays)
    obs = _obs()
    a_np, _ = pol.predict(obs)
    a_sb3, _ = model.predict(obs, deterministic=True)
    assert a_np.shape == a_sb3.shape and a_np.dtype == a_sb3.dtype
    if isinstance(space, gym.spaces.Discrete):
        np.testing.assert_array_equal(a_np, a_sb3)
        assert len(np.unique(a_np)) > 1         # the check is not on a constant policy
    else:
        np.testing.assert_allclose(a_np, a_sb3, rtol=0, atol=2e-6 * 5.0)
        assert np.all(a_np >= space.low) and np.all(a_np <= space.high)
    one, _ = pol.predict(obs[0])              # a single observation, as SB3: no batch axis
    np.testing.assert_array_equal(one, a_np[0])


@pytest.mark.parametrize("algo", ["PPO", "DQN"])
def test_exact_ties_pick_the_first_action_as_sb3(algo):
    model = _model(algo, DISCRETE)
    head = model.policy.action_net if algo == "PPO" else model.policy.q_net.q_net[-1]
    with torch.no_grad():                     # actions 1 and 3 identical: equal logits / Q-values everywhere
        head.weight[3] = head.weight[1]
        head.bias[3] = head.bias[1]
        head.bias[1] += 50.0                  # ... and the best
        head.bias[3] += 50.0
    pol = npp.NumpyPolicy(npp.export_model(model))
    obs = _obs(500)
    a_np, a_sb3 = pol.predict(obs)[0], model.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(a_np, a_sb3)
    assert np.all(a_np == 1)
    with torch.no_grad():                     # every action tied: action 0
        head.weight.zero_()
        head.bias.zero_()
    pol = npp.NumpyPolicy(npp.export_model(model))
    assert np.all(pol.predict(obs)[0] == 0) and np.all(model.predict(obs, deterministic=True)[0] == 0)


def test_unsupported_structures_keep_sb3_predict(tmp_path):
    gsde = sb3.PPO("MlpPolicy", _SpacesEnv(BOX), use_sde=True, device="cpu", seed=0)
    assert npp.export_model(gsde) is None
    gsde.save(tmp_path / "policy.zip")
    assert isinstance(load_model(tmp_path / "policy.zip", allow_pickle=True), sb3.PPO)
    with pytest.raises(ValueError, match="--allow-pickle"):       # no export: a pickle, refused without the opt-in
        load_model(tmp_path / "policy.zip")


def test_user_zip_is_exported_in_memory_and_stale_or_damaged_exports_are_ignored(tmp_path, capsys):
    d = tmp_path / "p"
    d.mkdir()
    shutil.copy(BUNDLED_POLICY, d / "policy.zip")
    shutil.copy(BUNDLED_POLICY.with_name("env_config.json"), d / "env_config.json")
    pol = load_model(d / "policy.zip", allow_pickle=True)    # no .npz: SB3 loads it, the actor runs in numpy
    assert isinstance(pol, npp.NumpyPolicy) and not npp.export_path(d / "policy.zip").exists()
    out = npp.save_export(d / "policy.zip", allow_pickle=True)
    assert out == d / "policy.npz" and isinstance(npp.load_export(d / "policy.zip"), npp.NumpyPolicy)
    ref = np.load(npp.export_path(BUNDLED_POLICY))
    for k in ref.files:                        # the shipped export is what save_export writes
        np.testing.assert_array_equal(np.load(out)[k], ref[k], err_msg=k)
    # an export of another zip: ignored, with a warning
    shutil.copy(BUNDLED_POLICY.parent / "recipe" / "broad_s700000" / "policy.npz", out)
    assert npp.load_export(d / "policy.zip") is None
    with pytest.raises(ValueError, match="made from another file.*--allow-pickle"):
        load_model(d / "policy.zip")
    assert isinstance(load_model(d / "policy.zip", allow_pickle=True), npp.NumpyPolicy)
    assert "exported from another file" in capsys.readouterr().err
    # a damaged export: a ValueError from load_export, a warning and SB3 from load_model
    out.write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not a numpy .npz"):
        npp.load_export(d / "policy.zip")
    with pytest.raises(ValueError, match="not a numpy .npz"):
        load_policy(d / "policy.zip")
    choose_q, _ = load_policy(d / "policy.zip", allow_pickle=True)
    err = capsys.readouterr().err
    assert "not a numpy .npz" in err and "exported from another file" not in err and callable(choose_q)


def test_damaged_arrays_are_refused_naming_the_problem():
    arrays = npp.load_export(BUNDLED_POLICY).arrays()
    bad = dict(arrays, W1=arrays["W1"][:, :-1])
    with pytest.raises(ValueError, match="layer 1"):
        npp.NumpyPolicy(bad)
    with pytest.raises(ValueError, match="head"):
        npp.NumpyPolicy(dict(arrays, head=np.array("softmax")))
    with pytest.raises(ValueError, match="missing array 'W0'"):
        npp.NumpyPolicy({k: v for k, v in arrays.items() if k != "W0"})


def test_bundled_policy_loads_without_torch_or_sb3():
    code = ("import sys\n"
            "import agents.evaluation.evaluate as ev\n"
            "choose_q, cfg = ev.load_policy(ev.BUNDLED_POLICY)\n"
            "import numpy as np\n"
            "q = choose_q(np.zeros((3, len(cfg.features) * cfg.frame_stack), np.float32))\n"
            "assert q.shape == (3,) and np.all(q > 0)\n"
            "print(sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules))\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "[]"


def test_ray_workers_get_the_numpy_export_with_the_zip():
    """The blob shipped to Ray workers carries the export, so a worker runs the policy without torch or unpickling."""
    from agents.evaluation.parallel import _policy_blob
    from agents.policies.bundle import BUNDLED_POLICY
    blob = _policy_blob(BUNDLED_POLICY)
    assert list(blob)[0] == "policy.zip" and {"env_config.json", "policy.npz"} <= set(blob)
    assert blob["policy.npz"] == BUNDLED_POLICY.with_name("policy.npz").read_bytes()
