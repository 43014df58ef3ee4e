"""``rbpf``, ``rbpf_ref`` and ``rbpf_rdot``: the Rao-Blackwellised particle filter of :mod:`radar_env.filters.rbpf`
run on episodes.

``rbpf`` is a tracker: it knows the random flights' regime laws (:class:`radar_env.sim.scenario.RandomScenarioConfig`)
but not where a flight started, as a deployed tracker would; it is the 100 of the normalised score
(:mod:`agents.evaluation.scores`). ``rbpf_ref`` also uses what the generator says about the flight's start (its first
leg's law from ``t = 0``, the number of legs): everything the laws give a causal filter on ``random``. Measured, it
converges to the same RMSE as ``rbpf`` and more slowly in the particle count (docs/trackers.md), so ``rbpf`` stands in
the tables. ``rbpf_rdot`` is ``rbpf`` updating on the plots' radial velocity too. On every suite but ``random`` they
are trackers with a mismatched prior.

Both start from the common track start (two-hit start and warm-up, as every tracker) and run on the same converted
plots and R. Each row's random stream is keyed by a hash of its looks (times and plots), so the same episode gives the
same numbers in any batch and any order.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np

from radar_env.filters.rbpf import DEFAULT_RBPF, RBPFSpec, rbpf_filter

from .imm_cv_ct_runner import _declared, common_start
from .trackers import TrackRun

__all__ = ["RBPFSpec", "DEFAULT_RBPF", "RBPF_REF", "RBPF_RDOT", "episode_key", "run_rbpf"]

RBPF_REF = replace(DEFAULT_RBPF, flight_start_known=True)
"""``rbpf_ref``'s settings: ``rbpf``'s, knowing the flight's start."""
RBPF_RDOT = replace(DEFAULT_RBPF, radial_velocity=True, rdot_noise_scale=1.0)
"""``rbpf_rdot``'s settings: ``rbpf``'s, also updating on the plots' radial velocity."""


def episode_key(episode) -> np.uint64:
    """The random-stream key of one episode's particle filter: a hash of its look times and plots."""
    h = hashlib.blake2b(digest_size=8)
    h.update(np.ascontiguousarray(episode.t_s, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(np.nan_to_num(episode.z_m), dtype=np.float64).tobytes())
    return np.uint64(int.from_bytes(h.digest(), "little"))


def run_rbpf(episodes, spec: RBPFSpec = DEFAULT_RBPF, name="rbpf", cfg=None, start=None):
    """The particle filter on recorded episodes from the common track start. Returns a
    :class:`baselines.trackers.TrackRun` with extra series ``maneuver_probability`` (the weight of particles off a
    straight leg), ``turn_rate_deg_s`` (the mean turn rate, straight particles counting 0) and ``ess`` (effective
    sample size before resampling); ``start``: a :func:`baselines.imm_cv_ct_runner.common_start` result to reuse."""
    episodes = list(episodes)
    batch, k0, x4, P4 = start if start is not None else common_start(episodes, cfg)
    B, K = batch.t_s.shape
    keys = np.array([episode_key(e) for e in episodes], dtype=np.uint64)
    x, P, p_man, w, ess = rbpf_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x4,
                                      P4, keys, spec, batch.radial_velocity_m_s, batch.site_xy_m,
                                      batch.radial_velocity_noise_std_m_s)
    rows = np.arange(B)
    x[rows, k0], P[rows, k0] = x4, P4      # the start look, as every tracker records it
    return TrackRun(name, x, P, k0 + 1, np.full((B, K), np.nan), declared=_declared(p_man),
                    extra={"maneuver_probability": p_man, "turn_rate_deg_s": np.degrees(w), "ess": ess})
