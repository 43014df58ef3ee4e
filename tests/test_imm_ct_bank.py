"""The IMM over a bank of CT modes (``IMMCVCTSpec.ct_rates_deg_s``; the registered ``imm_ct_bank``): the numba kernel
against the torch IMM (an independent implementation of the mixing: per-target turn rates of the CV sources as
tensors) to 1e-9 on every kind of look stream, with constant and per-look parameters; the mixing against its closed
form; the default spec unchanged; the spec's checks; the refusals (a rate out of range in the env, the learned IMM's
option on a q-policy); the learned IMM around the bank with range rate built on imm_ct_bank_rdot."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from baselines import imm_cv_ct_runner as I  # noqa: E402
from radar_env.filters import imm_cv_ct as C  # noqa: E402
from radar_env.common.units import DEG  # noqa: E402
from test_torch_chain import _episodes  # noqa: E402
from test_torch_imm import _consts, torch_and_numba  # noqa: E402

BANK = I.IMMCVCTSpec(q_cv_g=1.8e-4, q_ct_g=0.26, sigma_omega_deg_s15=0.001, sigma_omega0_deg_s=2.0, p_stay_cv=0.991,
                     p_stay_ct=0.977, q_high_g=7.2, p_stay_high=0.984, ct_rates_deg_s=(17.3, 1.25, 8.56))
BANK_SUITES = ("random", "random_radars", "adrian_flower", "two_sites_same_time", "three_sites_irregular",
               "missed_looks")


def test_bank_spec_layout():
    assert BANK.ct_rates_deg_s == (1.25, 8.56, 17.3)            # stored sorted
    assert (BANK.n_ct, BANK.n_modes, BANK.is_bank) == (6, 8, True)
    is_ct, q, log_Pi, log_mu0 = BANK.mode_arrays()
    assert is_ct.tolist() == [False] + [True] * 6 + [False]
    np.testing.assert_allclose(np.exp(log_Pi).sum(1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(np.diag(np.exp(log_Pi)), [0.991] + [0.977] * 6 + [0.984], rtol=1e-14)
    assert np.all(q[1:7] == q[1]) and np.exp(log_mu0).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(BANK.entry_rates() / DEG, [0, 1.25, -1.25, 8.56, -8.56, 17.3, -17.3, 0], rtol=1e-14)
    d = C.IMMCVCTSpec()                                          # the default: one CT mode entered at 0
    assert (d.n_ct, d.n_modes, d.is_bank) == (1, 3, False) and not d.entry_rates().any()
    assert "entry_w" not in d.filter_constants()
    assert C.imm_cv_ct_spec_from_params({"ct_rate_1_deg_s": 3, "ct_rate_2_deg_s": 1}).ct_rates_deg_s == (1.0, 3.0)


@pytest.mark.parametrize("rates, match", [((0.0,), "ct_rates_deg_s"), ((25.0,), "ct_rates_deg_s"),
                                          ((1, 2, 3, 4), "at most 3"), ("5", "sequence"), ({1: 2}, "sequence"),
                                          ((float("nan"),), "ct_rates_deg_s")])
def test_bank_spec_refuses(rates, match):
    with pytest.raises(ValueError, match=match):
        C.IMMCVCTSpec(ct_rates_deg_s=rates)


@pytest.mark.parametrize("per_look", [False, True], ids=["constant", "per_look"])
@pytest.mark.parametrize("suite", BANK_SUITES)
def test_bank_torch_equals_the_numba_kernel(suite, per_look):
    _, res, looks = torch_and_numba(BANK, suite, per_look, seed=12, param_seed=3)
    # the CT modes took different turn rates (the bank is not one mode six times)
    m = looks.scored_mask.numpy()
    w = looks.align(res.x_modes[..., 4]).numpy()[m]
    assert np.ptp(w[:, 1:7], axis=1).max() > 1.0 * DEG


def test_bank_mixing_closed_form():
    """At dt = 0 the CT mode k's predicted turn rate is the mixture's: the CV modes (CV and high CV) enter at
    r_k with variance sigma_omega0^2, CT mode j brings its own rate and variance: x0_k[4] = sum_i w_ik om_ik,
    P0_k[4, 4] = sum_i w_ik (P_i44 + (om_ik - x0_k[4])^2), w_ik = Pi_ik mu_i / c_k (inside the turn-rate bound)."""
    x = np.array([1e4, 2e4, 150.0, -80.0])
    P = np.diag([400.0, 400.0, 100.0, 100.0])
    xm, Pm, lm = C.initial_modes(BANK, x, P)
    xm[1:7, 4] = np.array([0.5, -1.0, 3.0, 7.0, -2.0, 0.1]) * DEG     # the CT modes' own rates and variances
    Pm[1:7, 4, 4] = np.array([1.0, 4.0, 0.5, 2.0, 3.0, 1.5]) * DEG ** 2
    lm = np.log(np.array([0.5, 0.05, 0.1, 0.05, 0.1, 0.05, 0.05, 0.1]))
    pred = C.predict_modes(BANK, xm, Pm, lm, 0.0)
    _, _, log_Pi, _ = BANK.mode_arrays()
    a = np.exp(log_Pi + lm[:, None])                               # a[i, k] = Pi_ik mu_i
    om = np.where(BANK.mode_arrays()[0][:, None], xm[:, 4][:, None], BANK.entry_rates()[None, :])
    want = (a * om).sum(0) / a.sum(0)
    np.testing.assert_allclose(pred.x_modes[1:7, 4], want[1:7], rtol=1e-12)
    np.testing.assert_allclose(pred.log_c, np.log(a.sum(0)), rtol=1e-12)
    var = np.where(BANK.mode_arrays()[0], Pm[:, 4, 4], (BANK.sigma_omega0_deg_s * DEG) ** 2)[:, None]
    want_var = (a * (var + (om - want[None]) ** 2)).sum(0) / a.sum(0)
    np.testing.assert_allclose(pred.P_modes[1:7, 4, 4], want_var[1:7], rtol=1e-10)


def test_default_spec_has_no_entry_rates_in_torch():
    c = _consts(I.tuned_imm_cv_ct_spec())
    assert c.entry_w == () and c.entry_ct == (0.0,)


@pytest.mark.parametrize("name", ["imm_ct_bank", "imm_ct_bank_rdot"])
def test_tuned_bank_is_registered(name):
    from baselines.registry import RANGE_RATE_TRACKERS, TRACKER_NAMES, run_tracker
    spec = I.tuned_imm_cv_ct_spec(name)
    assert name in TRACKER_NAMES and spec.is_bank and len(spec.ct_rates_deg_s) == 3
    assert (name in RANGE_RATE_TRACKERS) == name.endswith("_rdot")
    eps = _episodes("random", 3, seed=5)
    r = run_tracker(name, eps)
    assert r.name == name and np.isfinite(r.x[:, r.start_index.max():][:, :50]).all()
    rdot = name.endswith("_rdot")      # the registry runs its own tuned spec, with range rate for the _rdot one
    ref = I.run_imm_cv_ct(eps, spec, name, None, radial_velocity=rdot)
    np.testing.assert_array_equal(r.x, ref.x)
    if rdot:                          # the range rate moved the estimates: not the position-only run of its spec
        plain = I.run_imm_cv_ct(eps, spec, name, None)
        assert np.nanmax(np.abs(plain.x - r.x)) > 1.0
        other = I.run_imm_cv_ct(eps, I.tuned_imm_cv_ct_spec("imm_cv_ct_rdot"), name, None, radial_velocity=True)
        assert np.nanmax(np.abs(other.x - r.x)) > 1.0      # nor imm_cv_ct_rdot's


def test_first_start_of_the_bank_with_range_rate():
    """The tuner's first start (first_start_values): imm_ct_bank_rdot's is imm_ct_bank's rates with imm_cv_ct_rdot's
    other values (the later tracker of FIRST_START_FROM wins), its own previous values when it has them; the bank's
    is imm_cv_ct's; another range-rate tracker's its own, else its position-only sibling's."""
    from baselines.tuning import first_start_values
    old = {"imm_cv_ct": {"q_cv_g": 4.0}, "imm_ct_bank": {"q_cv_g": 1.0, "ct_rate_1_deg_s": 3.0},
           "imm_cv_ct_rdot": {"q_cv_g": 2.0, "p_stay_cv": 0.9}, "imm2": {"q_low_g": 0.01}}
    assert first_start_values(old, "imm_ct_bank_rdot") == {"q_cv_g": 2.0, "ct_rate_1_deg_s": 3.0, "p_stay_cv": 0.9}
    assert first_start_values({**old, "imm_ct_bank_rdot": {"q_cv_g": 5.0}}, "imm_ct_bank_rdot") == {"q_cv_g": 5.0}
    assert first_start_values({"imm_cv_ct": {"q_cv_g": 4.0}}, "imm_ct_bank") == {"q_cv_g": 4.0}
    assert first_start_values(old, "imm_ct_bank") == old["imm_ct_bank"]
    assert first_start_values(old, "imm_cv_ct_rdot") == old["imm_cv_ct_rdot"]
    assert first_start_values(old, "imm2_rdot") == old["imm2"] and first_start_values(old, "kf") is None


def test_refusals_of_a_bank():
    import gymnasium as gym
    import radar_env  # noqa: F401
    with pytest.raises(ValueError, match="imm_parameters: IMMCVCTSpec.ct_rates_deg_s"):
        gym.make("RadarTrack-v0", tracker="imm_cv_ct", imm_parameters={"ct_rate_1_deg_s": 30.0})
    from agents.training import backprop as bp
    from agents.training.runs import load_hyperparams
    with pytest.raises(ValueError, match="--hp imm: an option of the learned IMM"):
        bp.check_hp(dict(load_hyperparams("backprop"), imm="imm_ct_bank"))
    with pytest.raises(ValueError, match="--hp imm: must be one of"):
        bp.check_hp(dict(load_hyperparams("backprop_imm_cv_ct"), imm="imm3_ct"))
    hp, _, cfg = bp.check_hp(dict(load_hyperparams("backprop_imm_cv_ct"), imm="imm_ct_bank", chain="torch",
                                  env_kwargs={**load_hyperparams("backprop_imm_cv_ct")["env_kwargs"],
                                              "radial_velocity": True}))
    model = bp.make_model(hp, cfg)         # with range rate: around imm_ct_bank_rdot's tuned spec
    assert model.spec == I.tuned_imm_cv_ct_spec("imm_ct_bank_rdot")
