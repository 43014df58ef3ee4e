"""The covariance stays a covariance on every radar the env accepts: symmetric and positive definite by Cholesky
at every look, whatever the agent does, for the chain (the env) and the IMMs; and the update stays accurate where
the textbook forms cancel away.

* a hypothesis property over the documented radar ranges (``RadarSite``: scan period (0, 3600] s, range noise
  (0, 1e5] m, bearing noise (0, 0.5] rad, radial-velocity noise (0, 1e3] m/s, detection probability (0, 1]) and
  random actions;
* the soak of scripts/soak_covariance.py on corners of those ranges, a few seconds (the script runs longer);
* the update against a 60-digit reference on the case that lost definiteness (100 km range noise, 1e-7 rad
  bearing: a plot covariance with a condition number of 1e14);
* the reward's NEES term is defined on such radars (it raised ``LinAlgError: Singular matrix`` mid-episode).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from radar_env.envs import env_kernels as ek
from radar_env.filters import kalman as kf
from radar_env.envs.env import RadarTrackEnv
from radar_env.sim.radar import Radar, RadarSite, converted_covariance

SOAK = Path(__file__).resolve().parents[1] / "scripts" / "soak_covariance.py"


def _soak_module():
    spec = importlib.util.spec_from_file_location("soak_covariance", SOAK)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _log_uniform(lo, hi):
    return st.floats(np.log10(lo), np.log10(hi)).map(lambda e: float(10.0 ** e))


@pytest.mark.filterwarnings("ignore:scenario 'built_flight'")     # slow scans fly far from the radar on purpose
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    scan_period_s=_log_uniform(0.02, 3600.0),
    range_noise_std_m=_log_uniform(1e-6, 1e5),
    bearing_noise_std_rad=_log_uniform(1e-9, 0.5),
    radial_velocity_noise_std_m_s=_log_uniform(1e-6, 1e3),
    detection_probability=st.floats(0.05, 1.0),
    action_type=st.sampled_from(["discrete", "continuous"]),
    seed=st.integers(0, 2**31 - 1),
    radial_velocity=st.booleans(),
)
def test_every_documented_radar_keeps_the_covariance_positive_definite(
        scan_period_s, range_noise_std_m, bearing_noise_std_rad, radial_velocity_noise_std_m_s,
        detection_probability, action_type, seed, radial_velocity):
    soak = _soak_module()
    site = RadarSite(scan_period_s=scan_period_s, range_noise_std_m=range_noise_std_m,
                     bearing_noise_std_rad=bearing_noise_std_rad,
                     radial_velocity_noise_std_m_s=radial_velocity_noise_std_m_s,
                     detection_probability=detection_probability)
    slow = scan_period_s > 60.0
    env = RadarTrackEnv(radar=Radar(site), scenario=soak.scenario_for(scan_period_s), action_type=action_type,
                        reward_nees_weight=1.0, warmup_scans=1 if slow else 12, radial_velocity=radial_velocity)
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    batch = lambda i: {k: (np.asarray([v]) if not isinstance(v, dict) else  # noqa: E731
                           {t: np.asarray([x]) for t, x in v.items()}) for k, v in i.items()}
    soak.check_info(batch(info), "reset")
    for k in range(60):
        a = env.action_space.sample() if k % 7 == 0 else (
            int(rng.integers(0, 13)) if action_type == "discrete" else rng.uniform(-1, 1, 1).astype(np.float32))
        obs, reward, term, trunc, info = env.step(a)
        assert np.isfinite(obs).all() and np.isfinite(reward)
        soak.check_info(batch(info), f"step {k}")
        if term or trunc:
            obs, info = env.reset()


def test_soak_on_the_extremes_of_the_radar_ranges():
    """A few seconds of the soak: every extreme of every range at least once (the script covers all 48 corners)."""
    soak = _soak_module()
    ex = soak.EXTREMES
    lo = {k: v[0] for k, v in ex.items()}
    hi = {k: v[-1] for k, v in ex.items()}
    sites = [RadarSite(**lo), RadarSite(**hi), RadarSite(**{**lo, "range_noise_std_m": hi["range_noise_std_m"]}),
             RadarSite(**{**hi, "bearing_noise_std_rad": lo["bearing_noise_std_rad"]}),
             RadarSite(**{**hi, "scan_period_s": 12.0, "range_noise_std_m": lo["range_noise_std_m"]}),
             RadarSite(**{**lo, "scan_period_s": 12.0, "bearing_noise_std_rad": hi["bearing_noise_std_rad"]})]
    tot = soak.soak(seconds_per_corner=0.15, num_envs=4, imm_runs=2, sites=sites, out=lambda *_: None)
    assert tot["refused"] == 0, tot["first_failures"]
    assert tot["row_steps"] > 0 and tot["imm_looks"] > 0
    assert tot["env_failures"] == 0 and tot["imm_failures"] == 0, tot["first_failures"]


def _reference_update(P, R):
    """The Kalman posterior covariance in 60-digit arithmetic (mpmath), the textbook form."""
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 60
    Pm, Rm = mpmath.matrix(P.tolist()), mpmath.matrix(R.tolist())
    K = Pm[:, 0:2] * (Pm[0:2, 0:2] + Rm) ** -1
    return np.array((Pm - K * Pm[0:2, :]).tolist(), dtype=float)


# A prior met in the env on a radar with 100 km range noise and a 1e-7 rad bearing (row 6, step 151 of an 8-row
# soak), and its plot covariance: condition number 1e14, entries 5e9 m^2, cross-range variance 7e-5 m^2.
_NEAR_SINGULAR_PRIOR = np.array([
    [5.2991804425005895e+08, -4.9628658161425519e+08, 1.5242863573130661e+08, -1.4271154747987416e+08],
    [-4.9628658161425519e+08, 4.6478955373878813e+08, -1.4275436757891515e+08, 1.3365400208701259e+08],
    [1.5242863573130661e+08, -1.4275436757891515e+08, 3.5332579721087366e+08, -3.3089120549527752e+08],
    [-1.4271154747987416e+08, 1.3365400208701259e+08, -3.3089120549527752e+08, 3.0988115904203510e+08]])
_NEAR_SINGULAR_R = np.array([[5.327478749458741e+09, -4.989264241213590e+09],
                             [-4.989264241213590e+09, 4.672521250541331e+09]])


def test_update_is_accurate_and_positive_definite_for_a_near_singular_plot():
    """The textbook forms (closed-form S^-1, ``P - K H P`` or Joseph) gave eigenvalues (-3.0e-3, 10.47, ...)
    against the true (7.08e-5, 10.48, 4.4e8, 8.2e8): not positive definite. In R's principal axes the update keeps
    them to the accuracy R itself has (its 7e-5 eigenvalue is stored to ~1 %)."""
    ref = _reference_update(_NEAR_SINGULAR_PRIOR, _NEAR_SINGULAR_R)
    got = kf.update(np.zeros(4), _NEAR_SINGULAR_PRIOR, np.zeros(2), _NEAR_SINGULAR_R).P
    np.linalg.cholesky(got)
    ev, ev_ref = np.linalg.eigvalsh(got), np.linalg.eigvalsh(ref)
    assert ev_ref[0] > 0 and np.allclose(ev, ev_ref, rtol=0.01, atol=0), (ev, ev_ref)


def test_update_after_a_long_hard_coast_keeps_small_posterior_variances():
    """An hour's prediction at 8 g (position variance 1e20 m^2) then a 1 mm, 1e-6 deg plot at 50 km: the
    posterior position variances are the plot's (1e-6 and 7.6e-7 m^2); the textbook ``P - K H P``
    (tests/numpy_reference) carries a rounding error of eps x the prior there (it gives 3.1e-7 and 5.5e-7)."""
    dt, q = 3600.0, 8 * 9.80665
    P = kf.predict(np.zeros(4), np.diag([1.0, 1.0, 100.0, 100.0]), kf.transition_cv(dt)[0],
                   kf.process_noise(dt, q)[0])[1]
    R = converted_covariance(5e4, 0.3, 1e-3, np.radians(1e-6))
    ref = _reference_update(P, R)
    got = kf.update(np.zeros(4), P, np.zeros(2), R).P
    np.linalg.cholesky(got)
    np.testing.assert_allclose(np.linalg.eigvalsh(got[:2, :2]), np.linalg.eigvalsh(ref[:2, :2]), rtol=1e-6)


def test_nees_reward_term_is_defined_where_the_position_block_is_singular():
    """The reward's NEES term by the 2 x 2 closed form: a singular (or indefinite) position block, which a solve
    refused with LinAlgError mid-episode, gets the clipped penalty; a regular one the NEES beyond its bound."""
    env = RadarTrackEnv(reward_nees_weight=2.0)
    env.reset(seed=0)
    core = env.unwrapped._core
    P = np.stack([np.diag([1.0, 1.0, 1.0, 1.0]), np.diag([1.0, 0.0, 1.0, 1.0]), np.diag([1.0, -1.0, 1.0, 1.0])])
    fo = np.zeros((3, ek.W_FO))                 # the step kernel's per-row output block: truth, estimate, P, ...
    fo[:, ek.FO_TRUTH:ek.FO_TRUTH + 4] = [30.0, 40.0, 0.0, 0.0]
    fo[:, ek.FO_P:ek.FO_P + 16] = P.reshape(3, 16)
    inconsistency = core._inconsistency(fo)
    clip = core.cfg.reward_clip
    nees = 30.0**2 + 40.0**2
    assert inconsistency[0] == pytest.approx(-2.0 * min(nees / 9.21034037197618 - 1.0, clip))
    assert np.array_equal(inconsistency[1:], [-2.0 * clip, -2.0 * clip])
