"""Reference policies: the papers' rules for choosing q, with the stable-baselines3 ``predict`` interface.

A rule reads its features from the observation (decoded to physical units by the env's
:class:`radar_env.envs.observation.ObservationLayout`, so it sees exactly what an agent sees) and returns an action of
the env's action space. Internally each rule computes ``q`` in m/s^2 (:meth:`ReferencePolicy.q_m_s2`); the
action is the continuous action that maps to that q, or for a discrete env the level nearest in log10.

=================  =====================================================================================  ==========
name               rule                                                                                    source
=================  =====================================================================================  ==========
``kf_low``         q = 0.03 g                                                                              Bizup
``kf_high``        q = 2 g                                                                                 Bizup
``kf_tuned``       q = the constant minimising position RMSE on training seeds (``baselines/tuned.json``)  ours
``kf_blair``       q = Blair's rule of thumb, 0.5 * a_max .. a_max; here 0.5 * 7 g (the random max)       Blair
``cmin``           q = 0.03 g while c_min of the plot < 1 g, else q = c_min  (Q = c_min^2 I)                Bizup 3.3
``ckf``            q = 0.03 g while FMA(|nu|) < 5 NM, else 2 g                                              Bizup/Schutz
``kim_lee``        q = sqrt(phi) from the 12-look innovation window, sigma_D = 0.03 g when phi <= 0       Kim & Lee
=================  =====================================================================================  ==========
"""

from __future__ import annotations

import numpy as np

from radar_env.envs.observation import ObservationLayout
from radar_env.common.units import G0_M_S2, NM_M

from .tuned_params import tuned_parameters

__all__ = ["ReferencePolicy", "ConstantQPolicy", "CminPolicy", "CKFPolicy", "KimLeePolicy", "make_policy",
           "POLICY_NAMES", "BLAIR_Q_G"]

BLAIR_Q_G = 0.5 * 7.0
"""Blair's rule of thumb for a white-noise-acceleration filter: 0.5 a_max <= q <= a_max; lower end for the
random distribution's a_max = 7 g."""


class ReferencePolicy:
    """Base class. Subclasses implement :meth:`q_m_s2` from decoded features.

    Args:
        layout: the env's ``ObservationLayout`` (``env.unwrapped.layout``).
        action_type: ``"continuous"`` or ``"discrete"``.
        q_levels_m_s2: the env's q levels (their first and last give the continuous range).
    """

    requires: tuple = ()
    name = "reference"

    def __init__(self, layout: ObservationLayout, action_type="continuous", q_levels_m_s2=None):
        missing = [f for f in self.requires if f not in layout]
        if missing:
            raise ValueError(f"policy {self.name!r} needs observation feature(s) {missing}; add them to the env's "
                             "features")
        if q_levels_m_s2 is None:
            raise ValueError("q_levels_m_s2 is required (env.unwrapped.q_levels_m_s2)")
        self.layout = layout
        self.action_type = action_type
        self.levels = np.asarray(q_levels_m_s2, dtype=np.float64)
        self._l0, self._l1 = np.log10(self.levels[0]), np.log10(self.levels[-1])

    @classmethod
    def for_env(cls, env, **kwargs):
        """Build for a (possibly wrapped) RadarTrack env."""
        u = env.unwrapped
        return cls(u.layout, u.config.action_type, u.q_levels_m_s2, **kwargs)

    @property
    def reads(self):
        """The observation features the rule decodes (the run needs to encode only these)."""
        return tuple(self.requires)

    def q_m_s2(self, obs):
        raise NotImplementedError

    def q_to_action(self, q):
        lq = np.log10(np.clip(q, self.levels[0], self.levels[-1]))
        if self.action_type == "discrete":
            return np.abs(lq[..., None] - np.log10(self.levels)).argmin(axis=-1)
        return (2.0 * (lq - self._l0) / (self._l1 - self._l0) - 1.0).astype(np.float32)[..., None]

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """stable-baselines3 interface: ``(action, state)`` for one observation (F,) or a batch (n, F)."""
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        q = self.q_m_s2(obs[None] if single else obs)
        act = self.q_to_action(q)
        return (act[0] if single else act), state


class ConstantQPolicy(ReferencePolicy):
    """Constant q (g)."""

    def __init__(self, layout, action_type="continuous", q_levels_m_s2=None, q_g=0.03, name=None):
        super().__init__(layout, action_type, q_levels_m_s2)
        self.q_g = float(q_g)
        self.name = name or f"kf_{q_g:g}g"

    def q_m_s2(self, obs):
        return np.full(np.shape(obs)[0], self.q_g * G0_M_S2)


class CminPolicy(ReferencePolicy):
    """Bizup's c_min tracker: ``Q = (0.03 g)^2 I`` while ``c_min < 1 g``, else ``Q = c_min^2 I``.

    Bizup uses the plots twice, "once to detect ... then again to update": the c_min of plot k sets the Q of the
    update with plot k. That is ``next_c_min_g`` (the preview of the plot the chosen q is for); with an
    observation without the preview the rule falls back to the c_min of the previous plot (one look late)."""

    requires = ()
    name = "cmin"

    def __init__(self, layout, action_type="continuous", q_levels_m_s2=None, low_g=0.03, threshold_g=1.0):
        super().__init__(layout, action_type, q_levels_m_s2)
        self.low_g, self.threshold_g = float(low_g), float(threshold_g)
        self.feature = "next_c_min_g" if "next_c_min_g" in layout else "c_min_g"
        if self.feature not in layout:
            raise ValueError("policy 'cmin' needs observation feature 'next_c_min_g' or 'c_min_g'")

    @property
    def reads(self):
        return (self.feature,)

    def declared(self, obs):
        return self.layout.decode(obs, self.feature) >= self.threshold_g

    def q_m_s2(self, obs):
        c = self.layout.decode(obs, self.feature)
        return np.where(c < self.threshold_g, self.low_g, c) * G0_M_S2


class CKFPolicy(ReferencePolicy):
    """Bizup's Combined KF (after Schutz et al.): ``(0.03 g)^2`` while the fading-memory average of the position
    error is below 5 miles, else ``(2 g)^2``. "Miles" read as nautical miles (the paper's ranges and speeds are in
    NM and knots)."""

    requires = ("fma_innovation_km",)
    name = "ckf"

    def __init__(self, layout, action_type="continuous", q_levels_m_s2=None, low_g=0.03, high_g=2.0,
                 threshold_m=5 * NM_M):
        super().__init__(layout, action_type, q_levels_m_s2)
        self.low_g, self.high_g, self.threshold_m = float(low_g), float(high_g), float(threshold_m)

    def declared(self, obs):
        return self.layout.decode(obs, "fma_innovation_km") * 1e3 >= self.threshold_m

    def q_m_s2(self, obs):
        return np.where(self.declared(obs), self.high_g, self.low_g) * G0_M_S2


class KimLeePolicy(ReferencePolicy):
    """Kim & Lee's adaptive process noise (eqs 13-17) for the 2-D KF: ``q = sqrt(phi)`` from the sliding-window
    innovation covariance, ``q = sigma_D`` when ``phi <= 0`` (eq 17)."""

    requires = ("kim_lee_q_g",)
    name = "kim_lee"

    def __init__(self, layout, action_type="continuous", q_levels_m_s2=None, sigma_D_g=0.03):
        super().__init__(layout, action_type, q_levels_m_s2)
        self.sigma_D_g = float(sigma_D_g)

    def q_m_s2(self, obs):
        q = self.layout.decode(obs, "kim_lee_q_g")
        return np.where(q > 0.0, q, self.sigma_D_g) * G0_M_S2


def make_policy(name, layout, action_type="continuous", q_levels_m_s2=None):
    """Reference policy by name (see module table)."""
    if name == "kf_low":
        return ConstantQPolicy(layout, action_type, q_levels_m_s2, 0.03, name)
    if name == "kf_high":
        return ConstantQPolicy(layout, action_type, q_levels_m_s2, 2.0, name)
    if name == "kf_tuned":
        return ConstantQPolicy(layout, action_type, q_levels_m_s2, tuned_parameters()["kf"]["q_g"], name)
    if name == "kf_blair":
        return ConstantQPolicy(layout, action_type, q_levels_m_s2, BLAIR_Q_G, name)
    classes = {"cmin": CminPolicy, "ckf": CKFPolicy, "kim_lee": KimLeePolicy}
    if name not in classes:
        raise ValueError(f"unknown reference policy {name!r}; valid: {list(POLICY_NAMES)}")
    return classes[name](layout, action_type, q_levels_m_s2)


POLICY_NAMES = ("kf_low", "kf_high", "kf_tuned", "kf_blair", "cmin", "ckf", "kim_lee")
