"""The Gym layer's fast paths equal the plain code they replace, bit for bit: the observation encoding (one
vectorised transform) against a frozen copy of the column-by-column encoding, and the action checks."""

import numpy as np
import pytest

from radar_env.envs.config import EnvConfig
from radar_env.envs.core import _Core, actions_to_q_m_s2
from radar_env.envs.observation import (DEFAULT_FEATURES, DETECTOR_FEATURES, FEATURE_SPECS, PAST_FEATURES,
                                   ObservationLayout)
from radar_env.common.units import G0_M_S2


def _frozen_encode(lay, out, q_prev):
    """The encoding as it was: physical values column by column, then the scalings with boolean masks."""
    phys = lay.physical(out, q_prev)
    scale = np.array([s.scale for s in lay.specs])
    log10p = np.array([s.kind == "log10p" for s in lay.specs])
    logq = np.array([s.kind == "logq" for s in lay.specs])
    obs = phys / scale
    if log10p.any():
        obs[..., log10p] = np.log10(1.0 + np.maximum(phys[..., log10p], 0.0)) / scale[log10p]
    if logq.any():
        lq = np.log10(np.maximum(phys[..., logq], 1e-12))
        obs[..., logq] = 2.0 * (lq - lay._lq0) / (lay._lq1 - lay._lq0) - 1.0
    obs[np.isnan(obs)] = 0.0
    return np.clip(obs, lay.low, lay.high).astype(np.float32)


@pytest.fixture(scope="module")
def outputs():
    core = _Core(8, EnvConfig())
    core.rngs = [np.random.default_rng(s) for s in range(8)]
    core.reset()
    out0 = core.tracker.load(np.arange(8), core._draw(np.arange(8)))   # a track start's StepOutput
    outs = [out0]
    rng = np.random.default_rng(1)
    for _ in range(3):
        core.step(rng.integers(0, 13, 8))
        outs.append(core.tracker.step(np.full(8, 0.3 * G0_M_S2)))
    # extreme values: NaN, +-inf, negatives and huge numbers in every feature
    o = outs[-1]
    wild = {k: v.astype(np.float64).copy() for k, v in o.features.items()}
    for k in wild:
        wild[k][:5] = [np.nan, np.inf, -np.inf, -3.0, 1e300]
    outs.append(o._replace(features=wild, dt_s=np.array([np.nan, 0, 1e9, -1, 5, 5, 5, 5.0])))
    return outs


@pytest.mark.parametrize("names", [DEFAULT_FEATURES, PAST_FEATURES, ("detected",), ("q_prev_g", "nis"),
                                   tuple(reversed(DEFAULT_FEATURES)), ("next_q_fit_g",)], ids=str)
def test_encode_equals_the_columnwise_encoding(outputs, names):
    lay = ObservationLayout(names, 0.002 * G0_M_S2, 8 * G0_M_S2)
    for out in outputs:
        for q in (np.linspace(0.0, 50.0, 8), 0.3 * G0_M_S2):
            with np.errstate(all="ignore"):   # the wild values overflow (in both encodings alike)
                new, old = lay.encode(out, q), _frozen_encode(lay, out, q)
                again = lay.encode_physical(lay.physical(out, q))
            assert new.dtype == np.float32 and new.flags.c_contiguous and new.shape == (8, len(names))
            np.testing.assert_array_equal(new, old)
            np.testing.assert_array_equal(again, old)


def test_encode_physical_keeps_leading_shape():
    lay = ObservationLayout(DEFAULT_FEATURES)
    phys = np.random.default_rng(0).normal(size=(2, 3, len(DEFAULT_FEATURES)))
    assert lay.encode_physical(phys).shape == phys.shape
    np.testing.assert_array_equal(lay.encode_physical(phys)[1], lay.encode_physical(phys[1]))
    assert set(FEATURE_SPECS) == set(DEFAULT_FEATURES) | set(DETECTOR_FEATURES)   # the detectors: opt-in


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_action_to_q_matches_the_action_map_and_refuses_bad_actions(action_type):
    core = _Core(3, EnvConfig(action_type=action_type))
    L = core.levels_m_s2.size
    if action_type == "discrete":
        for a in ([0, 5, L - 1], np.array([2, 2, 2], dtype=np.uint8), np.array([1.0, 0.0, 12.0])):
            np.testing.assert_array_equal(core.action_to_q(a), actions_to_q_m_s2(np.asarray(a), "discrete",
                                                                                 core.levels_m_s2))
        bad = ([0, 1], [0, 1, L], [-1, 0, 0], [0.5, 0, 0], [np.nan, 0, 0], [np.inf, 0, 0],
               np.array([2**63 + 1, 0, 0], dtype=np.uint64), [True, False, True], ["0", "1", "2"])
    else:
        for a in ([-1.0, 0.0, 1.0], np.array([[0.3], [-0.2], [1.0 + 1e-7]], dtype=np.float32), [0, 1, -1]):
            np.testing.assert_array_equal(core.action_to_q(a), actions_to_q_m_s2(
                np.asarray(a, dtype=np.float64).reshape(-1), "continuous", core.levels_m_s2))
        bad = ([0.0, 0.0], [0.0, 0.0, 1.1], [np.nan, 0, 0], [np.inf, 0, 0], [-np.inf, 0, 0], [True, False, True],
               [1j, 0, 0])
    for a in bad:
        with pytest.raises(ValueError, match="action must"):
            core.action_to_q(a)


def test_unknown_reset_options_and_features_name_the_valid_ones():
    from radar_env.envs.env import RadarTrackEnv, RadarTrackVectorEnv

    for env in (RadarTrackEnv(scenario="kim_lee_accel"), RadarTrackVectorEnv(2, scenario="kim_lee_accel")):
        with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['speed'\]; valid: \['scenario'\]"):
            env.reset(seed=0, options={"speed": 1, "scenario": "kim_lee_accel"})
    with pytest.raises(ValueError, match=r"^unknown feature\(s\) \['bogus'\]; valid: \['nu_along'"):
        ObservationLayout(("nis", "bogus"))
