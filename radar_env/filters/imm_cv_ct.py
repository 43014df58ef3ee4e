r"""The CV / CT-EKF IMM (``imm_cv_ct``): its model, parameters and compiled per-look kernel, written once for
the tracker (:mod:`baselines.imm_cv_ct_runner`, which runs it on episodes) and the env (``RadarTrack-v0`` with
``tracker="imm_cv_ct"``, :mod:`radar_env.envs.imm_env`): a mixed-order IMM of a constant-velocity mode and a
coordinated-turn EKF mode whose turn rate is a state, optionally with a third, high-noise CV mode.

Models
------
CV mode, state :math:`[x, y, v_x, v_y]` (m, m/s): :math:`F_{cv}(dt)` and the piecewise-constant white-acceleration
noise :math:`Q(dt, q_{cv})` of :func:`radar_env.filters.kalman.process_noise`.

CT mode, state :math:`[x, y, v_x, v_y, \omega]` (:math:`\omega` in rad/s, positive = clockwise = right turn, as in
:mod:`radar_env.filters.kalman`), the exact coordinated-turn motion with :math:`\theta = \omega\,dt`:

.. math::
    x' = x + a v_x + b v_y,\quad y' = y - b v_x + a v_y,\quad
    v_x' = \cos\theta\,v_x + \sin\theta\,v_y,\quad v_y' = -\sin\theta\,v_x + \cos\theta\,v_y,\quad \omega' = \omega

with :math:`a = \sin\theta/\omega = dt\,\mathrm{sinc}\,\theta` and :math:`b = (1-\cos\theta)/\omega`. The EKF
linearises with the analytic Jacobian; its :math:`\omega` column is
:math:`\partial a/\partial\omega = dt^2 (\theta\cos\theta - \sin\theta)/\theta^2`,
:math:`\partial b/\partial\omega = dt^2 (\theta\sin\theta - 1 + \cos\theta)/\theta^2`,
:math:`\partial v_x'/\partial\omega = dt(-\sin\theta\,v_x + \cos\theta\,v_y)`,
:math:`\partial v_y'/\partial\omega = -dt(\cos\theta\,v_x + \sin\theta\,v_y)`. Every coefficient is evaluated by its
Taylor series (to :math:`\theta^9`) for :math:`|\theta| < 0.1`, so the motion and the Jacobian are smooth and
accurate to rounding at :math:`\omega \to 0`, where the CT motion is the CV motion. Process noise: the same
:math:`Q(dt, q_{ct})` on the acceleration and an independent turn-rate random walk,
:math:`\mathrm{var}(\Delta\omega) = \sigma_\omega^2\,dt` (:math:`\sigma_\omega` in rad/s^1.5; the spec takes it in
deg/s^1.5): over a look of ``dt`` seconds the turn rate diffuses by :math:`\sigma_\omega\sqrt{dt}`. This is Stone
Soup's ``ConstantTurn`` turn noise with ``turn_noise_coeff = sigma_omega^2``.

Optional high-noise CV mode: the CV model at ``q_high`` (speed changes and turns the CT mode has not yet caught).

Mixing between the 4- and 5-state modes
---------------------------------------
Every mode is carried in the 5-state space. A CV mode's state is augmented with :math:`\omega = 0`, variance
:math:`\sigma_{\omega 0}^2` (``sigma_omega0_deg_s``), uncorrelated with the rest. Why this and not the CT mode's own
:math:`\omega`: under the IMM's Markov model, "CV at k-1 and CT at k" is the start of a turn, and the CV hypothesis
carries no information on the rate of the turn that starts; its rate is a draw from the prior of turn rates at onset,
symmetric left/right (mean 0) with a spread of typical turn rates. Borrowing the CT mode's :math:`\omega` instead
would let an old turn's rate (left over in the CT mode after the turn ended) start the next turn, which may go the
other way. Measured on the 100 tuning episodes of the defaults (below): 78.4 m with this choice, 82.7 m when the CV
modes borrow the CT mode's turn-rate mean and variance for the mixing instead (other parameters unchanged, not
re-tuned for that variant; with ``sigma_omega0_deg_s`` at 3 or 20 deg/s: 79.1 / 78.8 m against 82.7 / 82.7 m).

The mixed mean and covariance into each mode are the usual moment-matched mixture in the 5-state space
(:math:`x_{0j} = \sum_i \mu_{i|j} x_i`, :math:`P_{0j} = \sum_i \mu_{i|j}(P_i + (x_i - x_{0j})(x_i - x_{0j})^T)`);
the CT mode takes all five components, a CV mode its 4-state marginal (its :math:`\omega` part is reset to the
augmentation, so the 4-state CV arithmetic is exactly that of a 4-state KF: the zero cross-covariances make the fifth
row inert). Mode probabilities are carried as logs (the log-space mixing of :func:`radar_env.filters.kalman.imm_mix`); the
update is the chain's (:func:`radar_env.filters.kalman.update`'s covariance form and floor, positive definite); NIS and
the Gaussian log-likelihood are those of :func:`radar_env.filters.kalman.update` (a
missed look: posterior = prior, log-likelihood 0). The output per look is the moment-matched combination of the
modes' 4-state marginals, the combined turn rate :math:`\sum_j \mu_j \omega_j` (a CV mode's turn rate is 0), and the
maneuver probability :math:`1 - \mu_{cv}` (the CT mode's probability when there is no third mode; with a third mode,
the high-noise CV mode counts as maneuvering too); declared = maneuver probability > 0.5.

A bank of CT modes
------------------
With ``ct_rates_deg_s = (r_1, ..., r_K)`` (:class:`IMMCVCTSpec`; the registered tracker ``imm_ct_bank``, K = 3) the
single CT mode becomes 2K CT modes, in the order ``+r_1, -r_1, +r_2, ...`` after the CV mode (the high-noise CV mode
last). They share ``q_ct_g``, ``sigma_omega_deg_s15`` and ``p_stay_ct`` and differ only where a turn starts: a CV
mode mixes into CT mode ``k`` as :math:`[x, \pm r_k]`, variance :math:`\sigma_{\omega 0}^2` (instead of
:math:`[x, 0]`), so the prior of a turn's rate at its onset is a mixture of narrow peaks at both signs of several
rates, which one CT mode with a wide :math:`\sigma_{\omega 0}` cannot hold. Everything else is the model above
(a CT mode mixing into another brings its own turn rate; every mode leaves with ``1 - p_stay`` split equally among
the others; every mode starts at the common track start, turn rate 0). Why: on the random flights (training-range
seeds) the tuned bank is 0.96x ``imm_cv_ct`` on ``random`` and 0.93x on ``random_radars`` (docs/trackers.md);
with two rates it was 0.98x / 0.95x. The default (``ct_rates_deg_s = ()``) is the single CT mode, bit for bit.

The turn-rate bound
-------------------
With plots ``T`` seconds apart, a turn rate :math:`\omega` and :math:`\omega + 2\pi/T` give the same velocity at the
plot times, so an unbounded :math:`\omega` can lock on an alias at a long scan period and stay there. The CT mode's
:math:`\omega` mean is clipped to :math:`|\omega| \le \min(\omega_{max},\ a_{max} / \max(|v|, 1\,\mathrm{m/s}))`
after mixing and after every update (``omega_max_deg_s``, default 20 deg/s, the random scenarios' cap;
``turn_accel_max_g``, default 8 g, above the 7 g of the hardest random turn; ``|v|`` the mode's own speed estimate).
The clipped mean is the mode of the Gaussian truncated to the interval; the covariance is left unchanged (slightly
conservative: the truncated variance is smaller), so the filter stays free to move back inside.

Parameters
----------
:class:`IMMCVCTSpec` (frozen, validated). The vector a tuner optimises is :data:`IMM_CV_CT_PARAMS` (name, unit,
physical bounds, whether to search in log scale), turned into a spec by :func:`imm_cv_ct_spec_from_params`:

=======================  ==========  =================  =======================================================
``q_cv_g``               g           [1e-5, 1]          CV mode's acceleration noise
``q_ct_g``               g           [1e-3, 3]          CT mode's acceleration noise
``sigma_omega_deg_s15``  deg/s^1.5   [1e-3, 10]         CT turn-rate random walk
``sigma_omega0_deg_s``   deg/s       [0.1, 30]          turn-rate prior at a turn's onset (the CV augmentation)
``p_stay_cv``            --          [0.5, 0.9999]      P(CV at k | CV at k-1), per look
``p_stay_ct``            --          [0.5, 0.9999]      P(CT at k | CT at k-1), per look
``q_high_g``             g           [0.1, 100]         third mode (high-noise CV) noise; absent = two modes
``p_stay_high``          --          [0.5, 0.9999]      its stay probability (three modes only)
=======================  ==========  =================  =======================================================

A mode leaves with probability ``1 - p_stay`` split equally among the other modes. Fixed (not tuned): the initial
mode probabilities (``mu0_cv`` = 0.9 on CV, the rest split equally), the turn-rate bound.

How the defaults (:data:`DEFAULT_IMM_CV_CT`) and the tuned values (``baselines/tuned.json``, what the
``imm_cv_ct`` tracker runs with) were chosen: :mod:`baselines.imm_cv_ct_runner`. Everything here is plain numpy and numba
(no Gymnasium, no baselines).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import NamedTuple

import numba
import numpy as np

from .kernels import _gain_update, _logsumexp, _pd_floor, _plot_nis, _rdot_update, _symmetrize
from ..sim.looks import L_DET, L_RDOT, L_RDSTD, L_SITE, range_rate_inputs
from ..common.units import DEG, G0_M_S2
from ..common.validate import check_known_keys, check_number

__all__ = ["IMMCVCTSpec", "DEFAULT_IMM_CV_CT", "IMM_CV_CT_PARAMS", "IMM_CT_BANK_PARAMS", "DEFAULT_CT_BANK_RATES_DEG_S",
           "LOOK_PARAMS", "imm_cv_ct_spec_from_params",
           "look_parameter_names", "look_parameter_vector", "check_look_parameters", "kernel_parameters",
           "ct_motion", "ct_jacobian", "initial_modes", "predict_modes", "update_modes", "ModePrediction",
           "ModeUpdate", "detector_names", "detector_inputs", "initial_detectors"]

MAX_CT_RATES = 3
"""Most rates of a bank of CT modes (:attr:`IMMCVCTSpec.ct_rates_deg_s`; 2 modes each; the parameters
``ct_rate_1_deg_s`` .. ``ct_rate_3_deg_s`` of :data:`IMM_CT_BANK_PARAMS`)."""

SERIES_THETA = 0.1
"""Below this |omega dt| (rad) the CT coefficients are evaluated by their Taylor series."""

MIN_SPEED_FOR_BOUND_M_S = 1.0
"""Speed floor (m/s) in the g-limit ``a_max / |v|`` of the turn-rate bound."""

_LOG_2PI = float(np.log(2.0 * np.pi))

OMEGA_SCALE_DEG_S = 20.0
"""Scale of the turn-rate detector (:func:`detector_inputs`) (imm_cv_ct's default turn-rate bound)."""
STD_FLOOR_DEG_S = 1e-3
"""Floor of the turn-rate standard deviation in :func:`detector_inputs` (deg/s)."""


# ------------------------------------------------------------------------------------------------ parameters
IMM_CV_CT_PARAMS = (
    # name, unit, low, high, log scale
    ("q_cv_g", "g", 1e-5, 1.0, True),
    ("q_ct_g", "g", 1e-3, 3.0, True),
    ("sigma_omega_deg_s15", "deg/s^1.5", 1e-3, 10.0, True),
    ("sigma_omega0_deg_s", "deg/s", 0.1, 30.0, True),
    ("p_stay_cv", "", 0.5, 0.9999, False),
    ("p_stay_ct", "", 0.5, 0.9999, False),
    ("q_high_g", "g", 0.1, 100.0, True),
    ("p_stay_high", "", 0.5, 0.9999, False),
)
"""The tunable parameters: ``(name, unit, low, high, log_scale)``; the bounds are the physical/valid ranges
:class:`IMMCVCTSpec` accepts. ``q_high_g`` and ``p_stay_high`` apply only with the third mode."""

LOOK_PARAMS = ("q_cv_g", "q_ct_g", "sigma_omega_deg_s15", "p_stay_cv", "p_stay_ct", "q_high_g", "p_stay_high")
"""The parameters that may be given per row and look (``params`` of :func:`imm_cv_ct_filter`,
:class:`IMMCVCTStepper`), in the order of a parameter vector: every tunable one but ``sigma_omega0_deg_s`` (the
turn-rate prior of the CV augmentation, a constant of the mixing). Two modes: the first five."""

_RANGES = {name: (lo, hi) for name, _, lo, hi, _ in IMM_CV_CT_PARAMS}
_RANGES.update(omega_max_deg_s=(0.1, 180.0), turn_accel_max_g=(0.1, 100.0), mu0_cv=(0.01, 0.99))


@dataclass(frozen=True)
class IMMCVCTSpec:
    """Parameters of :func:`run_imm_cv_ct` (see the module docstring; every value is checked when built).

    Attributes:
        q_cv_g: CV mode acceleration noise, g.
        q_ct_g: CT mode acceleration noise, g.
        sigma_omega_deg_s15: CT turn-rate random walk, deg/s^1.5 (``var(d omega) = sigma^2 dt``).
        sigma_omega0_deg_s: turn-rate standard deviation of the CV mode's augmentation (a turn's onset), deg/s.
        p_stay_cv, p_stay_ct: per-look stay probabilities.
        q_high_g: noise of a third, high-noise CV mode, g; ``None`` = two modes.
        p_stay_high: its stay probability (ignored with two modes).
        omega_max_deg_s: turn-rate bound, deg/s.
        turn_accel_max_g: g-limit of the turn-rate bound (``|omega| <= a_max / |v|``), g.
        mu0_cv: initial CV mode probability (the rest split equally).
        ct_rates_deg_s: a bank of CT modes (module docstring, "A bank of CT modes"): for each rate ``r`` (deg/s,
            in ``(0, omega_max_deg_s]``) two CT modes a CV mode enters at ``+r`` and ``-r`` (right and left
            turns); a tuple or list, stored sorted, at most :data:`MAX_CT_RATES` rates (a repeated rate gives
            redundant modes). Empty (default): one CT mode entered at 0.
    """

    q_cv_g: float = 1e-4
    q_ct_g: float = 0.58
    sigma_omega_deg_s15: float = 0.0055
    sigma_omega0_deg_s: float = 9.9
    p_stay_cv: float = 0.9906
    p_stay_ct: float = 0.978
    q_high_g: float | None = 30.0
    p_stay_high: float = 0.988
    omega_max_deg_s: float = 20.0
    turn_accel_max_g: float = 8.0
    mu0_cv: float = 0.9
    ct_rates_deg_s: tuple = ()

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if (f.name == "q_high_g" and v is None) or f.name == "ct_rates_deg_s":
                continue
            lo, hi = _RANGES[f.name]
            object.__setattr__(self, f.name, check_number(f"IMMCVCTSpec.{f.name}", v, lo, hi))
        rates = self.ct_rates_deg_s
        if not isinstance(rates, (tuple, list)) or len(rates) > MAX_CT_RATES:
            raise ValueError(f"IMMCVCTSpec.ct_rates_deg_s must be a sequence of at most {MAX_CT_RATES} turn rates "
                             f"(deg/s), got {rates!r}")
        rates = tuple(sorted(check_number("IMMCVCTSpec.ct_rates_deg_s", r, 0.0, self.omega_max_deg_s, lo_open=True)
                             for r in rates))
        object.__setattr__(self, "ct_rates_deg_s", rates)

    @property
    def n_ct(self):
        """Number of CT modes: 2 per bank rate, else 1."""
        return 2 * len(self.ct_rates_deg_s) if self.ct_rates_deg_s else 1

    @property
    def n_modes(self):
        return 1 + self.n_ct + (self.q_high_g is not None)

    @property
    def is_bank(self):
        """Whether the CT modes are a bank (:attr:`ct_rates_deg_s` given)."""
        return bool(self.ct_rates_deg_s)

    def mode_arrays(self):
        """``(is_ct (M,) bool, q_m_s2 (M,), log_Pi (M, M), log_mu0 (M,))`` in mode order CV, CT (the bank's
        ``+r_1, -r_1, +r_2, ...``)[, high CV]. Every mode stays with its ``p_stay`` and leaves to each other mode
        with ``(1 - p_stay) / (M - 1)``; every CT mode has ``q_ct_g`` and ``p_stay_ct``."""
        M, n_ct, high = self.n_modes, self.n_ct, self.q_high_g is not None
        stay = [self.p_stay_cv] + [self.p_stay_ct] * n_ct + ([self.p_stay_high] if high else [])
        Pi = np.empty((M, M))
        for i in range(M):
            Pi[i] = (1.0 - stay[i]) / (M - 1)
            Pi[i, i] = stay[i]
        mu0 = np.full(M, (1.0 - self.mu0_cv) / (M - 1))
        mu0[0] = self.mu0_cv
        q = [self.q_cv_g] + [self.q_ct_g] * n_ct + ([self.q_high_g] if high else [])
        is_ct = np.array([False] + [True] * n_ct + ([False] if high else []))
        return is_ct, np.asarray(q) * G0_M_S2, np.log(Pi), np.log(mu0)

    def mode_names(self):
        """The modes' names in the spec's order: ``cv``, ``ct`` (a bank's: ``ct+r``, ``ct-r`` per rate, deg/s)[,
        ``high``]."""
        ct = [f"ct{s}{r:g}" for r in self.ct_rates_deg_s for s in "+-"] if self.is_bank else ["ct"]
        return tuple(["cv"] + ct + (["high"] if self.q_high_g is not None else []))

    def entry_rates(self):
        """``(M,)`` each mode's entry turn rate (rad/s): a CT mode's (the bank's ``+r_1, -r_1, ...``, else 0), 0 for a
        CV mode (the kernel's ``entry_w``)."""
        w = np.zeros(self.n_modes)
        for k, r in enumerate(self.ct_rates_deg_s):
            w[1 + 2 * k], w[2 + 2 * k] = r * DEG, -r * DEG
        return w

    def filter_constants(self):
        """What the filter holds fixed whatever the per-look parameters, as plain numbers (the keyword arguments
        of ``radar_env.filters.torch_imm.IMMConstants``): ``is_ct``, ``log_mu0``, ``sig_w0_2`` (rad^2/s^2),
        ``omega_max_rad_s``, ``accel_max_m_s2``, ``min_speed_m_s`` and, for a bank, ``entry_w``
        (:meth:`entry_rates`)."""
        is_ct, _, _, log_mu0 = self.mode_arrays()
        sig_w0 = self.sigma_omega0_deg_s * DEG
        out = dict(is_ct=tuple(bool(c) for c in is_ct), log_mu0=tuple(float(v) for v in log_mu0),
                   sig_w0_2=sig_w0 * sig_w0, omega_max_rad_s=self.omega_max_deg_s * DEG,
                   accel_max_m_s2=self.turn_accel_max_g * G0_M_S2, min_speed_m_s=MIN_SPEED_FOR_BOUND_M_S)
        if self.is_bank:
            out["entry_w"] = tuple(float(v) for v in self.entry_rates())
        return out


DEFAULT_IMM_CV_CT = IMMCVCTSpec()
"""Defaults (see the module docstring for how they were chosen)."""

IMM_CT_BANK_PARAMS = IMM_CV_CT_PARAMS + tuple((f"ct_rate_{k + 1}_deg_s", "deg/s", 0.3, 20.0, True)
                                              for k in range(MAX_CT_RATES))
"""The tunable parameters of ``imm_ct_bank`` (a bank of six CT modes, module docstring): those of
:data:`IMM_CV_CT_PARAMS` and three entry rates (the spec's ``ct_rates_deg_s``; the bounds span the random flights'
turn rates, 0.9-20 deg/s)."""

DEFAULT_CT_BANK_RATES_DEG_S = (2.0, 6.0, 12.0)
"""The bank's entry rates where the tuner starts (spread over the random flights' turn rates)."""


def imm_cv_ct_spec_from_params(params) -> IMMCVCTSpec:
    """A spec from a dict of :data:`IMM_CV_CT_PARAMS` names (missing ones keep :data:`DEFAULT_IMM_CV_CT`'s value;
    ``q_high_g`` present = three modes) and, for a bank of CT modes, the rates of :data:`IMM_CT_BANK_PARAMS`
    (``ct_rate_<k>_deg_s``: the spec's ``ct_rates_deg_s``). Unknown names raise ``ValueError`` listing the valid
    ones."""
    names = [p[0] for p in IMM_CT_BANK_PARAMS]
    if not isinstance(params, dict):
        raise ValueError(f"params must be a dict of {names}, got {type(params).__name__}")
    check_known_keys("imm_cv_ct parameter", params, names, noun="name")
    d = asdict(DEFAULT_IMM_CV_CT)
    num = lambda v: float(v) if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool) \
        else v   # noqa: E731
    d.update({k: num(v) for k, v in params.items() if not k.startswith("ct_rate_")})
    rates = [num(params[n]) for n in names if n.startswith("ct_rate_") and n in params]
    if rates:
        d["ct_rates_deg_s"] = tuple(rates)
    return IMMCVCTSpec(**d)


# ------------------------------------------------------------------------------------------------ CT motion
@numba.njit(cache=True)
def _ct_coefficients(theta):
    """``(sin t / t, (1 - cos t) / t, (t cos t - sin t) / t^2, (t sin t - 1 + cos t) / t^2)`` at ``t = theta``,
    by Taylor series below ``SERIES_THETA``."""
    if abs(theta) < SERIES_THETA:
        t2 = theta * theta
        s1 = 1.0 + t2 * (-1.0 / 6 + t2 * (1.0 / 120 + t2 * (-1.0 / 5040 + t2 * (1.0 / 362880))))
        c1 = theta * (0.5 + t2 * (-1.0 / 24 + t2 * (1.0 / 720 + t2 * (-1.0 / 40320 + t2 * (1.0 / 3628800)))))
        g1 = theta * (-1.0 / 3 + t2 * (1.0 / 30 + t2 * (-1.0 / 840 + t2 * (1.0 / 45360 - t2 / 3991680))))
        g2 = 0.5 + t2 * (-1.0 / 8 + t2 * (1.0 / 144 + t2 * (-1.0 / 5760 + t2 * (1.0 / 403200))))
        return s1, c1, g1, g2
    s, c = math.sin(theta), math.cos(theta)
    t2 = theta * theta
    return s / theta, (1.0 - c) / theta, (theta * c - s) / t2, (theta * s - 1.0 + c) / t2


@numba.njit(cache=True)
def _ct_predict(x, dt, out, J):
    """``out = f(x)``, the exact CT motion of the 5-state ``x`` over ``dt``, and ``J = df/dx`` (5 x 5) at ``x``
    (one evaluation of the coefficients for both)."""
    th = x[4] * dt
    s1, c1, g1, g2 = _ct_coefficients(th)
    a, b = dt * s1, dt * c1
    s, c = math.sin(th), math.cos(th)
    vx, vy = x[2], x[3]
    out[0] = x[0] + a * vx + b * vy
    out[1] = x[1] - b * vx + a * vy
    out[2] = c * vx + s * vy
    out[3] = -s * vx + c * vy
    out[4] = x[4]
    J[:, :] = 0.0
    J[0, 0] = J[1, 1] = J[4, 4] = 1.0
    J[0, 2], J[0, 3] = a, b
    J[1, 2], J[1, 3] = -b, a
    J[2, 2], J[2, 3] = c, s
    J[3, 2], J[3, 3] = -s, c
    d2 = dt * dt
    J[0, 4] = d2 * (g1 * vx + g2 * vy)
    J[1, 4] = d2 * (-g2 * vx + g1 * vy)
    J[2, 4] = dt * (-s * vx + c * vy)
    J[3, 4] = -dt * (c * vx + s * vy)


def _ct_rows(x, dt_s):
    """:func:`_ct_predict` of every 5-state row of ``x (..., 5)``: ``(f (n, 5), J (n, 5, 5))``."""
    flat = np.asarray(x, dtype=np.float64).reshape(-1, 5)
    f, J = np.empty_like(flat), np.empty((flat.shape[0], 5, 5))
    for i in range(flat.shape[0]):
        _ct_predict(flat[i], float(dt_s), f[i], J[i])
    return f, J


def ct_motion(x, dt_s):
    """The CT motion ``f(x)`` of 5-state vectors ``x (..., 5)`` over ``dt_s`` (scalar) (for tests and users)."""
    return _ct_rows(x, dt_s)[0].reshape(np.shape(x))


def ct_jacobian(x, dt_s):
    """The analytic Jacobian ``df/dx (..., 5, 5)`` of :func:`ct_motion` at ``x (..., 5)``."""
    return _ct_rows(x, dt_s)[1].reshape(np.shape(x)[:-1] + (5, 5))


# ------------------------------------------------------------------------------------------------ the kernel
@numba.njit(cache=True)
def _clip_omega(x, omega_max, accel_max):
    speed = max(math.hypot(x[2], x[3]), MIN_SPEED_FOR_BOUND_M_S)
    bound = min(omega_max, accel_max / speed)
    if x[4] > bound:
        x[4] = bound
    elif x[4] < -bound:
        x[4] = -bound


@numba.njit(cache=True, inline="always")
def _add_cv_noise(P, dt, q):
    q2 = q * q
    pp, pv, vv = q2 * dt ** 4 / 4.0, q2 * dt ** 3 / 2.0, q2 * dt * dt
    P[0, 0] += pp
    P[1, 1] += pp
    P[0, 2] += pv
    P[2, 0] += pv
    P[1, 3] += pv
    P[3, 1] += pv
    P[2, 2] += vv
    P[3, 3] += vv


@numba.njit(cache=True)
def _abat(A, B, tmp, out):
    """``out = A B A^T`` for the 5 x 5 matrices of the CT-EKF (and of rbpf's turning and accelerating particles),
    the size fixed when compiled so that the loops unroll (read from the array, they took about a quarter of
    rbpf's time)."""
    for r in range(5):
        for c in range(5):
            s = 0.0
            for l in range(5):
                s += A[r, l] * B[l, c]
            tmp[r, c] = s
    for r in range(5):
        for c in range(5):
            s = 0.0
            for l in range(5):
                s += tmp[r, l] * A[c, l]
            out[r, c] = s


@numba.njit(cache=True)
def _moments(w, xs, Ps, n, x_out, P_out):
    """Moment-matched mixture of the first ``n`` components: ``x = sum w_i x_i``,
    ``P = sum w_i (P_i + (x_i - x)(x_i - x)^T)``, symmetrised."""
    x_out[:] = 0.0
    P_out[:, :] = 0.0
    for i in range(w.shape[0]):
        for r in range(n):
            x_out[r] += w[i] * xs[i, r]
    for i in range(w.shape[0]):
        for r in range(n):
            dr = xs[i, r] - x_out[r]
            for c in range(n):
                P_out[r, c] += w[i] * (Ps[i, r, c] + dr * (xs[i, c] - x_out[c]))
    _symmetrize(P_out)


@numba.njit(cache=True)
def _plot_update(x, P, z, R, x_out, P_out):
    """Kalman update of the 5-state ``(x, P)`` with the position plot ``z`` (R): the chain's update
    (:func:`radar_env.filters.kernels._gain_update`, positive definite by construction). Returns the log-likelihood
    ``-(NIS + log det(2 pi S)) / 2``."""
    nis, d = _gain_update(x, P, np.int64(5), z[0] - x[0], z[1] - x[1], R[0, 0], 0.5 * (R[0, 1] + R[1, 0]), R[1, 1], x_out,
                          P_out)
    return -0.5 * (nis + 2.0 * _LOG_2PI + math.log(d))


NO_RANGE_RATE = (0.0, np.inf, 0.0, 0.0)
"""The range-rate input of a look without one (:func:`_look_update`'s ``rr``: infinite variance)."""


@numba.njit(cache=True)
def _look_range_rate(lk, scale, rr):
    """``rr`` of the packed look row ``lk`` (:mod:`radar_env.sim.looks`): its radial velocity, the variance of the
    radar's noise std times ``scale``, its site; the variance inf (no range-rate update) for ``scale`` 0, a missed
    look, or a value or std that is not finite and positive."""
    rd, sd = lk[L_RDOT], lk[L_RDSTD] * scale
    ok = scale > 0.0 and lk[L_DET] != 0.0 and math.isfinite(rd) and math.isfinite(sd) and sd > 0.0
    rr[0], rr[1] = (rd, sd * sd) if ok else (0.0, np.inf)
    rr[2], rr[3] = lk[L_SITE], lk[L_SITE + 1]


@numba.njit(cache=True)
def _no_range_rate():
    """A fresh ``rr`` array of :data:`NO_RANGE_RATE` (for the kernels whose looks update on position only)."""
    rr = np.empty(4)
    rr[0], rr[1], rr[2], rr[3] = 0.0, np.inf, 0.0, 0.0
    return rr


def range_rate_block(shape, radial_velocity_m_s=None, site_xy_m=None, radial_velocity_std_m_s=None,
                     noise_scale=1.0):
    """The kernels' range-rate inputs ``rr (*shape, 4)`` = (radial velocity, its variance, site x, site y) of
    :func:`radar_env.sim.looks.range_rate_inputs` (no radial velocity given: every variance inf)."""
    rd, var, site = range_rate_inputs(shape, radial_velocity_m_s, site_xy_m, radial_velocity_std_m_s, noise_scale)
    return np.ascontiguousarray(np.concatenate([rd[..., None], var[..., None], site], axis=-1))


@numba.njit(cache=True)
def _set_cv_augmentation(x, P, sig_w0_2):
    x[4] = 0.0
    P[4, :] = 0.0
    P[:, 4] = 0.0
    P[4, 4] = sig_w0_2


@numba.njit(cache=True)
def _work(M):
    """Scratch arrays of one row's looks: ``(x0, P0, xp, Pp, log_c, a, w, ll, J, tmp, xc, Pc)``."""
    return (np.empty((M, 5)), np.empty((M, 5, 5)), np.empty((M, 5)), np.empty((M, 5, 5)), np.empty(M),
            np.empty((M, M)), np.empty(M), np.empty(M), np.empty((5, 5)), np.empty((5, 5)), np.empty(5),
            np.empty((5, 5)))


@numba.njit(cache=True)
def _copy_vec(dst, src):
    """``dst[:] = src[:dst.shape[0]]`` element by element (a slice assignment of an array compiles numba's
    shape-mismatch error path, string formatting included: seconds of the first use's compilation for a copy)."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@numba.njit(cache=True)
def _copy_mat(dst, src):
    """``dst[:, :] = src[:dst.shape[0], :dst.shape[1]]`` element by element (as :func:`_copy_vec`)."""
    for i in range(dst.shape[0]):
        for j in range(dst.shape[1]):
            dst[i, j] = src[i, j]


@numba.njit(cache=True)
def _init_modes(x_init, P_init, is_ct, sig_w0_2, log_mu0, xm, Pm, log_mu):
    """Every mode at the start state; a CV mode with its turn-rate augmentation."""
    for m in range(is_ct.shape[0]):
        _copy_vec(xm[m], x_init)
        _copy_mat(Pm[m], P_init)
        if not is_ct[m]:
            _set_cv_augmentation(xm[m], Pm[m], sig_w0_2)
    for m in range(log_mu.shape[0]):
        log_mu[m] = log_mu0[m]


@numba.njit(cache=True)
def _look_predict(dt, is_ct, q, sig_w2, log_Pi, sig_w0_2, omega_max, accel_max, xm, Pm, log_mu, work,
                  entry_w=None):
    """The first half of :func:`_look`: mixing and mode-matched prediction of the posterior modes ``xm (M, 5)``,
    ``Pm (M, 5, 5)``, ``log_mu (M,)`` over ``dt``. Writes the predicted modes and the log mixing normalisers (the
    predicted mode probabilities, ``log c_j``) into ``work``'s ``xp``, ``Pp``, ``log_c``. ``entry_w (M,)``: each CT
    mode's entry rate (rad/s; a bank of CT modes, :attr:`IMMCVCTSpec.ct_rates_deg_s`): a CV mode mixes into CT
    mode ``j`` with the turn rate ``entry_w[j]`` (variance ``sig_w0_2``) instead of 0; None: 0 for every CT mode.
    A CV mode's stored turn rate is not read: it mixes in at the target's entry rate (0 into a CV mode); it is set
    to that rate while mixing and left at 0, as every update leaves it."""
    x0, P0, xp, Pp, log_c, a, w, ll, J, tmp, xc, Pc = work
    M = q.shape[0]
    # ---- mixing (log space): a[j, i] = log Pi_ij + log mu_i (stored transposed: a[j] is a contiguous row, so
    # _logsumexp compiles once, for C arrays), log c_j = logsumexp_i a[j, i], in 5 states
    for i in range(M):
        for j in range(M):
            a[j, i] = log_Pi[i, j] + log_mu[i]
    for j in range(M):
        log_c[j] = _logsumexp(a[j], M)
        for i in range(M):
            w[i] = math.exp(a[j, i] - log_c[j])
        if entry_w is not None:
            for i in range(M):      # a CV mode enters CT mode j at its entry rate (a CV target: 0, reset below)
                if not is_ct[i]:
                    xm[i, 4] = entry_w[j] if is_ct[j] else 0.0
        _moments(w, xm, Pm, np.int64(5), x0[j], P0[j])
        if is_ct[j]:
            _clip_omega(x0[j], omega_max, accel_max)
        else:   # a CV mode keeps its 4-state marginal and its turn-rate augmentation (0, sigma_omega0^2)
            _set_cv_augmentation(x0[j], P0[j], sig_w0_2)
    if entry_w is not None:
        for i in range(M):
            if not is_ct[i]:
                xm[i, 4] = 0.0
    # ---- mode-matched prediction
    for j in range(M):
        if is_ct[j]:
            _ct_predict(x0[j], dt, xp[j], J)
        else:
            J[:, :] = 0.0
            for r in range(5):
                J[r, r] = 1.0
            J[0, 2] = J[1, 3] = dt
            _copy_vec(xp[j], x0[j])
            xp[j, 0] += dt * x0[j, 2]
            xp[j, 1] += dt * x0[j, 3]
        _abat(J, P0[j], tmp, Pp[j])
        _add_cv_noise(Pp[j], dt, q[j])
        if is_ct[j]:
            Pp[j, 4, 4] += sig_w2 * dt
        _symmetrize(Pp[j])


@numba.njit(cache=True)
def _predicted_combination(xp, Pp, log_c, w, xc, Pc):
    """The combined prediction: the moments of the predicted modes' 4-state marginals with weights ``c_j``
    normalised, into ``xc[:4]``, ``Pc[:4, :4]`` (``w``: scratch of M)."""
    M = log_c.shape[0]
    lse = _logsumexp(log_c, M)
    for j in range(M):
        w[j] = math.exp(log_c[j] - lse)
    _moments(w, xp, Pp, np.int64(4), xc, Pc)


@numba.njit(cache=True)
def _look_update(z, R, det, rr, is_ct, omega_max, accel_max, xm, Pm, log_mu, work, x_out, P_out, mu_out):
    """The second half of :func:`_look`: the mode-matched update of the predicted modes in ``work``
    (``xp``, ``Pp``, ``log_c``, read only; from :func:`_look_predict`) with the plot ``z``, ``R`` (``det`` False: a
    missed look) and, where ``rr = (radial velocity, its variance, site x, site y)`` has a finite variance, the
    radial velocity after the position (:func:`radar_env.filters.kernels._rdot_update`; its likelihood joins the
    mode's; :data:`NO_RANGE_RATE`: none), the mode probabilities and the outputs. Writes the posterior modes into
    ``xm, Pm, log_mu``, the combination of their 4-state marginals into ``x_out (4,)``, ``P_out (4, 4)`` and
    ``mu_out (M,)``; returns ``(NIS of the combined prediction, combined turn rate, its variance)``."""
    x0, P0, xp, Pp, log_c, a, w, ll, J, tmp, xc, Pc = work
    M = is_ct.shape[0]
    # ---- mode-matched update, log-likelihoods (a missed look: posterior = prior, log-likelihood 0)
    for j in range(M):
        if det:
            ll[j] = _plot_update(xp[j], Pp[j], z, R, xm[j], Pm[j])
            if rr[1] < math.inf:    # xc, Pc: scratch until the combination below
                ll[j] += _rdot_update(xm[j], Pm[j], np.int64(5), rr[0], rr[2], rr[3], rr[1], xc, Pc)
                _copy_vec(xm[j], xc)
                _copy_mat(Pm[j], Pc)
            if is_ct[j]:
                _clip_omega(xm[j], omega_max, accel_max)
        else:
            _copy_vec(xm[j], xp[j])
            _copy_mat(Pm[j], Pp[j])
            _pd_floor(Pm[j], np.int64(5), Pp[j])
            ll[j] = 0.0
    # ---- mode probabilities: log mu_j = log c_j + l_j - logsumexp
    for j in range(M):
        ll[j] += log_c[j]
    lse = _logsumexp(ll, M)
    for j in range(M):
        log_mu[j] = ll[j] - lse
    # ---- NIS of the combined prediction (weights c_j normalised), as radar_env.filters.kalman.imm_step
    _predicted_combination(xp, Pp, log_c, w, xc, Pc)
    nis = (_plot_nis(Pc[0, 0], 0.5 * (Pc[0, 1] + Pc[1, 0]), Pc[1, 1], R[0, 0], 0.5 * (R[0, 1] + R[1, 0]), R[1, 1],
                     z[0] - xc[0], z[1] - xc[1])[0] if det else 0.0)
    # ---- combination of the 4-state marginals; combined turn rate (a CV mode's is 0) and its variance
    om = 0.0
    for j in range(M):
        w[j] = math.exp(log_mu[j])
        mu_out[j] = w[j]
        if is_ct[j]:
            om += w[j] * xm[j, 4]
    om_var = 0.0
    for j in range(M):
        d = (xm[j, 4] - om) if is_ct[j] else -om
        om_var += w[j] * ((Pm[j, 4, 4] if is_ct[j] else 0.0) + d * d)
    _moments(w, xm, Pm, np.int64(4), xc, Pc)
    # a mixture of positive definite modes, but a mode with a 1e17 condition number can round it below: the floor
    # acts only then (the modes' own covariances are floored in the update)
    _pd_floor(Pc, np.int64(4), Pc)
    _copy_vec(x_out, xc)
    _copy_mat(P_out, Pc)
    return nis, om, om_var


@numba.njit(cache=True)
def _look(dt, z, R, det, rr, is_ct, q, sig_w2, log_Pi, sig_w0_2, omega_max, accel_max, xm, Pm, log_mu, work,
          x_out, P_out, mu_out, entry_w=None):
    """One look of one row with this look's parameters ``q (M,)``, ``sig_w2``, ``log_Pi (M, M)``: mixing,
    mode-matched prediction and update (``rr``: the range-rate input of :func:`_look_update`), mode probabilities
    (:func:`_look_predict` then :func:`_look_update`).
    Updates ``xm, Pm, log_mu`` in place, writes the combination of the modes' 4-state marginals into ``x_out (4,)``,
    ``P_out (4, 4)`` and ``mu_out (M,)``; returns ``(NIS of the combined prediction, combined turn rate, its
    variance)``. ``entry_w``: the CT modes' entry rates (:func:`_look_predict`)."""
    _look_predict(dt, is_ct, q, sig_w2, log_Pi, sig_w0_2, omega_max, accel_max, xm, Pm, log_mu, work, entry_w)
    return _look_update(z, R, det, rr, is_ct, omega_max, accel_max, xm, Pm, log_mu, work, x_out, P_out, mu_out)


@numba.njit(cache=True)
def _row(t, z, R, det, rr, n_looks, k_start, x_init, P_init, is_ct, entry_w, q, sig_w2, sig_w0_2, log_Pi, log_mu0,
         omega_max, accel_max, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis, keep_modes, out_xm, out_Pm):
    """One track: looks ``k_start .. n_looks - 1`` (the previous one, ``k_start - 1``, is the start; ``rr (K, 4)``
    their range-rate inputs, :func:`_look_update`). The
    parameters ``q (Kp, M)``, ``sig_w2 (Kp,)``, ``log_Pi (Kp, M, M)`` are per look (``Kp`` = K, indexed by the
    look) or the same for every look (``Kp`` = 1)."""
    M = is_ct.shape[0]
    xm = np.empty((M, 5))
    Pm = np.empty((M, 5, 5))
    log_mu = np.empty(M)
    work = _work(M)
    _init_modes(x_init, P_init, is_ct, sig_w0_2, log_mu0, xm, Pm, log_mu)
    last = q.shape[0] - 1
    t_last = t[k_start - 1]
    for k in range(k_start, n_looks):
        i = min(k, last)
        out_nis[k], out_omega[k], out_omega_var[k] = _look(
            t[k] - t_last, z[k], R[k], det[k], rr[k], is_ct, q[i], sig_w2[i], log_Pi[i], sig_w0_2, omega_max,
            accel_max, xm, Pm, log_mu, work, out_x[k], out_P[k], out_mu[k], entry_w)
        if keep_modes:
            out_xm[k] = xm
            out_Pm[k] = Pm
        t_last = t[k]


@numba.njit(cache=True, parallel=True)
def _kernel(t, z, R, det, rr, n_looks, k_start, x_init, P_init, is_ct, entry_w, q, sig_w2, sig_w0_2, log_Pi, log_mu0,
            omega_max, accel_max, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis, keep_modes, out_xm, out_Pm):
    last = q.shape[0] - 1           # parameters (Bp, Kp, ...): Bp = B (per row) or 1 (every row)
    for b in numba.prange(t.shape[0]):
        i = min(np.int64(b), last)  # (the prange index is unsigned: min with an int64 would be a float)
        # without keep_modes the per-mode outputs are (1, 1, ...) placeholders
        xm_b = out_xm[b] if keep_modes else out_xm[0]
        Pm_b = out_Pm[b] if keep_modes else out_Pm[0]
        _row(t[b], z[b], R[b], det[b], rr[b], n_looks[b], k_start[b], x_init[b], P_init[b], is_ct, entry_w, q[i],
             sig_w2[i], sig_w0_2, log_Pi[i], log_mu0, omega_max, accel_max, out_x[b], out_P[b], out_mu[b],
             out_omega[b], out_omega_var[b], out_nis[b], keep_modes, xm_b, Pm_b)


@numba.njit(cache=True)
def _step_kernel(rows, t, z, R, det, rr, is_ct, entry_w, q, sig_w2, sig_w0_2, log_Pi, omega_max, accel_max, xm, Pm,
                 log_mu, k, t_last, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis):
    """The next look ``k[r]`` of each row ``r = rows[i]`` with that row's parameters ``q[i]``, ``sig_w2[i]``,
    ``log_Pi[i]``; the modes ``xm, Pm, log_mu (B, ...)`` and cursors ``k, t_last (B,)`` are updated in place.
    Serial, one scratch set per call: a look is microseconds per row, less than a thread pool's start."""
    work = _work(is_ct.shape[0])
    for i in range(rows.shape[0]):
        r = rows[i]
        kk = k[r]
        out_nis[i], out_omega[i], out_omega_var[i] = _look(
            t[r, kk] - t_last[r], z[r, kk], R[r, kk], det[r, kk], rr[r, kk], is_ct, q[i], sig_w2[i], log_Pi[i], sig_w0_2,
            omega_max, accel_max, xm[r], Pm[r], log_mu[r], work, out_x[i], out_P[i], out_mu[i], entry_w)
        t_last[r] = t[r, kk]
        k[r] = kk + 1


# ------------------------------------------------------------------------------------------------ one track, split look
class ModePrediction(NamedTuple):
    """:func:`predict_modes`' output: the predicted modes and their combination."""

    x_modes: np.ndarray     # (M, 5) predicted mode means
    P_modes: np.ndarray     # (M, 5, 5)
    log_c: np.ndarray       # (M,) log predicted mode probabilities (the mixing normalisers)
    x: np.ndarray           # (4,) combined prediction [x, y, vx, vy]
    P: np.ndarray           # (4, 4)


class ModeUpdate(NamedTuple):
    """:func:`update_modes`' output: the posterior modes and their combination (what :func:`_look` gives)."""

    x_modes: np.ndarray     # (M, 5) posterior mode means
    P_modes: np.ndarray     # (M, 5, 5)
    log_mu: np.ndarray      # (M,) log mode probabilities
    mu: np.ndarray          # (M,) mode probabilities (the kernel's exp(log_mu))
    x: np.ndarray           # (4,) combined estimate
    P: np.ndarray           # (4, 4)
    nis: float              # NIS of the combined prediction (0 for a missed look)
    omega_rad_s: float      # combined turn rate
    omega_var: float        # its variance


def _spec_constants(spec):
    sig_w0 = spec.sigma_omega0_deg_s * DEG
    return sig_w0 * sig_w0, spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2


def _modes_in(x_modes, P_modes, log_p, M):
    x = np.array(x_modes, dtype=np.float64, order="C")      # copies: the kernel halves write in place
    P = np.array(P_modes, dtype=np.float64, order="C")
    lp = np.array(log_p, dtype=np.float64, order="C")
    if x.shape != (M, 5) or P.shape != (M, 5, 5) or lp.shape != (M,):
        raise ValueError(f"the modes must be x_modes (M, 5), P_modes (M, 5, 5), log probabilities (M,) with "
                         f"M = {M} (the spec's modes); got {x.shape}, {P.shape}, {lp.shape}")
    return x, P, lp


def initial_modes(spec: IMMCVCTSpec, x, P):
    """Every mode at the 4-state start ``x (4,)``, ``P (4, 4)`` as :func:`baselines.imm_cv_ct_runner.run_imm_cv_ct`
    starts them (turn rate 0 with variance ``sigma_omega0^2``; mode probabilities ``mu0``): ``(x_modes (M, 5),
    P_modes (M, 5, 5), log_mu (M,))``."""
    x4 = np.asarray(x, dtype=np.float64).reshape(-1)
    P4 = np.asarray(P, dtype=np.float64)
    if x4.shape != (4,) or P4.shape != (4, 4):
        raise ValueError(f"x must be (4,) and P (4, 4) ([x, y, vx, vy]); got {x4.shape}, {P4.shape}")
    sig_w0_2 = _spec_constants(spec)[0]
    x5 = np.append(x4, 0.0)
    P5 = np.zeros((5, 5))
    P5[:4, :4] = P4
    P5[4, 4] = sig_w0_2
    is_ct, _, _, log_mu0 = spec.mode_arrays()
    M = is_ct.size
    xm, Pm, log_mu = np.empty((M, 5)), np.empty((M, 5, 5)), np.empty(M)
    _init_modes(x5, P5, np.ascontiguousarray(is_ct), sig_w0_2, log_mu0, xm, Pm, log_mu)
    return xm, Pm, log_mu


def predict_modes(spec: IMMCVCTSpec, x_modes, P_modes, log_mu, dt_s, params=None) -> ModePrediction:
    """The prediction half of one look of the compiled kernel (:func:`_look_predict`, the same code), for one track
    at ``spec``'s constant parameters (or this look's ``params``, ``(n_par,)`` values of
    :func:`look_parameter_names`, as :class:`baselines.imm_cv_ct_runner.IMMCVCTStepper` takes them): mixing, then
    every mode predicted over ``dt_s`` (>= 0; 0 still mixes, as the kernel does at a look with dt 0). The inputs are
    not modified."""
    dt = float(dt_s)
    if not (math.isfinite(dt) and dt >= 0.0):
        raise ValueError(f"dt_s must be a finite number >= 0 (s), got {dt_s!r}")
    is_ct = np.ascontiguousarray(spec.mode_arrays()[0])
    M = is_ct.size
    xm, Pm, lm = _modes_in(x_modes, P_modes, log_mu, M)
    p = None if params is None else check_look_parameters(spec, np.asarray(params, dtype=np.float64).reshape(-1), 1, 1)
    q, sig_w2, log_Pi = kernel_parameters(spec, p)
    sig_w0_2, omega_max, accel_max = _spec_constants(spec)
    work = _work(M)
    _look_predict(dt, is_ct, q[0, 0], sig_w2[0, 0], log_Pi[0, 0], sig_w0_2, omega_max, accel_max, xm, Pm, lm, work,
                  spec.entry_rates())
    xp, Pp, log_c, w, xc, Pc = work[2].copy(), work[3].copy(), work[4].copy(), work[6], work[10], work[11]
    _predicted_combination(xp, Pp, log_c, w, xc, Pc)
    return ModePrediction(xp, Pp, log_c, xc[:4].copy(), Pc[:4, :4].copy())


def update_modes(spec: IMMCVCTSpec, x_modes, P_modes, log_c, z=None, R=None, range_rate=None) -> ModeUpdate:
    """The update half of one look of the compiled kernel (:func:`_look_update`, the same code): the predicted modes
    of :func:`predict_modes` updated with the Cartesian plot ``z (2,)`` (m), covariance ``R (2, 2)`` (m^2); ``z=None``
    is a missed look (the kernel's: posterior = prediction, mode probabilities renormalised). ``range_rate``: the
    plot's ``(radial velocity (m/s, positive receding), its variance (m^2/s^2), site x, site y (m))``, the kernel's
    ``rr``; every mode then also updates on it after the position (None, or a variance that is not finite and
    positive: position only, :data:`NO_RANGE_RATE`). The inputs are not modified. :func:`predict_modes` then
    :func:`update_modes` equals one look of :func:`_look` bit for bit."""
    is_ct = np.ascontiguousarray(spec.mode_arrays()[0])
    M = is_ct.size
    xp, Pp, lc = _modes_in(x_modes, P_modes, log_c, M)
    det = z is not None
    if det:
        z = np.array(z, dtype=np.float64).reshape(-1)
        R = np.array(R, dtype=np.float64) if R is not None else None
        if z.shape != (2,) or R is None or R.shape != (2, 2):
            raise ValueError(f"z must be (2,) and R (2, 2) (a Cartesian plot, m and m^2); got {z.shape}, "
                             f"{None if R is None else R.shape}")
        if not (np.isfinite(z).all() and np.isfinite(R).all()):
            raise ValueError(f"z and R must be finite; got z {z}, R {R.tolist()}")
    else:
        z, R = np.zeros(2), np.eye(2)      # what the kernel reads at a missed look (unused but for shape)
    rr = np.array(NO_RANGE_RATE if range_rate is None else range_rate, dtype=np.float64).reshape(-1)
    if rr.shape != (4,) or np.isnan(rr).any() or not np.isfinite(rr[[0, 2, 3]]).all():
        raise ValueError(f"range_rate must be (radial velocity, variance, site x, site y), finite but for an inf "
                         f"variance; got {rr.tolist()}")
    if not rr[1] > 0.0:
        rr[0], rr[1] = 0.0, np.inf      # as range_rate_inputs: no range-rate update
    _, omega_max, accel_max = _spec_constants(spec)
    work = _work(M)
    work[2][:], work[3][:], work[4][:] = xp, Pp, lc
    xm, Pm, log_mu = np.empty((M, 5)), np.empty((M, 5, 5)), np.empty(M)
    x, P, mu = np.empty(4), np.empty((4, 4)), np.empty(M)
    nis, om, om_var = _look_update(z, R, det, rr, is_ct, omega_max, accel_max, xm, Pm, log_mu, work, x, P, mu)
    return ModeUpdate(xm, Pm, log_mu, mu, x, P, float(nis), float(om), float(om_var))


# ------------------------------------------------------------------------------------------------ per-look parameters
def look_parameter_names(spec: IMMCVCTSpec | None = None):
    """The parameters that may change from look to look, in the order of a parameter vector: those of
    :data:`LOOK_PARAMS` that ``spec``'s modes have (the last two only with the third mode)."""
    spec = spec or DEFAULT_IMM_CV_CT
    return LOOK_PARAMS if spec.q_high_g is not None else LOOK_PARAMS[:5]


def look_parameter_vector(spec: IMMCVCTSpec | None = None) -> np.ndarray:
    """``spec``'s constant values of :func:`look_parameter_names`, (n_par,) (g, deg/s^1.5, probabilities)."""
    spec = spec or DEFAULT_IMM_CV_CT
    return np.array([getattr(spec, n) for n in look_parameter_names(spec)], dtype=np.float64)


def check_look_parameters(spec, params, B=None, K=None):
    """``params`` as float64 of shape ``(Bp, Kp, n_par)``, checked: ``n_par = len(look_parameter_names(spec))``;
    ``(n_par,)``, ``(Bp, n_par)`` and ``(Bp, Kp, n_par)`` are accepted with ``Bp`` in ``{1, B}``, ``Kp`` in ``{1, K}``
    (a 2-D array is one row of parameters per row, the same for every look). Every value finite and inside its
    :data:`IMM_CV_CT_PARAMS` range; ``ValueError`` naming the parameter otherwise."""
    names = look_parameter_names(spec)
    p = np.asarray(params, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, None]
    elif p.ndim == 2:
        p = p[:, None]
    if p.ndim != 3 or p.shape[-1] != len(names) or (B is not None and p.shape[0] not in (1, B)) \
            or (K is not None and p.shape[1] not in (1, K)):
        raise ValueError(f"params must be (n_par,), (B, n_par) or (B, K, n_par) with n_par = {len(names)} "
                         f"({', '.join(names)}), B = {B}, K = {K} (or 1 to broadcast); got shape "
                         f"{np.shape(params)}")
    for i, n in enumerate(names):
        lo, hi = _RANGES[n]
        v = p[..., i]
        bad = ~((v >= lo) & (v <= hi))              # NaN is bad too
        if bad.any():
            raise ValueError(f"params[..., {i}] ({n}) must be finite and in [{lo}, {hi}], got "
                             f"{float(v[bad].flat[0])!r}")
    return np.ascontiguousarray(p)


def kernel_parameters(spec=None, params=None):
    """The kernel's per-look arrays ``(q_m_s2 (Bp, Kp, M), sig_w2 (Bp, Kp), log_Pi (Bp, Kp, M, M))``.

    ``params=None``: ``spec``'s constants (:meth:`IMMCVCTSpec.mode_arrays`), shape ``(1, 1, ...)``; else a checked
    array of :func:`check_look_parameters`, converted with the same operations as ``mode_arrays`` (so the
    constant values given per look produce the same numbers, bit for bit: tested)."""
    spec = spec or DEFAULT_IMM_CV_CT
    if params is None:
        _, q, log_Pi, _ = spec.mode_arrays()
        sig_w = spec.sigma_omega_deg_s15 * DEG
        return q[None, None], np.full((1, 1), sig_w * sig_w), log_Pi[None, None]
    M, n_ct, high = spec.n_modes, spec.n_ct, spec.q_high_g is not None
    names = look_parameter_names(spec)
    col = {n: params[..., i] for i, n in enumerate(names)}
    q_g = np.stack([col["q_cv_g"]] + [col["q_ct_g"]] * n_ct + ([col["q_high_g"]] if high else []), axis=-1)
    stay = np.stack([col["p_stay_cv"]] + [col["p_stay_ct"]] * n_ct + ([col["p_stay_high"]] if high else []), axis=-1)
    Pi = np.repeat(((1.0 - stay) / (M - 1))[..., None], M, axis=-1)
    i = np.arange(M)
    Pi[..., i, i] = stay
    sig_w = col["sigma_omega_deg_s15"] * DEG
    return (np.ascontiguousarray(q_g * G0_M_S2), np.ascontiguousarray(sig_w * sig_w),
            np.ascontiguousarray(np.log(Pi)))


# ------------------------------------------------------------------------------------------------ detectors
def detector_names(modes):
    """Names of :func:`detector_inputs`' columns; ``modes``: the number of modes of a spec with one CT mode (2 or 3),
    or a spec (a bank's CT modes named by their entry rates, e.g. ``mu_ct+6.77``)."""
    names = modes.mode_names() if isinstance(modes, IMMCVCTSpec) else ("cv", "ct", "high")[:modes]
    return tuple(f"mu_{m}" for m in names) + ("omega_over_20deg_s", "log10_omega_std_deg_s_over_3")


def detector_inputs(mu, omega_rad_s, omega_std_rad_s, xp=np):
    """The IMM's own detectors as network inputs ``(n, M + 2)``: the mode probabilities ``mu (n, M)``, the combined
    turn rate over 20 deg/s, and ``log10`` of its standard deviation in deg/s (floored at 1e-3 deg/s) over 3
    (``xp``: ``numpy`` or ``torch``, the arrays' kind)."""
    sd = omega_std_rad_s / DEG
    sd = xp.log10(xp.maximum(sd, xp.full_like(sd, STD_FLOOR_DEG_S))) / 3.0
    return xp.concatenate([mu, (omega_rad_s / (OMEGA_SCALE_DEG_S * DEG))[:, None], sd[:, None]], 1)


def initial_detectors(spec, n):
    """The detectors at the track start: ``mu0``, turn rate 0, its std ``sqrt(mu0_ct) sigma_omega0``."""
    is_ct, _, _, log_mu0 = spec.mode_arrays()
    mu0 = np.exp(log_mu0)
    std = math.sqrt(float(mu0[is_ct].sum())) * spec.sigma_omega0_deg_s * DEG
    return detector_inputs(np.tile(mu0, (n, 1)), np.zeros(n), np.full(n, std))
