r"""Kalman and IMM filter math: one batched implementation used by the env, the baselines and the evaluation.

All functions are pure, float64, batch axis first, and free of randomness. The arithmetic is written once, as
compiled per-row code in :mod:`radar_env.filters.kernels`; the functions here broadcast their inputs, flatten the batch
axes and call those kernels (the only numpy reference left is :func:`inv2`, a two-line closed form used by
baselines/konle.py). State order is ``[x, y, vx, vy]``
(metres, m/s), the measurement is the converted position ``z = H x + v`` with ``H = [I2 0]``.

Models
------
Constant velocity (Bizup eq 1), with ``dt`` the time since the previous update:

.. math:: F_{cv}(dt) = \begin{bmatrix} I & dt\,I \\ 0 & I \end{bmatrix}

Coordinated turn with heading rate :math:`\omega` (positive = clockwise = right turn, see docs/architecture.md);
velocity rotates clockwise by :math:`\theta = \omega\,dt`:

.. math::
    F_{ct}(dt, \omega) = \begin{bmatrix}
      1 & 0 & \sin\theta/\omega & (1-\cos\theta)/\omega \\
      0 & 1 & -(1-\cos\theta)/\omega & \sin\theta/\omega \\
      0 & 0 & \cos\theta & \sin\theta \\
      0 & 0 & -\sin\theta & \cos\theta \end{bmatrix}

(Adrian's counter-clockwise :math:`F(\omega)` is ours at :math:`-\omega`.) The sinc forms used below are exact and
smooth at :math:`\omega = 0`, where :math:`F_{ct} = F_{cv}`.

Process noise, piecewise-constant white acceleration of standard deviation ``q`` (m/s^2) per axis:
:math:`Q = q^2\,\Gamma\Gamma^T`, :math:`\Gamma = [dt^2/2,\ dt]^T` per axis.

Filter cycle
------------
predict: :math:`x^- = F x + u`, :math:`P^- = F P F^T + Q` (``u`` an optional known input, used by the clairvoyant
bound). update: :math:`\nu = z - H x^-`, :math:`S = H P^- H^T + R`, :math:`K = P^- H^T S^{-1}`,
:math:`x^+ = x^- + K\nu`, :math:`P^+ = (I-KH)P^-`, written so that small posterior variances stay accurate after a
large prior: the position rows and columns as :math:`P^+H^T = KR`, the rest as :math:`P^-_{vv} - K_v P^-_{pv}`
(``P - KHP`` and the Joseph form subtract prior-sized numbers in the position block: a rounding error of
``eps x prior``, above the posterior after a long or hard coast), symmetrised. Where rounding would still leave
:math:`P^+` indefinite, or so near singular that a Cholesky factorisation may refuse it (the smallest eigenvalue of
its correlation matrix below ``2^-45``: a near-singular plot, a coast of minutes at 100 g), the smallest isotropic
addition on a grid restores that margin
(:func:`radar_env.filters.kernels._pd_floor`; nothing changes on ordinary looks), so :math:`P^+` is symmetric positive
definite (Cholesky) for any :math:`q \ge 0` and every radar the env accepts. NIS :math:`= \nu^T S^{-1}\nu`; the Gaussian
log-likelihood :math:`\ell = -\tfrac12(\mathrm{NIS} + \log\det(2\pi S))`. A missed detection skips the update
(posterior = prior, NIS = 0, likelihood 0 in log space).

IMM
---
Mode probabilities are carried as logs. With transition matrix :math:`\Pi_{ij} = P(j \mid i)`:
:math:`\log\bar c_j = \mathrm{logsumexp}_i(\log\Pi_{ij} + \log\mu_i)`, mixing weights
:math:`\mu_{i|j} = \exp(\log\Pi_{ij} + \log\mu_i - \log\bar c_j)`; after the mode-matched updates
:math:`\log\mu_j = \log\bar c_j + \ell_j - \mathrm{logsumexp}_j(\cdot)`. Working in logs avoids the underflow of
the linear-space product when one mode's likelihood is tiny (FilterPy multiplies in linear space).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import kernels as _k
from ..sim.motion import _as_batch, _flat, transition_ct, transition_cv  # noqa: F401  (the motion model)
from ..sim.looks import range_rate_inputs

__all__ = [
    "transition_cv",
    "transition_ct",
    "process_noise",
    "predict",
    "update",
    "UpdateResult",
    "two_point_init",
    "inv2",
    "imm_mix",
    "imm_mode_probabilities",
    "imm_combine",
    "imm_step",
    "IMMResult",
    "imm_filter",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


def process_noise(dt_s, q_m_s2) -> np.ndarray:
    """Piecewise-constant white-acceleration process noise ``Q = q^2 Gamma Gamma^T`` of shape (B,4,4).

    Args:
        dt_s: time steps (B,) or scalar, seconds.
        q_m_s2: acceleration standard deviation (B,) or scalar, m/s^2 (Bizup's ``Q = q^2 I`` on the acceleration).
    """
    dt, q = np.broadcast_arrays(_as_batch(dt_s), _as_batch(q_m_s2))
    Q = np.empty((dt.size, 4, 4))
    _k.k_process_noise(_flat(dt, dt.shape, ()), _flat(q, dt.shape, ()), Q)
    return Q.reshape(dt.shape + (4, 4))


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray, u: np.ndarray | None = None):
    """Kalman prediction ``x- = F x (+ u)``, ``P- = F P F^T + Q`` (symmetrised). Shapes (...,4), (...,4,4)."""
    x, P, F, Q = (np.asarray(a, dtype=np.float64) for a in (x, P, F, Q))
    shape = np.broadcast_shapes(x.shape[:-1], P.shape[:-2], F.shape[:-2], Q.shape[:-2],
                                () if u is None else np.shape(u)[:-1])
    xf, Pf, Ff, Qf = _flat(x, shape, (4,)), _flat(P, shape, (4, 4)), _flat(F, shape, (4, 4)), _flat(Q, shape, (4, 4))
    uf = np.zeros((1, 4)) if u is None else _flat(u, shape, (4,))
    xo, Po = np.empty_like(xf), np.empty_like(Pf)
    _k.k_predict(xf, Pf, Ff, Qf, uf, u is not None, xo, Po)
    return xo.reshape(shape + (4,)), Po.reshape(shape + (4, 4))


def inv2(S: np.ndarray):
    """Closed-form inverse and determinant of 2x2 matrices ``S (...,2,2)``. Returns ``(S_inv, det)``.

    Plain numpy (a helper of baselines/konle.py); the kernels inline the same closed form."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    inv = np.empty_like(S)
    inv[..., 0, 0], inv[..., 0, 1] = d / det, -b / det
    inv[..., 1, 0], inv[..., 1, 1] = -c / det, a / det
    return inv, det


class UpdateResult(NamedTuple):
    """Output of :func:`update`. ``nu`` is zero, ``nis`` and ``loglik`` are 0 where the plot was missed."""

    x: np.ndarray  # posterior state (...,4)
    P: np.ndarray  # posterior covariance (...,4,4)
    nu: np.ndarray  # innovation z - H x- (...,2)
    S: np.ndarray  # innovation covariance (...,2,2)
    nis: np.ndarray  # normalised innovation squared (...)
    loglik: np.ndarray  # Gaussian log-likelihood of the innovation (...)


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, detected=None) -> UpdateResult:
    """Kalman update with a converted position plot (the module docstring's covariance form, positive definite).

    Args:
        x, P: prior state (...,4) and covariance (...,4,4).
        z, R: converted position (...,2) and its covariance (...,2,2). May hold NaN where ``detected`` is False.
        detected: bool (...) or None (all detected). Where False the posterior equals the prior (bit for bit, unless the
            prior is not positive definite with that margin: then floored as above), the
            innovation is 0 and ``S = P[:2,:2] + I`` (R is not read, so NaN there does no harm).
    """
    x, P, z, R = (np.asarray(a, dtype=np.float64) for a in (x, P, z, R))
    det = np.ones((), dtype=bool) if detected is None else np.asarray(detected, dtype=bool)
    shape = np.broadcast_shapes(x.shape[:-1], P.shape[:-2], z.shape[:-1], R.shape[:-2], det.shape)
    xf, Pf = _flat(x, shape, (4,)), _flat(P, shape, (4, 4))
    zf, Rf = _flat(z, shape, (2,)), _flat(R, shape, (2, 2))
    df = _k.c_array(np.broadcast_to(det, shape)).reshape(-1)
    n = xf.shape[0]
    xo, Po, nu, S, nis, ll = (np.empty_like(xf), np.empty_like(Pf), np.empty((n, 2)), np.empty((n, 2, 2)),
                              np.empty(n), np.empty(n))
    _k.k_update(xf, Pf, zf, Rf, df, xo, Po, nu, S, nis, ll)
    return UpdateResult(xo.reshape(shape + (4,)), Po.reshape(shape + (4, 4)), nu.reshape(shape + (2,)),
                        S.reshape(shape + (2, 2)), nis.reshape(shape), ll.reshape(shape))


def two_point_init(z1, R1, t1_s, z2, R2, t2_s):
    """Two-hit track start from two converted plots: position from the second, velocity by differencing.

    ``x = [z2, (z2 - z1)/dt]``, ``P = [[R2, R2/dt], [R2/dt, (R1 + R2)/dt^2]]`` (the exact covariance of that
    estimate when the plots' errors are independent and the target moves uniformly).
    """
    z1, z2, R1, R2 = (np.asarray(a, dtype=np.float64) for a in (z1, z2, R1, R2))
    t1, t2 = np.asarray(t1_s, dtype=np.float64), np.asarray(t2_s, dtype=np.float64)
    if np.any(t2 - t1 <= 0):
        raise ValueError("two_point_init: t2_s must be later than t1_s")
    shape = np.broadcast_shapes(z1.shape[:-1], z2.shape[:-1], R1.shape[:-2], R2.shape[:-2], t1.shape, t2.shape)
    n = int(np.prod(shape))
    x, P = np.empty((n, 4)), np.empty((n, 4, 4))
    _k.k_two_point_init(_flat(z1, shape, (2,)), _flat(R1, shape, (2, 2)), _flat(t1, shape, ()),
                        _flat(z2, shape, (2,)), _flat(R2, shape, (2, 2)), _flat(t2, shape, ()), x, P)
    return x.reshape(shape + (4,)), P.reshape(shape + (4, 4))


# ----------------------------------------------------------------------------------------------------------- IMM
def _log_pi(log_Pi, B, M):
    return _flat(log_Pi, (B,), (M, M))


def imm_mix(log_mu: np.ndarray, log_Pi: np.ndarray, x: np.ndarray, P: np.ndarray):
    """IMM interaction (mixing) step.

    Args:
        log_mu: log mode probabilities (B,M).
        log_Pi: log transition matrix (M,M) or (B,M,M), ``Pi[i, j] = P(mode j at k | mode i at k-1)``.
        x, P: mode-matched posteriors (B,M,4), (B,M,4,4).
    Returns:
        ``x0 (B,M,4), P0 (B,M,4,4)`` mixed initial conditions and ``log_c (B,M)`` predicted log mode probabilities.
    """
    log_mu = _k.c_array(log_mu, np.float64)
    B, M = log_mu.shape
    x0, P0, log_c = np.empty((B, M, 4)), np.empty((B, M, 4, 4)), np.empty((B, M))
    _k.k_imm_mix(log_mu, _log_pi(log_Pi, B, M), _flat(x, (B, M), (4,)).reshape(B, M, 4),
                 _flat(P, (B, M), (4, 4)).reshape(B, M, 4, 4), x0, P0, log_c)
    return x0, P0, log_c


def imm_mode_probabilities(log_c: np.ndarray, loglik: np.ndarray) -> np.ndarray:
    """Posterior log mode probabilities ``log mu_j = log c_j + l_j - logsumexp`` (B,M)."""
    log_c = _k.c_array(log_c, np.float64)
    out = np.empty_like(log_c)
    _k.k_imm_mode_probabilities(log_c, _k.c_array(np.broadcast_to(loglik, log_c.shape), dtype=np.float64),
                                out)
    return out


def imm_combine(log_mu: np.ndarray, x: np.ndarray, P: np.ndarray):
    """Moment-matched combined estimate ``(x (B,4), P (B,4,4))`` of the mode-matched posteriors."""
    log_mu = _k.c_array(log_mu, np.float64)
    B, M = log_mu.shape
    xc, Pc = np.empty((B, 4)), np.empty((B, 4, 4))
    _k.k_imm_combine(log_mu, _flat(x, (B, M), (4,)).reshape(B, M, 4), _flat(P, (B, M), (4, 4)).reshape(B, M, 4, 4),
                     xc, Pc)
    return xc, Pc


class IMMResult(NamedTuple):
    """Output of :func:`imm_step`."""

    log_mu: np.ndarray  # (B,M) posterior log mode probabilities
    x_modes: np.ndarray  # (B,M,4)
    P_modes: np.ndarray  # (B,M,4,4)
    x: np.ndarray  # (B,4) combined
    P: np.ndarray  # (B,4,4) combined
    loglik: np.ndarray  # (B,M) mode-matched log-likelihoods
    nis: np.ndarray  # (B,) NIS of the combined prediction
    nu: np.ndarray  # (B,2) innovation of the combined prediction
    S: np.ndarray  # (B,2,2) its covariance


def imm_step(log_mu, x_modes, P_modes, log_Pi, F, Q, z, R, detected=None, radial_velocity_m_s=None, site_xy_m=None,
             radial_velocity_std_m_s=None) -> IMMResult:
    """One full IMM cycle: mix, mode-matched predict and update, mode probabilities, combination.

    Args:
        log_mu (B,M), x_modes (B,M,4), P_modes (B,M,4,4): previous IMM state.
        log_Pi: (M,M) or (B,M,M) log transition matrix.
        F, Q: per-mode transition and process noise, (B,M,4,4) (or broadcastable, e.g. (M,4,4)).
        z (B,2), R (B,2,2), detected (B,) or None: the plot.
        radial_velocity_m_s (B,), site_xy_m (B,2), radial_velocity_std_m_s (B,): optional; given, each mode also
            updates on the radial velocity after the position, and its likelihood joins the mode's
            (:func:`radar_env.filters.kernels._rdot_update`; a look whose value or std is not finite is skipped).

    ``nis``, ``nu``, ``S`` are those of the combined prediction (the moment-matched mixture of the mode-matched
    predictions): what the IMM "saw", a maneuver feature.
    """
    log_mu = _k.c_array(log_mu, np.float64)
    B, M = log_mu.shape
    det = np.ones(B, dtype=bool) if detected is None else \
        _k.c_array(np.broadcast_to(np.asarray(detected, dtype=bool), (B,)))
    out = (np.empty((B, M)), np.empty((B, M, 4)), np.empty((B, M, 4, 4)), np.empty((B, 4)), np.empty((B, 4, 4)),
           np.empty((B, M)), np.empty(B), np.empty((B, 2)), np.empty((B, 2, 2)))
    _k.k_imm_step(log_mu, _flat(x_modes, (B, M), (4,)).reshape(B, M, 4),
                  _flat(P_modes, (B, M), (4, 4)).reshape(B, M, 4, 4), _log_pi(log_Pi, B, M),
                  _flat(F, (B, M), (4, 4)).reshape(B, M, 4, 4), _flat(Q, (B, M), (4, 4)).reshape(B, M, 4, 4),
                  _flat(z, (B,), (2,)), _flat(R, (B,), (2, 2)), det,
                  *range_rate_inputs((B,), radial_velocity_m_s, site_xy_m, radial_velocity_std_m_s), *out)
    return IMMResult(*out)


def imm_filter(t_s, z_m, R_m2, detected, n_looks, k_start, t_start_s, log_mu0, x0, P0, log_Pi, q_m_s2,
               turn_rate_rad_s, radial_velocity_m_s=None, site_xy_m=None, radial_velocity_std_m_s=None):
    """:func:`imm_step` over every look of B padded look sequences, in one compiled call: mode ``m`` predicts with
    ``transition_ct(dt, turn_rate_rad_s[m])`` (0 = CV) and ``process_noise(dt, q_m_s2[m])``; the results are those
    of calling ``imm_step`` look by look, bit for bit.

    Args:
        t_s (B, K), z_m (B, K, 2), R_m2 (B, K, 2, 2), detected (B, K): the looks (z, R not read where missed).
        n_looks (B,), k_start (B,): row b filters looks ``k_start[b] .. n_looks[b] - 1``.
        t_start_s (B,): time of the mode states below (the look before ``k_start``).
        log_mu0 (B, M), x0 (B, M, 4), P0 (B, M, 4, 4): the IMM state at ``t_start_s``.
        log_Pi (M, M): log transition matrix; q_m_s2 (M,), turn_rate_rad_s (M,): the modes.
        radial_velocity_m_s (B, K), site_xy_m (B, K, 2), radial_velocity_std_m_s (B, K): optional, as
            :func:`imm_step`'s.
    Returns:
        ``(x (B, K, 4), P (B, K, 4, 4), log_mu (B, K, M))``: the combined estimate and the posterior log mode
        probabilities of every filtered look, NaN elsewhere.
    """
    t = _k.c_array(t_s, np.float64)
    B, K = t.shape
    log_mu0 = _k.c_array(log_mu0, np.float64)
    M = log_mu0.shape[1]
    n, ks = _k.c_array(np.reshape(n_looks, B), np.int64), _k.c_array(np.reshape(k_start, B), np.int64)
    if np.any(ks < 0) or np.any(ks > n) or np.any(n > K):
        raise ValueError(f"imm_filter: need 0 <= k_start <= n_looks <= K = {K} per row; got k_start {ks}, n_looks {n}")
    x, P, log_mu = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan), np.full((B, K, M), np.nan)
    _k.k_imm_run(t, _flat(z_m, (B, K), (2,)).reshape(B, K, 2), _flat(R_m2, (B, K), (2, 2)).reshape(B, K, 2, 2),
                 _k.c_array(np.broadcast_to(detected, (B, K)), np.bool_),
                 *range_rate_inputs((B, K), radial_velocity_m_s, site_xy_m, radial_velocity_std_m_s), n, ks,
                 _k.c_array(t_start_s, np.float64), log_mu0, _flat(x0, (B, M), (4,)).reshape(B, M, 4),
                 _flat(P0, (B, M), (4, 4)).reshape(B, M, 4, 4), _flat(log_Pi, (M,), (M,)),
                 _flat(q_m_s2, (M,), ()), _flat(turn_rate_rad_s, (M,), ()), x, P, log_mu)
    return x, P, log_mu
