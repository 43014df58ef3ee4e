r"""``imm_cv_ct``: a mixed-order IMM of a constant-velocity mode and a coordinated-turn EKF mode whose turn rate is
a state (the IMM air-traffic trackers use), optionally with a third, high-noise CV mode; batched, compiled.

Models
------
CV mode, state :math:`[x, y, v_x, v_y]` (m, m/s): :math:`F_{cv}(dt)` and the piecewise-constant white-acceleration
noise :math:`Q(dt, q_{cv})` of :func:`radar_env.filters.process_noise`.

CT mode, state :math:`[x, y, v_x, v_y, \omega]` (:math:`\omega` in rad/s, positive = clockwise = right turn, as in
:mod:`radar_env.filters`), the exact coordinated-turn motion with :math:`\theta = \omega\,dt`:

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
row inert). Mode probabilities are carried as logs (the log-space mixing of :func:`radar_env.filters.imm_mix`); the
update is the chain's (:func:`radar_env.filters.update`'s covariance form and floor, positive definite); NIS and
the Gaussian log-likelihood are those of :func:`radar_env.filters.update` (a
missed look: posterior = prior, log-likelihood 0). The output per look is the moment-matched combination of the
modes' 4-state marginals, the combined turn rate :math:`\sum_j \mu_j \omega_j` (a CV mode's turn rate is 0), and the
maneuver probability :math:`1 - \mu_{cv}` (the CT mode's probability when there is no third mode; with a third mode,
the high-noise CV mode counts as maneuvering too); declared = maneuver probability > 0.5.

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

The defaults (:data:`DEFAULT_IMM_CV_CT`) were chosen on tuning seeds only: scipy Nelder-Mead (log scale for the
noises, logit for the probabilities, 3 restarts of 250 evaluations) minimising the pooled position RMSE after the
track start on 100 ``random`` episodes drawn from ``agents.evaluation.suites.TUNING_SEEDS.start`` on; values rounded to two or
three digits. Result: 78.4 m against 81.6 m for the tuned ``imm2`` on the same episodes (0.961x); without the third
mode the best was 79.1 m (0.969x), so the third mode is on by default. The criterion is flat in
``sigma_omega_deg_s15`` (0.2 to 0.005 changed it by < 0.4 m) and in ``q_cv_g`` below 1e-3 g; ``q_high_g`` went to
~30 g (a restart with the bound at 100 g stayed at 31.6 g, same RMSE); those numbers are from the episode stream
of the previous version. ``baselines/tuned.json``'s ``imm_cv_ct`` entry (the continuous tuner of
:mod:`baselines.tuning`, 200 tuning episodes of the current stream: 80.22 m against imm2's 82.11 m) replaces them
(:func:`tuned_imm_cv_ct_spec`); it is what ``imm_cv_ct`` runs with.

Implementation: the whole per-look loop of every row is one numba kernel (``prange`` over rows); the track start
is the common one (two-hit start and warm-up through :class:`radar_env.tracking.Tracker`), the looks are read from
:func:`radar_env.episode.stack_episodes`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np

from radar_env.numba_cache import drop_stale_kernels, package_sources
from radar_env.episode import stack_episodes
from radar_env.kernels import _gain_update, _pd_floor, _plot_nis
from radar_env.units import DEG, G0_M_S2
from radar_env.validate import check_known_keys, check_number

from .trackers import TrackRun, _tracker

__all__ = ["IMMCVCTSpec", "DEFAULT_IMM_CV_CT", "IMM_CV_CT_PARAMS", "LOOK_PARAMS", "imm_cv_ct_spec_from_params",
           "tuned_imm_cv_ct_spec", "imm_cv_ct_filter", "IMMCVCTResult", "IMMCVCTStepper", "IMMCVCTStep",
           "look_parameter_names", "look_parameter_vector", "check_look_parameters", "kernel_parameters",
           "run_imm_cv_ct", "ct_motion", "ct_jacobian"]

SERIES_THETA = 0.1
"""Below this |omega dt| (rad) the CT coefficients are evaluated by their Taylor series."""

MIN_SPEED_FOR_BOUND_M_S = 1.0
"""Speed floor (m/s) in the g-limit ``a_max / |v|`` of the turn-rate bound."""

_LOG_2PI = float(np.log(2.0 * np.pi))


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

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "q_high_g" and v is None:
                continue
            lo, hi = _RANGES[f.name]
            object.__setattr__(self, f.name, check_number(f"IMMCVCTSpec.{f.name}", v, lo, hi))

    @property
    def n_modes(self):
        return 2 if self.q_high_g is None else 3

    def mode_arrays(self):
        """``(is_ct (M,) bool, q_m_s2 (M,), log_Pi (M, M), log_mu0 (M,))`` in mode order CV, CT[, high CV]."""
        M = self.n_modes
        stay = [self.p_stay_cv, self.p_stay_ct] + ([self.p_stay_high] if M == 3 else [])
        Pi = np.empty((M, M))
        for i in range(M):
            Pi[i] = (1.0 - stay[i]) / (M - 1)
            Pi[i, i] = stay[i]
        mu0 = np.full(M, (1.0 - self.mu0_cv) / (M - 1))
        mu0[0] = self.mu0_cv
        q = [self.q_cv_g, self.q_ct_g] + ([self.q_high_g] if M == 3 else [])
        is_ct = np.array([False, True] + ([False] if M == 3 else []))
        return is_ct, np.asarray(q) * G0_M_S2, np.log(Pi), np.log(mu0)

    def filter_constants(self):
        """What the filter holds fixed whatever the per-look parameters, as plain numbers (the keyword arguments
        of ``radar_env.torch_imm.IMMConstants``): ``is_ct``, ``log_mu0``, ``sig_w0_2`` (rad^2/s^2),
        ``omega_max_rad_s``, ``accel_max_m_s2``, ``min_speed_m_s``."""
        is_ct, _, _, log_mu0 = self.mode_arrays()
        sig_w0 = self.sigma_omega0_deg_s * DEG
        return dict(is_ct=tuple(bool(c) for c in is_ct), log_mu0=tuple(float(v) for v in log_mu0),
                    sig_w0_2=sig_w0 * sig_w0, omega_max_rad_s=self.omega_max_deg_s * DEG,
                    accel_max_m_s2=self.turn_accel_max_g * G0_M_S2, min_speed_m_s=MIN_SPEED_FOR_BOUND_M_S)


DEFAULT_IMM_CV_CT = IMMCVCTSpec()
"""Defaults (see the module docstring for how they were chosen)."""


def imm_cv_ct_spec_from_params(params) -> IMMCVCTSpec:
    """A spec from a dict of :data:`IMM_CV_CT_PARAMS` names (missing ones keep :data:`DEFAULT_IMM_CV_CT`'s value;
    ``q_high_g`` present = three modes). Unknown names raise ``ValueError`` listing the valid ones."""
    if not isinstance(params, dict):
        raise ValueError(f"params must be a dict of {[p[0] for p in IMM_CV_CT_PARAMS]}, got {type(params).__name__}")
    check_known_keys("imm_cv_ct parameter", params, [p[0] for p in IMM_CV_CT_PARAMS], noun="name")
    d = asdict(DEFAULT_IMM_CV_CT)
    d.update({k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
                  else v) for k, v in params.items()})
    return IMMCVCTSpec(**d)


def tuned_imm_cv_ct_spec() -> IMMCVCTSpec:
    """The spec of the registered ``imm_cv_ct``: ``baselines/tuned.json``'s ``imm_cv_ct`` entry (its parameter
    names; other keys such as the tuning RMSE are ignored) if present, else :data:`DEFAULT_IMM_CV_CT`."""
    from .tuned_params import TUNED_PATH, tuned_parameters

    entry = tuned_parameters().get("imm_cv_ct") if TUNED_PATH.is_file() else None
    if entry is None:
        return DEFAULT_IMM_CV_CT
    names = {p[0] for p in IMM_CV_CT_PARAMS}
    return imm_cv_ct_spec_from_params({k: v for k, v in entry.items() if k in names})


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
def _ct_predict_mean(x, dt, out):
    """``out = f(x)``: the exact CT motion of the 5-state ``x`` over ``dt``."""
    th = x[4] * dt
    s1, c1, _, _ = _ct_coefficients(th)
    a, b = dt * s1, dt * c1
    s, c = math.sin(th), math.cos(th)
    vx, vy = x[2], x[3]
    out[0] = x[0] + a * vx + b * vy
    out[1] = x[1] - b * vx + a * vy
    out[2] = c * vx + s * vy
    out[3] = -s * vx + c * vy
    out[4] = x[4]


@numba.njit(cache=True)
def _ct_jacobian(x, dt, J):
    """``J = df/dx`` (5 x 5) of the CT motion at ``x``."""
    th = x[4] * dt
    s1, c1, g1, g2 = _ct_coefficients(th)
    a, b = dt * s1, dt * c1
    s, c = math.sin(th), math.cos(th)
    vx, vy = x[2], x[3]
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


def ct_motion(x, dt_s):
    """The CT motion ``f(x)`` of 5-state vectors ``x (..., 5)`` over ``dt_s`` (scalar) (for tests and users)."""
    x = np.asarray(x, dtype=np.float64)
    flat = x.reshape(-1, 5)
    out = np.empty_like(flat)
    for i in range(flat.shape[0]):
        _ct_predict_mean(flat[i], float(dt_s), out[i])
    return out.reshape(x.shape)


def ct_jacobian(x, dt_s):
    """The analytic Jacobian ``df/dx (..., 5, 5)`` of :func:`ct_motion` at ``x (..., 5)``."""
    x = np.asarray(x, dtype=np.float64)
    flat = x.reshape(-1, 5)
    out = np.empty((flat.shape[0], 5, 5))
    for i in range(flat.shape[0]):
        _ct_jacobian(flat[i], float(dt_s), out[i])
    return out.reshape(x.shape[:-1] + (5, 5))


# ------------------------------------------------------------------------------------------------ the kernel
@numba.njit(cache=True)
def _clip_omega(x, omega_max, accel_max):
    speed = max(math.hypot(x[2], x[3]), MIN_SPEED_FOR_BOUND_M_S)
    bound = min(omega_max, accel_max / speed)
    if x[4] > bound:
        x[4] = bound
    elif x[4] < -bound:
        x[4] = -bound


@numba.njit(cache=True)
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
def _sym(A):
    n = A.shape[0]
    for r in range(n):
        for c in range(r + 1, n):
            v = 0.5 * (A[r, c] + A[c, r])
            A[r, c] = v
            A[c, r] = v


@numba.njit(cache=True)
def _abat(A, B, tmp, out):
    """``out = A B A^T`` (square)."""
    n = A.shape[0]
    for r in range(n):
        for c in range(n):
            s = 0.0
            for l in range(n):
                s += A[r, l] * B[l, c]
            tmp[r, c] = s
    for r in range(n):
        for c in range(n):
            s = 0.0
            for l in range(n):
                s += tmp[r, l] * A[c, l]
            out[r, c] = s


@numba.njit(cache=True)
def _logsumexp(a):
    mx = -np.inf
    for v in a:
        mx = max(mx, v)
    s = 0.0
    for v in a:
        s += math.exp(v - mx)
    return mx + math.log(s)


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
    _sym(P_out)


@numba.njit(cache=True)
def _plot_update(x, P, z, R, x_out, P_out):
    """Kalman update of the 5-state ``(x, P)`` with the position plot ``z`` (R): the chain's update
    (:func:`radar_env.kernels._gain_update`, positive definite by construction). Returns the log-likelihood
    ``-(NIS + log det(2 pi S)) / 2``."""
    nis, d = _gain_update(x, P, 5, z[0] - x[0], z[1] - x[1], R[0, 0], 0.5 * (R[0, 1] + R[1, 0]), R[1, 1], x_out,
                          P_out)
    return -0.5 * (nis + 2.0 * _LOG_2PI + math.log(d))


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
def _init_modes(x_init, P_init, is_ct, sig_w0_2, log_mu0, xm, Pm, log_mu):
    """Every mode at the start state; a CV mode with its turn-rate augmentation."""
    for m in range(is_ct.shape[0]):
        xm[m] = x_init
        Pm[m] = P_init
        if not is_ct[m]:
            _set_cv_augmentation(xm[m], Pm[m], sig_w0_2)
    log_mu[:] = log_mu0


@numba.njit(cache=True)
def _look(dt, z, R, det, is_ct, q, sig_w2, log_Pi, sig_w0_2, omega_max, accel_max, xm, Pm, log_mu, work, x_out,
          P_out, mu_out):
    """One look of one row with this look's parameters ``q (M,)``, ``sig_w2``, ``log_Pi (M, M)``: mixing,
    mode-matched prediction and update, mode probabilities. Updates ``xm, Pm, log_mu`` in place, writes the
    combination of the modes' 4-state marginals into ``x_out (4,)``, ``P_out (4, 4)`` and ``mu_out (M,)``;
    returns ``(NIS of the combined prediction, combined turn rate, its variance)``."""
    x0, P0, xp, Pp, log_c, a, w, ll, J, tmp, xc, Pc = work
    M = q.shape[0]
    # ---- mixing (log space): a[i, j] = log Pi_ij + log mu_i, log c_j = logsumexp_i a[i, j], in 5 states
    for i in range(M):
        for j in range(M):
            a[i, j] = log_Pi[i, j] + log_mu[i]
    for j in range(M):
        log_c[j] = _logsumexp(a[:, j])
        for i in range(M):
            w[i] = math.exp(a[i, j] - log_c[j])
        _moments(w, xm, Pm, 5, x0[j], P0[j])
        if is_ct[j]:
            _clip_omega(x0[j], omega_max, accel_max)
        else:   # a CV mode keeps its 4-state marginal and its turn-rate augmentation (0, sigma_omega0^2)
            _set_cv_augmentation(x0[j], P0[j], sig_w0_2)
    # ---- mode-matched prediction
    for j in range(M):
        if is_ct[j]:
            _ct_predict_mean(x0[j], dt, xp[j])
            _ct_jacobian(x0[j], dt, J)
        else:
            J[:, :] = 0.0
            for r in range(5):
                J[r, r] = 1.0
            J[0, 2] = J[1, 3] = dt
            xp[j] = x0[j]
            xp[j, 0] += dt * x0[j, 2]
            xp[j, 1] += dt * x0[j, 3]
        _abat(J, P0[j], tmp, Pp[j])
        _add_cv_noise(Pp[j], dt, q[j])
        if is_ct[j]:
            Pp[j, 4, 4] += sig_w2 * dt
        _sym(Pp[j])
    # ---- mode-matched update, log-likelihoods (a missed look: posterior = prior, log-likelihood 0)
    for j in range(M):
        if det:
            ll[j] = _plot_update(xp[j], Pp[j], z, R, xm[j], Pm[j])
            if is_ct[j]:
                _clip_omega(xm[j], omega_max, accel_max)
        else:
            xm[j] = xp[j]
            Pm[j] = Pp[j]
            _pd_floor(Pm[j], 5, Pp[j])
            ll[j] = 0.0
    # ---- mode probabilities: log mu_j = log c_j + l_j - logsumexp
    for j in range(M):
        ll[j] += log_c[j]
    lse = _logsumexp(ll)
    for j in range(M):
        log_mu[j] = ll[j] - lse
    # ---- NIS of the combined prediction (weights c_j normalised), as radar_env.filters.imm_step
    lse = _logsumexp(log_c)
    for j in range(M):
        w[j] = math.exp(log_c[j] - lse)
    _moments(w, xp, Pp, 4, xc, Pc)
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
    _moments(w, xm, Pm, 4, xc, Pc)
    x_out[:] = xc[:4]
    P_out[:, :] = Pc[:4, :4]
    return nis, om, om_var


@numba.njit(cache=True)
def _row(t, z, R, det, n_looks, k_start, x_init, P_init, is_ct, q, sig_w2, sig_w0_2, log_Pi, log_mu0, omega_max,
         accel_max, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis, keep_modes, out_xm, out_Pm):
    """One track: looks ``k_start .. n_looks - 1`` (the previous one, ``k_start - 1``, is the start). The
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
            t[k] - t_last, z[k], R[k], det[k], is_ct, q[i], sig_w2[i], log_Pi[i], sig_w0_2, omega_max, accel_max,
            xm, Pm, log_mu, work, out_x[k], out_P[k], out_mu[k])
        if keep_modes:
            out_xm[k] = xm
            out_Pm[k] = Pm
        t_last = t[k]


@numba.njit(cache=True, parallel=True)
def _kernel(t, z, R, det, n_looks, k_start, x_init, P_init, is_ct, q, sig_w2, sig_w0_2, log_Pi, log_mu0, omega_max,
            accel_max, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis, keep_modes, out_xm, out_Pm):
    last = q.shape[0] - 1           # parameters (Bp, Kp, ...): Bp = B (per row) or 1 (every row)
    for b in numba.prange(t.shape[0]):
        i = min(np.int64(b), last)  # (the prange index is unsigned: min with an int64 would be a float)
        # without keep_modes the per-mode outputs are (1, 1, ...) placeholders
        xm_b = out_xm[b] if keep_modes else out_xm[0]
        Pm_b = out_Pm[b] if keep_modes else out_Pm[0]
        _row(t[b], z[b], R[b], det[b], n_looks[b], k_start[b], x_init[b], P_init[b], is_ct, q[i], sig_w2[i],
             sig_w0_2, log_Pi[i], log_mu0, omega_max, accel_max, out_x[b], out_P[b], out_mu[b], out_omega[b],
             out_omega_var[b], out_nis[b], keep_modes, xm_b, Pm_b)


@numba.njit(cache=True)
def _step_kernel(rows, t, z, R, det, is_ct, q, sig_w2, sig_w0_2, log_Pi, omega_max, accel_max, xm, Pm, log_mu, k,
                 t_last, out_x, out_P, out_mu, out_omega, out_omega_var, out_nis):
    """The next look ``k[r]`` of each row ``r = rows[i]`` with that row's parameters ``q[i]``, ``sig_w2[i]``,
    ``log_Pi[i]``; the modes ``xm, Pm, log_mu (B, ...)`` and cursors ``k, t_last (B,)`` are updated in place.
    Serial, one scratch set per call: a look is microseconds per row, less than a thread pool's start."""
    work = _work(is_ct.shape[0])
    for i in range(rows.shape[0]):
        r = rows[i]
        kk = k[r]
        out_nis[i], out_omega[i], out_omega_var[i] = _look(
            t[r, kk] - t_last[r], z[r, kk], R[r, kk], det[r, kk], is_ct, q[i], sig_w2[i], log_Pi[i], sig_w0_2,
            omega_max, accel_max, xm[r], Pm[r], log_mu[r], work, out_x[i], out_P[i], out_mu[i])
        t_last[r] = t[r, kk]
        k[r] = kk + 1


# ------------------------------------------------------------------------------------------------ per-look parameters
def look_parameter_names(spec: IMMCVCTSpec | None = None):
    """The parameters that may change from look to look, in the order of a parameter vector: those of
    :data:`LOOK_PARAMS` that ``spec``'s modes have (the last two only with the third mode)."""
    spec = spec or DEFAULT_IMM_CV_CT
    return LOOK_PARAMS if spec.n_modes == 3 else LOOK_PARAMS[:5]


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
    M = spec.n_modes
    names = look_parameter_names(spec)
    col = {n: params[..., i] for i, n in enumerate(names)}
    q_g = np.stack([col["q_cv_g"], col["q_ct_g"]] + ([col["q_high_g"]] if M == 3 else []), axis=-1)
    stay = np.stack([col["p_stay_cv"], col["p_stay_ct"]] + ([col["p_stay_high"]] if M == 3 else []), axis=-1)
    Pi = np.repeat(((1.0 - stay) / (M - 1))[..., None], M, axis=-1)
    i = np.arange(M)
    Pi[..., i, i] = stay
    sig_w = col["sigma_omega_deg_s15"] * DEG
    return (np.ascontiguousarray(q_g * G0_M_S2), np.ascontiguousarray(sig_w * sig_w),
            np.ascontiguousarray(np.log(Pi)))


class IMMCVCTResult(NamedTuple):
    """Output of :func:`imm_cv_ct_filter` (B rows, K looks; NaN before ``k_start`` and after ``n_looks``)."""

    x: np.ndarray           # (B, K, 4) combined estimate
    P: np.ndarray           # (B, K, 4, 4)
    mu: np.ndarray          # (B, K, M) mode probabilities (CV, CT[, high CV])
    omega_rad_s: np.ndarray  # (B, K) combined turn rate
    nis: np.ndarray         # (B, K) NIS of the combined prediction (0 where missed)
    x_modes: np.ndarray | None   # (B, K, M, 5) mode posteriors (keep_modes only)
    P_modes: np.ndarray | None   # (B, K, M, 5, 5)
    omega_std_rad_s: np.ndarray | None = None   # (B, K) std of the combined turn rate (CV modes' turn rate: 0)


def _modes_from_arrays(is_ct, q_m_s2, log_Pi, log_mu0):
    is_ct = np.ascontiguousarray(is_ct, dtype=np.bool_)
    M = is_ct.size
    q = np.ascontiguousarray(q_m_s2, dtype=np.float64).reshape(M)
    return is_ct, q, np.ascontiguousarray(log_Pi, dtype=np.float64).reshape(M, M), \
        np.ascontiguousarray(log_mu0, dtype=np.float64).reshape(M)


def _looks_arrays(t_s, z_m, R_m2, detected, n_looks, k_start):
    t = np.ascontiguousarray(t_s, dtype=np.float64)
    B, K = t.shape
    z = np.ascontiguousarray(np.nan_to_num(np.asarray(z_m, dtype=np.float64)))
    det = np.ascontiguousarray(detected, dtype=np.bool_)
    R = np.ascontiguousarray(np.where(det[..., None, None], np.nan_to_num(np.asarray(R_m2, dtype=np.float64)),
                                      np.eye(2)))
    n = np.ascontiguousarray(n_looks, dtype=np.int64).reshape(B)
    ks = np.ascontiguousarray(k_start, dtype=np.int64).reshape(B)
    if z.shape != (B, K, 2) or R.shape != (B, K, 2, 2) or det.shape != (B, K):
        raise ValueError(f"t_s (B, K), z_m (B, K, 2), R_m2 (B, K, 2, 2), detected (B, K) must agree; got "
                         f"{t.shape}, {z.shape}, {R.shape}, {det.shape}")
    if np.any(ks < 1) or np.any(n > K) or np.any(ks > n):
        raise ValueError(f"k_start must be in [1, n_looks] and n_looks <= K = {K}; got k_start {ks}, n_looks {n}")
    return t, z, R, det, n, ks


def _bounds(spec):
    return spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2


def imm_cv_ct_filter(t_s, z_m, R_m2, detected, n_looks, k_start, x0, P0, spec: IMMCVCTSpec | None = None,
                     keep_modes=False, modes=None, params=None):
    """Run the IMM on B padded look sequences (the compiled kernel; no track start of its own).

    Args:
        t_s (B, K), z_m (B, K, 2), R_m2 (B, K, 2, 2), detected (B, K) bool: the looks (NaN allowed where missed).
        n_looks (B,) int: looks per row; k_start (B,) int, >= 1: first look filtered (``k_start - 1`` is the start,
            its time the time of ``x0``).
        x0 (B, 5), P0 (B, 5, 5): start state with a turn rate (a CV mode replaces the turn-rate part by its
            augmentation).
        spec: the parameters (default :data:`DEFAULT_IMM_CV_CT`).
        keep_modes: also return every mode's 5-state posterior per look.
        modes: ``(is_ct (M,), q_m_s2 (M,), log_Pi (M, M), log_mu0 (M,))`` overriding the spec's modes (e.g. a
            single CT mode: the CT-EKF alone); the spec still gives the turn-rate noises and bound.
        params: per-look values of :func:`look_parameter_names` (``(B, K, n_par)``, or broadcastable as
            :func:`check_look_parameters` says; look ``k`` of row ``b`` predicts and mixes with
            ``params[b, k]``), replacing the spec's constants; not with ``modes``.
    """
    spec = spec or DEFAULT_IMM_CV_CT
    t, z, R, det, n, ks = _looks_arrays(t_s, z_m, R_m2, detected, n_looks, k_start)
    B, K = t.shape
    x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(B, 5)
    P0 = np.ascontiguousarray(P0, dtype=np.float64).reshape(B, 5, 5)
    if modes is not None and params is not None:
        raise ValueError("give modes or params, not both (modes fixes q and the transition matrix)")
    if modes is not None:
        is_ct, q, log_Pi, log_mu0 = _modes_from_arrays(*modes)
        sig_w = spec.sigma_omega_deg_s15 * DEG
        q, sig_w2, log_Pi = q[None, None], np.full((1, 1), sig_w * sig_w), log_Pi[None, None]
    else:
        is_ct, _, _, log_mu0 = _modes_from_arrays(*spec.mode_arrays())
        q, sig_w2, log_Pi = kernel_parameters(
            spec, None if params is None else check_look_parameters(spec, params, B, K))
    M = is_ct.size
    out_x = np.full((B, K, 4), np.nan)
    out_P = np.full((B, K, 4, 4), np.nan)
    out_mu = np.full((B, K, M), np.nan)
    out_w = np.full((B, K), np.nan)
    out_wv = np.full((B, K), np.nan)
    out_nis = np.full((B, K), np.nan)
    shape_m = (B, K) if keep_modes else (1, 1)
    out_xm = np.full(shape_m + (M, 5), np.nan)
    out_Pm = np.full(shape_m + (M, 5, 5), np.nan)
    sig_w0 = spec.sigma_omega0_deg_s * DEG
    _kernel(t, z, R, det, n, ks, x0, P0, is_ct, q, sig_w2, sig_w0 * sig_w0, log_Pi, log_mu0, *_bounds(spec), out_x,
            out_P, out_mu, out_w, out_wv, out_nis, bool(keep_modes), out_xm, out_Pm)
    return IMMCVCTResult(out_x, out_P, out_mu, out_w, out_nis, out_xm if keep_modes else None,
                         out_Pm if keep_modes else None, np.sqrt(out_wv))


class IMMCVCTStep(NamedTuple):
    """One look of :meth:`IMMCVCTStepper.step` for the stepped rows (leading axis = those rows)."""

    look_index: np.ndarray      # (n,) the look just processed
    x: np.ndarray               # (n, 4) combined estimate
    P: np.ndarray               # (n, 4, 4)
    mu: np.ndarray              # (n, M) mode probabilities
    omega_rad_s: np.ndarray     # (n,) combined turn rate
    omega_std_rad_s: np.ndarray  # (n,) its standard deviation
    nis: np.ndarray             # (n,) NIS of the combined prediction (0 where missed)
    done: np.ndarray            # (n,) bool: the row's last look was processed


class IMMCVCTStepper:
    """The same IMM one look at a time, for a caller that chooses each look's parameters after seeing the
    previous look's output (a learned policy): :meth:`step` processes the next look of the given rows with
    their parameters, in the same compiled per-look function as :func:`imm_cv_ct_filter` (equal to it bit for
    bit with the same parameters: tested).

    Args: the looks, ``n_looks``, ``k_start``, ``x0``, ``P0`` and ``spec`` as :func:`imm_cv_ct_filter`.
    Attributes: ``x_modes (B, M, 5)``, ``P_modes (B, M, 5, 5)``, ``log_mu (B, M)``, ``k (B,)`` (next look),
    ``n_looks (B,)``.
    """

    def __init__(self, t_s, z_m, R_m2, detected, n_looks, k_start, x0, P0, spec: IMMCVCTSpec | None = None):
        self.spec = spec = spec or DEFAULT_IMM_CV_CT
        self._t, self._z, self._R, self._det, self.n_looks, ks = _looks_arrays(t_s, z_m, R_m2, detected, n_looks,
                                                                               k_start)
        B = self.B = self._t.shape[0]
        self.is_ct, _, _, log_mu0 = _modes_from_arrays(*spec.mode_arrays())
        M = self.is_ct.size
        sig_w0 = spec.sigma_omega0_deg_s * DEG
        self._sig_w0_2 = sig_w0 * sig_w0
        self.x_modes, self.P_modes, self.log_mu = np.empty((B, M, 5)), np.empty((B, M, 5, 5)), np.empty((B, M))
        x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(B, 5)
        P0 = np.ascontiguousarray(P0, dtype=np.float64).reshape(B, 5, 5)
        for b in range(B):   # once per track start, not per look
            _init_modes(x0[b], P0[b], self.is_ct, self._sig_w0_2, log_mu0, self.x_modes[b], self.P_modes[b],
                        self.log_mu[b])
        self.k = ks.copy()
        self.t_last = self._t[np.arange(B), ks - 1].copy()

    def step(self, params=None, rows=None) -> IMMCVCTStep:
        """Process the next look of ``rows`` (index array; default all) with ``params`` ((n, n_par) values of
        :func:`look_parameter_names`, or (n_par,) for all; default the spec's constants). ``ValueError`` for a row
        whose episode has ended or a parameter out of its range."""
        rows = np.arange(self.B) if rows is None else np.asarray(rows, dtype=np.int64).reshape(-1)
        n = rows.size
        if np.any(self.k[rows] >= self.n_looks[rows]):
            raise ValueError("step() called on a row whose episode has ended")
        p = None if params is None else check_look_parameters(self.spec, params, n, 1)
        q, sig_w2, log_Pi = kernel_parameters(self.spec, p)
        q = np.ascontiguousarray(np.broadcast_to(q[:, 0], (n,) + q.shape[2:]))
        sig_w2 = np.ascontiguousarray(np.broadcast_to(sig_w2[:, 0], (n,)))
        log_Pi = np.ascontiguousarray(np.broadcast_to(log_Pi[:, 0], (n,) + log_Pi.shape[2:]))
        M = self.is_ct.size
        out = IMMCVCTStep(self.k[rows].copy(), np.empty((n, 4)), np.empty((n, 4, 4)), np.empty((n, M)),
                          np.empty(n), np.empty(n), np.empty(n), None)
        _step_kernel(rows, self._t, self._z, self._R, self._det, self.is_ct, q, sig_w2, self._sig_w0_2, log_Pi,
                     *_bounds(self.spec), self.x_modes, self.P_modes, self.log_mu, self.k, self.t_last, out.x,
                     out.P, out.mu, out.omega_rad_s, out.omega_std_rad_s, out.nis)
        np.sqrt(out.omega_std_rad_s, out=out.omega_std_rad_s)
        return out._replace(done=self.k[rows] >= self.n_looks[rows])


# ------------------------------------------------------------------------------------------------ on episodes
def common_start(episodes, cfg=None):
    """The common track start of ``episodes`` (two-hit start + warm-up through :class:`Tracker`):
    ``(batch, look_index (B,), x (B, 4), P (B, 4, 4))`` with ``look_index`` the last warm-up look."""
    episodes = list(episodes)
    tr, out = _tracker(episodes, cfg)
    return stack_episodes(episodes), np.asarray(out.look_index, dtype=np.int64), tr.x.copy(), tr.P.copy()


def run_imm_cv_ct(episodes, spec: IMMCVCTSpec | None = None, name="imm_cv_ct", cfg=None,
                  start=None):
    """``imm_cv_ct`` on recorded episodes, from the common track start (every mode at the warm-up estimate, turn
    rate 0 with variance ``sigma_omega0^2``). Returns a :class:`baselines.trackers.TrackRun` with extra series
    ``maneuver_probability`` and ``turn_rate_deg_s``; ``start``: a :func:`common_start` result to reuse (tuning)."""
    spec = spec or DEFAULT_IMM_CV_CT
    batch, k0, x4, P4 = start if start is not None else common_start(episodes, cfg)
    B, K = batch.t_s.shape
    x5 = np.concatenate([x4, np.zeros((B, 1))], axis=1)
    P5 = np.zeros((B, 5, 5))
    P5[:, :4, :4] = P4
    P5[:, 4, 4] = (spec.sigma_omega0_deg_s * DEG) ** 2
    res = imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec)
    rows = np.arange(B)
    x, P = res.x, res.P
    x[rows, k0], P[rows, k0] = x4, P4      # the start look, as every tracker records it
    p_man = 1.0 - res.mu[..., 0]
    declared = np.zeros((B, K), dtype=bool)
    declared[np.isfinite(p_man)] = p_man[np.isfinite(p_man)] > 0.5
    return TrackRun(name, x, P, k0 + 1, np.full((B, K), np.nan), declared=declared,
                    extra={"maneuver_probability": p_man, "turn_rate_deg_s": np.degrees(res.omega_rad_s)})


# numba keys each cached kernel on its own file only, and these call radar_env.kernels: drop the cached kernels
# of this folder when a source of radar_env or baselines changed (radar_env.numba_cache)
drop_stale_kernels(_ct_coefficients, package_sources(Path(__file__).parents[1] / "radar_env", Path(__file__).parent))
