r"""Kalman and IMM filter math: one batched implementation used by the env, the baselines and the evaluation.

All functions are pure, float64, batch axis first, and free of randomness. State order is ``[x, y, vx, vy]``
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
:math:`x^+ = x^- + K\nu`, and the Joseph form :math:`P^+ = (I-KH)P^-(I-KH)^T + K R K^T`, symmetrised, which keeps
:math:`P^+` symmetric positive definite for any :math:`q \ge 0`. NIS :math:`= \nu^T S^{-1}\nu`; the Gaussian
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
]

_LOG_2PI = float(np.log(2.0 * np.pi))


def _as_batch(a) -> np.ndarray:
    return np.atleast_1d(np.asarray(a, dtype=np.float64))


def _mT(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def _sym(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + _mT(A))


def transition_cv(dt_s) -> np.ndarray:
    """Constant-velocity transition matrices ``F (B,4,4)`` for time steps ``dt_s (B,)``."""
    dt = _as_batch(dt_s)
    F = np.zeros(dt.shape + (4, 4))
    F[..., 0, 0] = F[..., 1, 1] = F[..., 2, 2] = F[..., 3, 3] = 1.0
    F[..., 0, 2] = F[..., 1, 3] = dt
    return F


def transition_ct(dt_s, turn_rate_rad_s) -> np.ndarray:
    """Coordinated-turn transition matrices ``F (B,4,4)``; exact kinematics of a constant-speed turn.

    Args:
        dt_s: time steps (B,) or scalar.
        turn_rate_rad_s: heading rate (B,) or scalar, positive = clockwise (right turn). Zero gives ``F_cv``.
    """
    dt, w = np.broadcast_arrays(_as_batch(dt_s), _as_batch(turn_rate_rad_s))
    theta = w * dt
    s, c = np.sin(theta), np.cos(theta)
    # sin(theta)/w = dt*sinc(theta); (1-cos(theta))/w = dt*(theta/2)*sinc(theta/2)^2 -- exact, smooth at w = 0.
    a = dt * np.sinc(theta / np.pi)
    b = dt * (theta / 2.0) * np.sinc(theta / (2.0 * np.pi)) ** 2
    F = np.zeros(dt.shape + (4, 4))
    F[..., 0, 0] = F[..., 1, 1] = 1.0
    F[..., 0, 2], F[..., 0, 3] = a, b
    F[..., 1, 2], F[..., 1, 3] = -b, a
    F[..., 2, 2], F[..., 2, 3] = c, s
    F[..., 3, 2], F[..., 3, 3] = -s, c
    return F


def process_noise(dt_s, q_m_s2) -> np.ndarray:
    """Piecewise-constant white-acceleration process noise ``Q = q^2 Gamma Gamma^T`` of shape (B,4,4).

    Args:
        dt_s: time steps (B,) or scalar, seconds.
        q_m_s2: acceleration standard deviation (B,) or scalar, m/s^2 (Bizup's ``Q = q^2 I`` on the acceleration).
    """
    dt, q = np.broadcast_arrays(_as_batch(dt_s), _as_batch(q_m_s2))
    q2 = q * q
    pp, pv, vv = q2 * dt**4 / 4.0, q2 * dt**3 / 2.0, q2 * dt**2
    Q = np.zeros(dt.shape + (4, 4))
    Q[..., 0, 0] = Q[..., 1, 1] = pp
    Q[..., 0, 2] = Q[..., 2, 0] = Q[..., 1, 3] = Q[..., 3, 1] = pv
    Q[..., 2, 2] = Q[..., 3, 3] = vv
    return Q


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray, u: np.ndarray | None = None):
    """Kalman prediction ``x- = F x (+ u)``, ``P- = F P F^T + Q`` (symmetrised). Shapes (...,4), (...,4,4)."""
    x_prior = np.einsum("...ij,...j->...i", F, x)
    if u is not None:
        x_prior = x_prior + u
    return x_prior, _sym(F @ P @ _mT(F) + Q)


def inv2(S: np.ndarray):
    """Closed-form inverse and determinant of 2x2 matrices ``S (...,2,2)``. Returns ``(S_inv, det)``."""
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
    """Kalman update with a converted position plot, Joseph form.

    Args:
        x, P: prior state (...,4) and covariance (...,4,4).
        z, R: converted position (...,2) and its covariance (...,2,2). May hold NaN where ``detected`` is False.
        detected: bool (...) or None (all detected). Where False the posterior equals the prior.
    """
    if detected is None:
        detected = np.ones(x.shape[:-1], dtype=bool)
    detected = np.asarray(detected, dtype=bool)
    # Missed plots are replaced by harmless values so that no NaN enters the arithmetic; a zero gain then
    # leaves x and P bit-for-bit unchanged.
    nu = np.where(detected[..., None], z - x[..., :2], 0.0)
    R = np.where(detected[..., None, None], R, np.eye(2))
    S = _sym(P[..., :2, :2] + R)
    S_inv, det = inv2(S)
    K = np.where(detected[..., None, None], P[..., :, :2] @ S_inv, 0.0)  # P H^T S^-1, (...,4,2)
    x_post = x + np.einsum("...ij,...j->...i", K, nu)
    # Joseph form with H = [I 0]: M = (I - K H) P, P+ = M (I - K H)^T + K R K^T = M + (K R - M H^T) K^T,
    # where M H^T = P H^T - K (H P H^T) is formed directly (contiguous 4x2 products are the cheap ones).
    M = P - K @ P[..., :2, :]
    MHt = P[..., :, :2] - K @ P[..., :2, :2]
    P_post = _sym(M + (K @ R - MHt) @ _mT(K))
    n0, n1 = nu[..., 0], nu[..., 1]
    nis = n0 * n0 * S_inv[..., 0, 0] + 2.0 * n0 * n1 * S_inv[..., 0, 1] + n1 * n1 * S_inv[..., 1, 1]
    loglik = -0.5 * (nis + 2.0 * _LOG_2PI + np.log(det))
    return UpdateResult(x_post, P_post, nu, S, np.where(detected, nis, 0.0), np.where(detected, loglik, 0.0))


def two_point_init(z1, R1, t1_s, z2, R2, t2_s):
    """Two-hit track start from two converted plots: position from the second, velocity by differencing.

    ``x = [z2, (z2 - z1)/dt]``, ``P = [[R2, R2/dt], [R2/dt, (R1 + R2)/dt^2]]`` (the exact covariance of that
    estimate when the plots' errors are independent and the target moves uniformly).
    """
    z1, z2, R1, R2 = (np.asarray(a, dtype=np.float64) for a in (z1, z2, R1, R2))
    dt = np.asarray(t2_s, dtype=np.float64) - np.asarray(t1_s, dtype=np.float64)
    if np.any(dt <= 0):
        raise ValueError("two_point_init: t2_s must be later than t1_s")
    dt2 = dt[..., None, None]
    x = np.concatenate([z2, (z2 - z1) / dt[..., None]], axis=-1)
    P = np.zeros(z1.shape[:-1] + (4, 4))
    P[..., :2, :2] = R2
    P[..., :2, 2:] = R2 / dt2
    P[..., 2:, :2] = R2 / dt2
    P[..., 2:, 2:] = (R1 + R2) / dt2**2
    return x, P


# ----------------------------------------------------------------------------------------------------------- IMM
def _logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(a - m), axis=axis))


def imm_mix(log_mu: np.ndarray, log_Pi: np.ndarray, x: np.ndarray, P: np.ndarray):
    """IMM interaction (mixing) step.

    Args:
        log_mu: log mode probabilities (B,M).
        log_Pi: log transition matrix (M,M) or (B,M,M), ``Pi[i, j] = P(mode j at k | mode i at k-1)``.
        x, P: mode-matched posteriors (B,M,4), (B,M,4,4).
    Returns:
        ``x0 (B,M,4), P0 (B,M,4,4)`` mixed initial conditions and ``log_c (B,M)`` predicted log mode probabilities.
    """
    a = log_Pi + log_mu[..., :, None]  # (B,M_from,M_to)
    log_c = _logsumexp(a, axis=-2)  # (B,M_to)
    w = np.exp(a - log_c[..., None, :])  # mu_{i|j}, columns sum to 1
    x0 = np.einsum("bij,bid->bjd", w, x)
    dx = x[:, :, None, :] - x0[:, None, :, :]  # (B,i,j,4)
    P0 = np.einsum("bij,bijde->bjde", w, P[:, :, None] + dx[..., :, None] * dx[..., None, :])
    return x0, 0.5 * (P0 + np.swapaxes(P0, -1, -2)), log_c


def imm_mode_probabilities(log_c: np.ndarray, loglik: np.ndarray) -> np.ndarray:
    """Posterior log mode probabilities ``log mu_j = log c_j + l_j - logsumexp`` (B,M)."""
    a = log_c + loglik
    return a - _logsumexp(a, axis=-1)[..., None]


def imm_combine(log_mu: np.ndarray, x: np.ndarray, P: np.ndarray):
    """Moment-matched combined estimate ``(x (B,4), P (B,4,4))`` of the mode-matched posteriors."""
    mu = np.exp(log_mu)
    xc = np.einsum("bm,bmd->bd", mu, x)
    dx = x - xc[:, None, :]
    Pc = np.einsum("bm,bmde->bde", mu, P + dx[..., :, None] * dx[..., None, :])
    return xc, 0.5 * (Pc + np.swapaxes(Pc, -1, -2))


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


def imm_step(log_mu, x_modes, P_modes, log_Pi, F, Q, z, R, detected=None) -> IMMResult:
    """One full IMM cycle: mix, mode-matched predict and update, mode probabilities, combination.

    Args:
        log_mu (B,M), x_modes (B,M,4), P_modes (B,M,4,4): previous IMM state.
        log_Pi: (M,M) or (B,M,M) log transition matrix.
        F, Q: per-mode transition and process noise, (B,M,4,4) (or broadcastable, e.g. (M,4,4)).
        z (B,2), R (B,2,2), detected (B,) or None: the plot.
    """
    B, M = log_mu.shape
    x0, P0, log_c = imm_mix(log_mu, log_Pi, x_modes, P_modes)
    x_pr, P_pr = predict(x0, P0, F, Q)
    det_bm = np.ones((B, M), bool) if detected is None else np.broadcast_to(np.asarray(detected)[:, None], (B, M))
    upd = update(x_pr, P_pr, z[:, None, :], R[:, None, :, :], det_bm)
    log_mu_new = imm_mode_probabilities(log_c, upd.loglik)
    xc, Pc = imm_combine(log_mu_new, upd.x, upd.P)
    # Innovation of the combined prediction (a maneuver feature, and what the IMM "saw").
    xp_c, Pp_c = imm_combine(log_c - _logsumexp(log_c, -1)[..., None], x_pr, P_pr)
    comb = update(xp_c, Pp_c, z, R, detected)
    return IMMResult(log_mu_new, upd.x, upd.P, xc, Pc, upd.loglik, comb.nis, comb.nu, comb.S)
