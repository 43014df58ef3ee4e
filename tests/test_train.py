"""Training pipeline: the SB3 adapter equals DummyVecEnv over the single env, PPO/DQN/SAC train end to end and
their saved models run in ``radar-track evaluate``, the bundled policy acts deterministically."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

from agents.evaluation import evaluate as ev  # noqa: E402
from agents.training.callbacks import ImmRatioEvalCallback  # noqa: E402
from agents.cli import main as cli_main  # noqa: E402
from agents.training.sb3_vec import make_sb3_vec_env  # noqa: E402
from agents.training.train import load_hyperparams, main as train_main, train  # noqa: E402
from agents.policies.learned import load_learned  # noqa: E402
from radar_env.envs.env import RadarTrackEnv  # noqa: E402
from radar_env.envs.observation import DEFAULT_FEATURES  # noqa: E402


def _assert_info_equal(i1, i2):
    assert set(i1) == set(i2), set(i1) ^ set(i2)
    for k in i1:
        if isinstance(i1[k], dict):
            assert i1[k] == i2[k], k
        else:
            assert np.array_equal(np.asarray(i1[k]), np.asarray(i2[k])), k


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_adapter_matches_dummy_vec_env_across_episode_ends(action_type):
    n, seed = 3, 11
    kw = {"action_type": action_type, "warmup_scans": 2}
    vec, _ = make_sb3_vec_env(n, kw, seed=seed, monitor=False, full_info=True)
    lean, _ = make_sb3_vec_env(n, kw, seed=seed, monitor=False)
    dummy = DummyVecEnv([lambda: RadarTrackEnv(**kw) for _ in range(n)])
    dummy.seed(seed)
    assert dummy._seeds == vec._seeds == [seed + i for i in range(n)]
    o1, o2, o3 = vec.reset(), dummy.reset(), lean.reset()
    assert np.array_equal(o1, o2) and np.array_equal(o3, o2)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(700):
        if action_type == "discrete":
            a = rng.integers(0, 13, n)
        else:
            a = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        r1, r2, r3 = vec.step(a), dummy.step(a), lean.step(a)
        for x, y, z in zip(r1[:3], r2[:3], r3[:3]):
            assert np.array_equal(x, y) and np.array_equal(z, y)
        for i1, i2, i3 in zip(r1[3], r2[3], r3[3]):
            _assert_info_equal(i1, i2)
            assert i3["TimeLimit.truncated"] == i2["TimeLimit.truncated"]
            if "terminal_observation" in i2:
                assert np.array_equal(i3["terminal_observation"], i2["terminal_observation"])
            else:
                assert "terminal_observation" not in i3
        ends += int(r2[2].sum())
    assert ends >= 6  # crossed several episode boundaries (about 170 looks per random episode)


def test_adapter_seed_none_and_attrs():
    vec, adapter = make_sb3_vec_env(2, {}, seed=None, monitor=True)
    obs = vec.reset()
    assert obs.shape == (2, len(DEFAULT_FEATURES)) and obs.dtype == np.float32
    assert vec.get_attr("render_mode") == [None, None]
    assert vec.env_is_wrapped(object) == [False, False]
    obs, rew, done, infos = vec.step(np.array([4, 4]))
    assert rew.shape == (2,) and len(infos) == 2 and adapter.env_time_s > 0


def _tiny(algo):
    hp = load_hyperparams(algo)
    hp.update(n_envs=4, n_timesteps=2048, eval_freq=1024, eval_runs=4, checkpoint_freq=1024,
              eval_scenarios={"random": 4, "random_radars": 2})
    if algo == "ppo":
        hp.update(n_steps=128, batch_size=128, n_epochs=2)
    else:
        hp.update(learning_starts=256, buffer_size=5000, batch_size=64)
    if algo == "dqn":
        hp.update(target_update_interval=500)
    hp["env_kwargs"] = {**hp["env_kwargs"], "warmup_scans": 4}
    return hp


@pytest.mark.parametrize("algo", ["ppo", "dqn", "sac"])
def test_train_end_to_end_and_evaluate(algo, tmp_path, capsys):
    run = train(algo, _tiny(algo), seed=3, out=tmp_path, progress=False, verbose=0, run_name=algo)
    for f in ("policy.zip", "env_config.json", "config.json", "args.json", "command.txt", "summary.json",
              "best/policy.zip", "best/env_config.json", "best/selection.json", "training_curve.png"):
        assert (run / f).is_file(), f
    assert any((run / "checkpoints").iterdir()) and any((run / "tb").iterdir())
    assert (run / "vecnormalize.pkl").is_file()
    summary = json.loads((run / "summary.json").read_text())
    assert summary["timesteps"] >= 2048 and 0 < summary["env_share_of_wall"] < 1
    assert np.isfinite(summary["best_selection_ratio_imm2"])
    env_cfg = json.loads((run / "env_config.json").read_text())
    assert env_cfg["action_type"] == ("continuous" if algo == "sac" else "discrete")
    for p in (run / "policy.zip", run / "best" / "policy.zip"):
        res = ev.main(["--policy", str(p), "--scenario", "random", "--runs", "2", "--no-plots", "--quiet",
                       "--trackers", "policy,imm2"])
        m = res["random"]["trackers"]["policy"]
        assert np.isfinite(m["pos_rmse_m"]) and m["runs"] == 2
        # the run and its best/ are learned-tracker folders: one loader reads them by the kind training wrote
        lt = load_learned(p.parent)
        assert lt.kind == f"{algo}_q_policy"
        assert lt.name == (f"{algo}_best" if p.parent.name == "best" else algo)     # the run is named algo
        assert {"policy.json", "env_config.json", "training.json", "choice.json"} <= {f.name for f in p.parent.iterdir()}
        assert json.loads((p.parent / "choice.json").read_text())["chosen"] == ("best" if p.parent.name == "best"
                                                                                else "final")
    capsys.readouterr()


def test_fine_tune_from_saved_model_on_random_radars(tmp_path):
    """init_from copies the saved weights (the fine-tuned run starts where the first ended); random_radars is a
    training scenario; select_on scores the geometric mean of the named suites; mismatched spaces are refused."""
    import stable_baselines3 as sb3
    hp = _tiny("ppo")
    first = train("ppo", hp, seed=3, out=tmp_path, progress=False, verbose=0, run_name="a")
    from agents.policies.learned import load_learned
    from agents.policies.numpy_policy import NumpyPolicy, load_export
    assert isinstance(load_export(first / "policy.zip"), NumpyPolicy)    # exported at the save: no pickle needed
    load_learned(first)
    src = sb3.PPO.load(first / "policy.zip", device="cpu")
    hp2 = _tiny("ppo")
    hp2.update(n_timesteps=128, n_steps=32, init_from=str(first / "policy.zip"), learning_rate=0.0,
               eval_scenarios={"random": 2, "random_radars": 2}, select_on=["random", "random_radars"])
    hp2["env_kwargs"] = {**hp2["env_kwargs"], "scenario": "random_radars"}
    with pytest.raises(ValueError, match="init_from.*pickle.*--allow-pickle"):     # no unpickling without the opt-in
        train("ppo", hp2, seed=5, out=tmp_path, progress=False, verbose=0, run_name="b")
    second = train("ppo", hp2, seed=5, out=tmp_path, progress=False, verbose=0, run_name="b", allow_pickle=True)
    tuned = sb3.PPO.load(second / "policy.zip", device="cpu")
    for k, v in src.policy.state_dict().items():     # learning rate 0: the weights are exactly the source's
        assert np.array_equal(v.numpy(), tuned.policy.state_dict()[k].numpy()), k
    row = json.loads((second / "summary.json").read_text())["selection_history"][-1]
    assert row["selection_ratio"] == pytest.approx(np.sqrt(row["random_ratio_imm2"] * row["random_radars_ratio_imm2"]))
    assert json.loads((second / "env_config.json").read_text())["scenario"] == "random_radars"
    hp3 = _tiny("ppo")
    hp3.update(init_from=str(first / "policy.zip"))
    hp3["env_kwargs"] = {**hp3["env_kwargs"], "features": ["nis", "c_min_g"]}
    with pytest.raises(ValueError, match="init_from"):
        train("ppo", hp3, seed=3, out=tmp_path, progress=False, verbose=0, run_name="c", allow_pickle=True)


def test_cli_train_branch_and_errors(tmp_path, capsys):
    assert cli_main(["train", "--algo", "ppo", "--timesteps", "256", "--n-envs", "2", "--out", str(tmp_path),
                     "--name", "cli", "--no-progress", "--quiet", "--hp", "n_steps=128", "--hp", "batch_size=64",
                     "--hp", "n_epochs=1", "--hp", "eval_freq=256",
                     "--hp", 'eval_scenarios={"random": 2, "random_radars": 2}',
                     "--env-kwargs", '{"reward_type": "absolute"}']) == 0
    cmd = (tmp_path / "cli" / "command.txt").read_text()
    assert cmd.startswith("radar-track train --algo ppo") and "absolute" in cmd
    assert json.loads((tmp_path / "cli" / "env_config.json").read_text())["reward_type"] == "absolute"
    with pytest.raises(SystemExit, match="DQN needs"):
        train_main(["--algo", "dqn", "--action-type", "continuous", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="training seeds"):
        train_main(["--algo", "ppo", "--seed", "10000000", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="random"):
        train_main(["--algo", "ppo", "--env-kwargs", '{"scenario": "bizup2002"}', "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="training range"):
        ImmRatioEvalCallback({}, scenarios={"random": 2}, seed=10_000_000)
    capsys.readouterr()


@pytest.mark.skipif(not ev.BUNDLED_POLICY.is_file(), reason="no bundled policy")
def test_bundled_policy_loads_and_is_deterministic():
    choose_q, cfg = ev.load_policy(ev.BUNDLED_POLICY)
    env = RadarTrackEnv(**{f: getattr(cfg, f) for f in ("action_type", "q_levels_g", "features", "frame_stack",
                                                   "reward_type")})
    obs = [env.reset(seed=5)[0]]
    for _ in range(40):
        obs.append(env.step(env.action_space.sample() if env.config.action_type == "discrete"
                            else np.zeros(1, np.float32))[0])
    obs = np.stack(obs)
    q1, q2 = choose_q(obs), choose_q(obs.copy())
    assert np.array_equal(q1, q2) and np.all(np.isfinite(q1)) and np.all(q1 > 0)
    assert ev.BUNDLED_POLICY.stat().st_size < 1_000_000


def _bundled_policy_ratios(scenario, runs, baselines):
    """Position-RMSE ratios (with paired 95 % intervals) of the bundled policy to each baseline tracker, on
    ``runs`` held-out runs of ``scenario`` with fixed evaluation seeds (not those of the README table)."""
    from agents.evaluation.metrics import ratio_ci
    from agents.evaluation.suites import EVAL_SEED_BASE, draw_suite
    from baselines.registry import run_tracker
    from baselines.trackers import run_q_policy
    from radar_env.sim.episode import stack_episodes
    choose_q, cfg = ev.load_policy(ev.BUNDLED_POLICY)
    eps = draw_suite(scenario, runs, seed=EVAL_SEED_BASE + 5000)
    batch = stack_episodes(eps)
    pol = run_q_policy(eps, choose_q, "policy", cfg)
    return [ratio_ci(batch, pol, run_tracker(name, eps)) for name in baselines]


@pytest.mark.skipif(not ev.BUNDLED_POLICY.is_file(), reason="no bundled policy")
def test_bundled_policy_beats_tuned_kf_and_imm_on_held_out_runs():
    """A real check of the bundled policy on 200 held-out random runs (evaluation seeds, fixed): its pooled position
    RMSE is below the tuned constant-q KF's, the tuned IMM's and the CV / CT-EKF IMM's (the strongest classical
    tracker on ``random``), each with a paired 95 % interval below 1. (40 runs were too few for the IMM margin
    after the episode stream changed: 0.977 [0.937, 1.024]; the pooled RMSE over runs is heavy-tailed.)"""
    res = _bundled_policy_ratios("random", 200, ("kf_tuned", "imm2", "imm_cv_ct"))
    for name, (r, ci) in zip(("kf_tuned", "imm2", "imm_cv_ct"), res):
        assert r < 1.0 and ci[1] < 1.0, (name, r, ci)


def _bundled_policy_family_check(scenario, runs):
    """The issue's per-suite bound on further held-out runs (seeds EVAL_SEED_BASE + 5000 + i, not the README's):
    ratio to imm2 and its 95 % interval, ratio to the strongest classical tracker of agents.reports.generalisation.CLASSICAL
    on these runs, and the track-loss rates of the policy and imm2."""
    from agents.reports.generalisation import CLASSICAL
    from agents.evaluation.metrics import evaluate_run, ratio_ci
    from agents.evaluation.suites import EVAL_SEED_BASE, draw_suite
    from baselines.registry import run_tracker
    from baselines.trackers import run_q_policy
    from radar_env.sim.episode import stack_episodes
    choose_q, cfg = ev.load_policy(ev.BUNDLED_POLICY)
    eps = draw_suite(scenario, runs, seed=EVAL_SEED_BASE + 5000)
    batch = stack_episodes(eps)
    pol = run_q_policy(eps, choose_q, "policy", cfg)
    runs_c = {t: run_tracker(t, eps) for t in CLASSICAL}
    m = {t: evaluate_run(batch, r) for t, r in (("policy", pol), *runs_c.items())}
    rmse = {t: m[t]["pos_rmse_m"] for t in runs_c}
    strongest = min((t for t in rmse if np.isfinite(rmse[t])), key=rmse.get)
    loss = {t: m[t]["track_loss_rate"] for t in ("policy", "imm2")}
    return ratio_ci(batch, pol, runs_c["imm2"]), (strongest, ratio_ci(batch, pol, runs_c[strongest])), loss


# The suites where the bundled policy does NOT meet issue 20's bound on these further runs: strict xfails (reported
# as not reached in the README's targets table); one that starts passing fails the suite (XPASS) until it is taken
# off this list, so the list cannot go stale.
FAMILY_BOUND_NOT_MET = {
    "start_maneuver": "not reached: above imm2 where the maneuver begins during the track start",
    "short_tracks": "not reached: above imm2 on tracks under 40 looks",
    "speed_changes": "not reached on these 40 runs: above imm2 (within the bound on the README's 200 runs)",
    "slow_orbits": "not reached: worse than imm_cv_ct (the CT model) beyond the interval",
    "adsb_heldout": "not reached: worse than imm3_ct beyond the interval on the real flights",
    "bizup2002": "not reached: above imm2 (and worse than imm_cv_ct)",
    "adrian_flower": "not reached: worse than imm_cv_ct beyond the interval",
    # since rbpf (the particle filter over the random flights' regimes) joined the classical field (issue 38)
    "sharp_turns": "not reached: worse than rbpf beyond the interval",
    "seed002_course_changes": "not reached: worse than rbpf beyond the interval",
    "seed002_two_radars": "not reached: worse than rbpf beyond the interval",
}


@pytest.mark.skipif(not ev.BUNDLED_POLICY.is_file(), reason="no bundled policy")
@pytest.mark.parametrize("scenario,runs", [(f, 40) for f in ("start_maneuver", "short_tracks", "sharp_turns",
                                                             "slow_orbits", "speed_changes")]
                         + [("adsb_heldout", 12), ("bizup2002", 20), ("kim_lee_accel", 20), ("adrian_flower", 4),
                            ("seed002_course_changes", 20), ("seed002_two_radars", 20)])
def test_bundled_policy_within_issue_bound_on_families_and_named_scenarios(scenario, runs, request):
    """Issue 20's bound on every held-out family and named scenario (further held-out runs): at most 1.0 x imm2
    with the interval's upper end at most 1.05, not worse than the strongest classical tracker beyond its interval,
    and a track-loss rate no higher than imm2's."""
    if scenario in FAMILY_BOUND_NOT_MET:
        request.applymarker(pytest.mark.xfail(strict=True, reason=FAMILY_BOUND_NOT_MET[scenario]))
    (r, ci), (strongest, (rs, cis)), loss = _bundled_policy_family_check(scenario, runs)
    assert r <= 1.0 and ci[1] <= 1.05, (scenario, "imm2", r, ci)
    assert cis[0] <= 1.0, (scenario, strongest, rs, cis)
    assert loss["policy"] <= loss["imm2"], (scenario, loss)


@pytest.mark.skipif(not ev.BUNDLED_POLICY.is_file(), reason="no bundled policy")
@pytest.mark.parametrize("scenario,runs", [("bizup2002", 20), ("kim_lee_accel", 20), ("adrian_flower", 4),
                                           ("seed002_course_changes", 20), ("seed002_two_radars", 20)])
def test_bundled_policy_within_issue_bound_on_named_scenarios(scenario, runs):
    """The issue's second target on further held-out runs: on every named paper scenario the bundled policy's pooled
    position RMSE is at most 1.05 x the tuned IMM's."""
    [(ratio, ci)] = _bundled_policy_ratios(scenario, runs, ("imm2",))
    assert ratio <= 1.05, (scenario, ratio, ci)
