"""A learned window correction (kind ``window_correction``): a small network that reads the last plots in its base
tracker's frame and moves the position the base tracker reports (issue 38; docs/training.md, "A window correction").

A Kalman filter's estimate after a turn lags: its state summarises the whole past with one Gaussian, so plots that
left the straight line a few looks ago pull it only as far as its gain allows. The correction looks again at the
last ``window_looks`` plots (detected or not, each with its time) as residuals from the base track's straight line
through its current estimate, in the frame of its velocity (along, across), and outputs where the target is
relative to that estimate: a regression of the truth on the window, trained on flights of training-range seeds
(:mod:`agents.training.window`). Optionally it also reads least-squares quadratics through the window's residuals
(``fit_looks``) and the q its base chose at its last looks (``q_looks``, a q-policy base), :func:`window_features`.
It is causal (look k's correction uses the plots up to look k and the base's estimate and q up to look k only) and
has no feedback: the base tracker runs unchanged. Without a covariance head its
covariance is reported unchanged (the consistency rows show what that costs); with one (``policy.json``'s
``architecture.covariance``), the reported covariance is the head's: a second linear output of the last tanh layer
giving the Cholesky factor of the error covariance of the corrected position and the base's velocity, fitted by
Gaussian likelihood on the training looks with the network fixed (:func:`head_covariance`).

A folder holds ``policy.npz`` (the weights, float64), ``policy.json`` (``kind``, ``format``, ``version``, ``base``:
the base tracker as a bundled name or a folder relative to this one, and the ``architecture``) and
``env_config.json`` (the base's, for the evaluation's bookkeeping); ``training.json`` and ``choice.json`` as every
learned tracker. Loading checks every file (:mod:`agents.policies.checks`); no pickle.

An *ensemble* folder (``policy.json`` version 2, :data:`ENSEMBLE_VERSION`; built by
``scripts/make_window_ensemble.py`` from training runs) holds ``members`` networks of one architecture over one base,
each as trained, on its standardised inputs: the estimate moves by the mean of their moves, and the covariance is the
mixture's, times ``covariance_scale`` (1 unless ``scripts/calibrate_window_covariance.py`` fitted one: the mean of
heads fitted each to its own looks is more cautious than each head). Its ``precision`` may be ``"float32"`` (the
networks were trained in float32; the forward then costs about half) and its ``base_precision`` ``"float32"`` for a
recurrent q-policy base (its GRU; about 0.7x the time): the bundled ``policy_window`` runs both, the three networks
and the base together costing less than one float64 network over a float64 base (issue 38's cap of 5x imm_cv_ct per
look), and equal to its float64 numbers to 1e-8 in the pooled RMSE.

The network: ``layers`` tanh layers of the given widths and a linear output of two numbers, the truth's offset from
the base estimate along and across its velocity in units of ``scale_m`` (and, with a covariance head, a second linear
output of :data:`COV_OUTPUTS` numbers from the same last layer). It runs through the compiled
:func:`agents.policies.recurrent.linear` (a row's output does not depend on the batch it is in).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import gymnasium as gym
import numba
import numpy as np

from agents.policies.recurrent import layer_weights, linear

__all__ = ["FORMAT", "VERSION", "POLICY_FILE", "COV_OUTPUTS", "head_covariance", "window_features", "look_features",
           "feature_count", "FIT_FEATURES", "Q_FLOOR_M_S2", "check_q_looks", "network_shapes", "network_forward",
           "WindowCorrection", "ENSEMBLE_VERSION", "COVARIANCE_SCALE_RANGE", "save_window_ensemble", "ensemble_members",
           "ensemble_fields",
           "is_window_correction", "load_window_correction", "save_window_correction", "CorrectedEstimate"]

FORMAT = "radar-track-window-correction"
VERSION = 1
"""A single correction's folder (the trainer writes it): ``policy.npz`` holds one network, its input
standardisation folded into the first layer."""
ENSEMBLE_VERSION = 2
"""An ensemble's folder (:func:`save_window_ensemble`): ``policy.npz`` holds ``members`` networks over one base, each
as trained (``member{j}.`` + :func:`network_shapes`' names, on standardised inputs) with its standardisation
(``member{j}.input_mean``, ``member{j}.input_sd``); ``policy.json`` adds ``members``, ``precision`` (the networks'
forward), ``base_precision`` (a q-policy base's GRU) and, optionally, ``covariance_scale`` (the reported covariance's
factor, :data:`COVARIANCE_SCALE_RANGE`; 1 when absent; ``scripts/calibrate_window_covariance.py`` fits it)."""
MAX_MEMBERS = 16
COVARIANCE_SCALE_RANGE = (0.1, 10.0)
"""Bounds of an ensemble's ``covariance_scale``: a calibration outside them says the heads are wrong, not shy."""
PRECISIONS = ("float64", "float32")
POLICY_FILE = "policy.npz"
RESIDUAL_CLIP = 30.0
"""Residuals are clipped to +-30 ``scale_m`` (9 km at the default 300 m): a plot that far off the track says only
"far", and the network's inputs stay bounded whatever the plots."""


COV_OUTPUTS = 10
"""Outputs of the covariance head: the lower triangle, row by row, of a Cholesky factor ``L`` of the 4x4 error
covariance in the base frame (position along, across in ``scale_m``; velocity along, across in ``scale_m_s``): a
diagonal entry as its logarithm, an off-diagonal one as a multiple of its column's diagonal entry."""
COV_TRIL = ((0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2), (3, 0), (3, 1), (3, 2), (3, 3))
"""``(row, column)`` of ``L`` for each output of the covariance head."""
COV_LOG_DIAG_CLIP = 6.0
"""The head's log-diagonal is clipped to +-6 (a factor of 400 either way of the unit) and its off-diagonal
multiples to +-:data:`COV_OFFDIAG_CLIP`; with the floor :data:`COV_FLOOR` that bounds the covariance's condition
number (about 1e14 in the head's units, times ``(scale_m / scale_m_s)^2`` at most in m and m/s), so numpy's
Cholesky factorises it whatever the weights (tested on extreme outputs; the head reads a tanh layer, so its outputs
are bounded anyway)."""
COV_OFFDIAG_CLIP = 10.0
COV_FLOOR = 1e-6
"""Added to the covariance's diagonal in units squared: standard deviations of at least 0.001 unit (0.3 m and
0.03 m/s at the default units), far below any error the head describes."""


@numba.njit(cache=True, nogil=True)
def _head_covariance(raw, frame, scale_m, scale_m_s, out):
    """:func:`head_covariance` into ``out (n, 4, 4)``, row by row (compiled: a few hundred flops a look)."""
    L = np.zeros((4, 4))
    A = np.zeros((4, 4))
    u = np.array([scale_m, scale_m, scale_m_s, scale_m_s])
    for r in range(raw.shape[0]):
        L[:] = 0.0
        c = 0
        for i in range(4):          # COV_TRIL: row by row, the diagonal last in each row
            for j in range(i + 1):
                if i == j:
                    L[i, i] = math.exp(min(max(raw[r, c], -COV_LOG_DIAG_CLIP), COV_LOG_DIAG_CLIP))
                c += 1
        c = 0
        for i in range(4):
            for j in range(i + 1):
                if i != j:
                    L[i, j] = min(max(raw[r, c], -COV_OFFDIAG_CLIP), COV_OFFDIAG_CLIP) * L[j, j]
                c += 1
        ca, sa = frame[r, 0], frame[r, 1]
        for i in range(4):          # S = L L^T + floor, in the base frame and the head's units
            for j in range(i + 1):
                v = COV_FLOOR if i == j else 0.0
                for k in range(j + 1):
                    v += L[i, k] * L[j, k]
                A[i, j] = A[j, i] = v * u[i] * u[j]
        for o in (0, 2):            # rotate rows then columns: position and velocity blocks, (along, across) -> (E, N)
            for j in range(4):
                a0, a1 = A[o, j], A[o + 1, j]
                A[o, j], A[o + 1, j] = ca * a0 - sa * a1, sa * a0 + ca * a1
        for o in (0, 2):
            for i in range(4):
                a0, a1 = A[i, o], A[i, o + 1]
                A[i, o], A[i, o + 1] = ca * a0 - sa * a1, sa * a0 + ca * a1
        for i in range(4):
            out[r, i, i] = A[i, i]
            for j in range(i):
                out[r, i, j] = out[r, j, i] = 0.5 * (A[i, j] + A[j, i])


def head_covariance(raw, frame, scale_m, scale_m_s):
    """The covariance head's outputs ``raw (n, 10)`` as 4x4 covariances ``(n, 4, 4)`` of the corrected estimate in
    the world frame (m, m/s): ``L L^T + COV_FLOOR I`` (:data:`COV_TRIL`) scaled by ``(scale_m, scale_m, scale_m_s,
    scale_m_s)`` and rotated from the base frame (``frame (n, 2)``, the unit vector along the base velocity).
    Exactly symmetric and positive definite. Compiled."""
    raw = np.ascontiguousarray(raw, dtype=np.float64)
    out = np.empty((raw.shape[0], 4, 4))
    _head_covariance(raw, np.ascontiguousarray(frame, dtype=np.float64), float(scale_m), float(scale_m_s), out)
    return out


def feature_count(window_looks, fit_looks=(), q_looks=0):
    """Number of inputs for a window of ``window_looks`` looks: four per look (along, across, detected, time), the
    plot noise along and across, the speed, the base covariance's four standard deviations,
    :data:`FIT_FEATURES` per entry of ``fit_looks`` and one per look of ``q_looks`` (:func:`window_features`)."""
    return 4 * int(window_looks) + 7 + FIT_FEATURES * len(fit_looks) + int(q_looks)


FIT_FEATURES = 9
"""Inputs per quadratic fit (``fit_looks``): along a0, a1, a2, across a0, a1, a2, the rms residuals along and across,
and 1 if the fit was made (else all 0)."""
FIT_ACROSS = (3, 4, 5)
"""A fit's across coefficients among its :data:`FIT_FEATURES` (they change sign when the track is mirrored)."""
FIT_CLIP = 1e4
"""A fit's coefficients are clipped to +-1e4 (``scale_m`` per minute to the power of the term): the inputs stay
bounded however close in time its plots are."""


def check_fit_looks(fit_looks, window_looks, where):
    """``fit_looks`` as a tuple of ints, or ``ValueError`` naming ``where``: distinct, increasing, each in
    ``[4, window_looks]``, at most 8."""
    ok = (isinstance(fit_looks, (list, tuple)) and len(fit_looks) <= 8
          and all(isinstance(m, int) and not isinstance(m, bool) and 4 <= m <= window_looks for m in fit_looks)
          and all(a < b for a, b in zip(fit_looks, fit_looks[1:])))
    if not ok:
        raise ValueError(f"{where} must be a list of at most 8 increasing integers in [4, window_looks = "
                         f"{window_looks}], got {fit_looks!r}")
    return tuple(fit_looks)


Q_FLOOR_M_S2 = 1e-3
"""The base's process-noise level as an input (``q_looks``) is ``log10(max(q, 1e-3 m/s^2)) / 2``; a look without
one (before the track's start or the episode's) reads as the floor."""


def check_q_looks(q_looks, window_looks, where):
    """``q_looks`` as an int, or ``ValueError`` naming ``where``: an integer in ``[0, window_looks]``."""
    if not isinstance(q_looks, (int, np.integer)) or isinstance(q_looks, bool) or not 0 <= q_looks <= window_looks:
        raise ValueError(f"{where} must be an integer in [0, window_looks = {window_looks}], got {q_looks!r}")
    return int(q_looks)


@numba.njit(cache=True, nogil=True)
def _quadratic_fits(F, i, K, fit_looks, o):
    """The quadratic fits of row ``i`` of ``F`` (its window slots already written) into ``F[i, o:]``: for each
    ``m`` of ``fit_looks``, the least-squares fit ``y = a0 + a1 tau + a2 tau^2`` (tau in minutes, 0 at the current
    look) of the along and across residuals of the detected plots among the last ``m`` looks, solved in
    ``s = tau / span`` (span: the oldest detected plot's ``|tau|``) for its conditioning; all 0 with fewer than 4
    detected plots or a near-singular system."""
    for f in range(fit_looks.size):
        m = min(fit_looks[f], K)
        base = o + FIT_FEATURES * f
        for c in range(FIT_FEATURES):
            F[i, base + c] = 0.0
        n, span = 0, 0.0
        for j in range(m):
            if F[i, 4 * j + 2] != 0.0:
                n += 1
                span = max(span, abs(F[i, 4 * j + 3]))
        if n < 4 or not span > 0.0:
            continue
        s0 = s1 = s2 = s3 = s4 = 0.0
        ya0 = ya1 = ya2 = yc0 = yc1 = yc2 = 0.0
        for j in range(m):
            if F[i, 4 * j + 2] != 0.0:
                s = F[i, 4 * j + 3] / span
                ss = s * s
                s0 += 1.0
                s1 += s
                s2 += ss
                s3 += ss * s
                s4 += ss * ss
                ya, yc = F[i, 4 * j], F[i, 4 * j + 1]
                ya0 += ya
                ya1 += ya * s
                ya2 += ya * ss
                yc0 += yc
                yc1 += yc * s
                yc2 += yc * ss
        # the symmetric 3x3 moment matrix [[s0, s1, s2], [s1, s2, s3], [s2, s3, s4]]: its inverse by cofactors
        c00, c01, c02 = s2 * s4 - s3 * s3, s2 * s3 - s1 * s4, s1 * s3 - s2 * s2
        c11, c12, c22 = s0 * s4 - s2 * s2, s1 * s2 - s0 * s3, s0 * s2 - s1 * s1
        det = s0 * c00 + s1 * c01 + s2 * c02
        if not det > 1e-9 * s0 * s0 * s0:        # s in [-1, 0]: a relative threshold
            continue
        inv = 1.0 / det
        ra = rc = 0.0
        for side in range(2):
            y0, y1, y2 = (ya0, ya1, ya2) if side == 0 else (yc0, yc1, yc2)
            b0 = (c00 * y0 + c01 * y1 + c02 * y2) * inv
            b1 = (c01 * y0 + c11 * y1 + c12 * y2) * inv
            b2 = (c02 * y0 + c12 * y1 + c22 * y2) * inv
            r2 = 0.0
            for j in range(m):
                if F[i, 4 * j + 2] != 0.0:
                    s = F[i, 4 * j + 3] / span
                    e = F[i, 4 * j + side] - (b0 + s * (b1 + s * b2))
                    r2 += e * e
            k = base + 3 * side
            F[i, k] = min(max(b0, -FIT_CLIP), FIT_CLIP)
            F[i, k + 1] = min(max(b1 / span, -FIT_CLIP), FIT_CLIP)
            F[i, k + 2] = min(max(b2 / (span * span), -FIT_CLIP), FIT_CLIP)
            if side == 0:
                ra = math.sqrt(r2 / (n - 3))
            else:
                rc = math.sqrt(r2 / (n - 3))
        F[i, base + 6], F[i, base + 7], F[i, base + 8] = ra, rc, 1.0


@numba.njit(cache=True, nogil=True)
def _rotated(c00, c01, c11, ca, sa):
    """Standard deviations along and across ``(ca, sa)`` of the 2x2 covariance ``[[c00, c01], [c01, c11]]``."""
    a = c00 * (ca * ca) + 2 * c01 * ca * sa + c11 * (sa * sa)
    c = c00 * (sa * sa) - 2 * c01 * ca * sa + c11 * (ca * ca)
    return math.sqrt(max(a, 0.0)), math.sqrt(max(c, 0.0))


@numba.njit(cache=True, nogil=True)
def _features(t_s, z_m, R_m2, detected, x, P, rows, looks, K, scale_m, fit_looks, q, q_looks, F, frame):
    """:func:`window_features` of look ``looks[i]`` of row ``rows[i]`` into ``F[i]`` and its frame into ``frame[i]``."""
    for i in range(rows.size):
        b, k = rows[i], looks[i]
        vx, vy = x[b, k, 2], x[b, k, 3]
        sp = math.hypot(vx, vy)
        if sp > 1e-3:
            ca, sa = vx / sp, vy / sp
        else:                       # no direction to speak of: east
            ca, sa = 1.0, 0.0
        frame[i, 0], frame[i, 1] = ca, sa
        r00 = r01 = r11 = 0.0
        have = False
        for j in range(K):
            kk = k - j
            det = kk >= 0 and detected[b, max(kk, 0)]
            if det and not have:    # R of the latest detected plot in the window
                r00, r01, r11 = R_m2[b, kk, 0, 0], R_m2[b, kk, 0, 1], R_m2[b, kk, 1, 1]
                have = True
            tau = t_s[b, kk] - t_s[b, k] if kk >= 0 else 0.0
            al = cr = 0.0
            if det:
                dx = z_m[b, kk, 0] - (x[b, k, 0] + tau * vx)
                dy = z_m[b, kk, 1] - (x[b, k, 1] + tau * vy)
                al = min(max((dx * ca + dy * sa) / scale_m, -RESIDUAL_CLIP), RESIDUAL_CLIP)
                cr = min(max((-dx * sa + dy * ca) / scale_m, -RESIDUAL_CLIP), RESIDUAL_CLIP)
            F[i, 4 * j], F[i, 4 * j + 1], F[i, 4 * j + 2], F[i, 4 * j + 3] = al, cr, 1.0 if det else 0.0, tau / 60.0
        m = 4 * K
        ra, rc = _rotated(r00, r01, r11, ca, sa)
        pa, pc = _rotated(P[b, k, 0, 0], P[b, k, 0, 1], P[b, k, 1, 1], ca, sa)
        va, vc = _rotated(P[b, k, 2, 2], P[b, k, 2, 3], P[b, k, 3, 3], ca, sa)
        F[i, m], F[i, m + 1], F[i, m + 2] = math.log1p(ra) / 5, math.log1p(rc) / 5, sp / scale_m
        F[i, m + 3], F[i, m + 4] = math.log1p(pa) / 5, math.log1p(pc) / 5
        F[i, m + 5], F[i, m + 6] = math.log1p(va) / 5, math.log1p(vc) / 5
        if fit_looks.size:
            _quadratic_fits(F, i, K, fit_looks, m + 7)
        o = m + 7 + FIT_FEATURES * fit_looks.size
        for j in range(q_looks):    # the base's q at the last q_looks looks (the floor where it has none)
            v = q[b, k - j] if k - j >= 0 else np.nan
            F[i, o + j] = math.log10(v if v > Q_FLOOR_M_S2 else Q_FLOOR_M_S2) / 2.0


def look_features(t_s, z_m, R_m2, detected, x, P, rows, looks, window_looks, scale_m, fit_looks=(), q=None,
                  q_looks=0):
    """The correction's inputs at the looks ``(rows[i], looks[i])`` only (module docstring; arguments as
    :func:`window_features`): ``(F (n, feature_count), frame (n, 2))``, ``frame`` the unit vector along the base
    velocity. Compiled; the base estimate must be finite at those looks. ``ValueError`` for a ``q_looks`` outside
    ``[0, window_looks]`` (the env wrapper keeps no more looks) or, with ``q_looks``, a ``q`` not of ``t_s``'s shape
    (the compiled code does not check its indices)."""
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    looks = np.ascontiguousarray(looks, dtype=np.int64)
    q_looks = check_q_looks(q_looks, window_looks, "q_looks")
    if not q_looks:
        q = np.full((1, 1), np.nan)         # not read
    elif q is None:
        raise ValueError(f"q_looks = {q_looks} needs the base's q (B, L), got None")
    else:
        q = np.ascontiguousarray(q, dtype=np.float64)
        if q.shape != np.shape(t_s):
            raise ValueError(f"q must have t_s's shape (B, L) = {np.shape(t_s)} with q_looks = {q_looks}, got "
                             f"{q.shape}")
    F = np.empty((rows.size, feature_count(window_looks, fit_looks, q_looks)))
    frame = np.empty((rows.size, 2))
    _features(np.ascontiguousarray(t_s, dtype=np.float64), np.ascontiguousarray(z_m, dtype=np.float64),
              np.ascontiguousarray(R_m2, dtype=np.float64), np.ascontiguousarray(detected, dtype=np.bool_),
              np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(P, dtype=np.float64), rows, looks,
              int(window_looks), float(scale_m), np.asarray(fit_looks, dtype=np.int64).reshape(-1), q, int(q_looks),
              F, frame)
    return F, frame


def window_features(t_s, z_m, R_m2, detected, x, P, window_looks, scale_m, fit_looks=(), q=None, q_looks=0):
    """The correction's inputs at every look.

    Args:
        t_s, z_m, R_m2, detected: the episodes' looks (B, L), converted plots (B, L, 2), their R (B, L, 2, 2) and
            detection flags (B, L), as :func:`radar_env.sim.episode.stack_episodes` holds them.
        x, P: the base tracker's estimates (B, L, 4) and covariances (B, L, 4, 4) (NaN where it has none).
        window_looks: how many looks, the current one included. scale_m: the length unit of the inputs.
        fit_looks: the window lengths (looks) of the quadratic fits appended to the inputs (none by default).
        q, q_looks: the base's process-noise level at every look (B, L, ``t_s``'s shape) in m/s^2 (NaN where it
            has none), and how many of its last looks are appended to the inputs: an integer in ``[0,
            window_looks]`` (0, none, by default; ``q`` is then not read). Else ``ValueError``.
    Returns:
        ``(F (B, L, feature_count), ca (B, L), sa (B, L))``: the inputs and the frame (unit vector along the base
        velocity; east below 1 mm/s). Slot j (0 = the current look) holds the plot of look ``k - j`` as its residual
        from the base's straight line ``x[k, :2] + (t[k-j] - t[k]) x[k, 2:]``, along and across, in ``scale_m``
        (0 when not detected or before the episode; clipped to +-:data:`RESIDUAL_CLIP`), the detection flag and
        ``(t[k-j] - t[k]) / 60 s`` (0 before the episode). Then log(1 + sd / 1 m) / 5 along and across of the R of
        the latest detected plot in the window (0 if none), the speed in ``scale_m`` per second, and
        log(1 + sd) / 5 of the base's position (m) and velocity (m/s) covariance along and across. Then, for each
        ``m`` of ``fit_looks``, :data:`FIT_FEATURES` inputs: the least-squares quadratic ``a0 + a1 tau + a2 tau^2``
        (tau in minutes) through the along and then the across residuals of the detected plots among the last ``m``
        looks (a0, a1, a2 each, clipped to +-:data:`FIT_CLIP`), the rms residuals along and across, and 1 (all 0
        with fewer than 4 detected plots): what a turn or a speed change has done to the plots lately, as a
        curvature the network need not find by itself. Then ``log10(max(q, 1e-3)) / 2`` of the base's q at each of
        the last ``q_looks`` looks, the current one first (the floor before the track's start): what the base
        itself made of the past plots. NaN where the base estimate is not finite.
    """
    B, L = t_s.shape
    rows, looks = np.nonzero(np.isfinite(x).all(-1))
    f, frame = look_features(t_s, z_m, R_m2, detected, x, P, rows, looks, window_looks, scale_m, fit_looks, q,
                             q_looks)
    F = np.full((B, L, f.shape[1]), np.nan)
    ca, sa = np.full((B, L), np.nan), np.full((B, L), np.nan)
    F[rows, looks], ca[rows, looks], sa[rows, looks] = f, frame[:, 0], frame[:, 1]
    return F, ca, sa


def network_shapes(arch):
    """``{name: shape}`` of the weights for ``arch`` (``input_size``, ``layers``: tanh widths)."""
    sizes = [int(arch["input_size"])] + [int(h) for h in arch["layers"]]
    shapes = {}
    for i in range(len(sizes) - 1):
        shapes[f"layer.{i}.weight"] = (sizes[i + 1], sizes[i])
        shapes[f"layer.{i}.bias"] = (sizes[i + 1],)
    shapes["out.weight"], shapes["out.bias"] = (2, sizes[-1]), (2,)
    if arch.get("covariance"):
        shapes["cov.weight"], shapes["cov.bias"] = (COV_OUTPUTS, sizes[-1]), (COV_OUTPUTS,)
    return shapes


FORWARD_CHUNK = 1024
"""Rows the network takes at a time: its layers' outputs then stay in the cache (all the looks of 200 episodes at once
took 1.8x the time); a row's output does not depend on the chunk it is in."""


def network_forward(w, n_layers, F, covariance=False, dtype=np.float64, mean=None, sd=None):
    """The network on inputs ``F (n, input_size)`` (weights from :func:`layer_weights`): ``(n, 2)``; with
    ``covariance``, ``((n, 2), (n, 10))``, the covariance head's outputs too. In chunks of :data:`FORWARD_CHUNK`
    rows. ``mean``, ``sd``: a network trained on standardised inputs (an ensemble's member) reads ``(F - mean) / sd``
    (computed in float64). ``dtype`` float32: the layers in float32 (``w`` given in float32; about 2x faster), on
    standardised inputs only: a first layer with the standardisation folded in sums terms of thousands that cancel,
    which float32 would round to centimetres. The outputs are float64 either way."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    if covariance:      # both outputs in one pass (each output's sum is the same, in the same order)
        wo, bo = np.vstack([w["out.weight"], w["cov.weight"]]), np.concatenate([w["out.bias"], w["cov.bias"]])
    else:
        wo, bo = w["out.weight"], w["out.bias"]
    z = np.empty((F.shape[0], bo.size))
    for i in range(0, F.shape[0], FORWARD_CHUNK):
        y = F[i:i + FORWARD_CHUNK]
        if mean is not None:
            y = (y - mean) / sd
        for k in range(n_layers):
            y = linear(y, w[f"layer.{k}.weight"], dtype)
            y += w[f"layer.{k}.bias"]
            np.tanh(y, out=y)               # in place: the same numbers without two temporaries a layer
        z[i:i + FORWARD_CHUNK] = linear(y, wo, dtype) + bo
    return (z[:, :2], z[:, 2:]) if covariance else z


class WindowCorrection:
    """A loaded window correction over its base tracker, ready to run.

    Args:
        weights: ``{name: array}`` (:func:`network_shapes`; an ensemble's, version 2, ``member{j}.`` before each name
            and the members' standardisations, :data:`ENSEMBLE_VERSION`). config: the ``policy.json`` dict. base: the
            loaded base tracker, as :func:`agents.policies.loading.load_policy` returns it (a q-policy ``choose_q``
            or a tracker with ``run``). base_cfg: its env config.

    An ensemble (``config["members"]`` networks) moves the base estimate by the mean of its members' moves; its
    covariance (with covariance heads) is the mixture's: the mean of the heads' covariances plus the spread of the
    members' moves about their mean (position block), times ``config["covariance_scale"]`` (1 when absent). With one
    member and no scale the numbers are that member's.
    """

    is_tracker = True
    """It runs episodes itself (:meth:`run`)."""
    is_correction = True
    """It corrects a base tracker's output (kind ``window_correction``)."""

    def __init__(self, weights, config, base, base_cfg):
        self.config, self.base, self.cfg = config, base, base_cfg
        self.arch = config["architecture"]
        self.window_looks = int(config["window_looks"])
        self.fit_looks = tuple(config.get("fit_looks", ()))
        self.q_looks = check_q_looks(config.get("q_looks", 0), self.window_looks, "q_looks")
        self.scale_m = float(config["scale_m"])
        self.n_layers = len(self.arch["layers"])
        n = feature_count(self.window_looks, self.fit_looks, self.q_looks)
        if self.arch.get("input_size") != n:        # the loader says which file; one built by hand hears it here
            raise ValueError(f"architecture.input_size must be {n} (window_looks {self.window_looks}, fit_looks "
                             f"{list(self.fit_looks)}, q_looks {self.q_looks}), got {self.arch.get('input_size')!r}")
        self.has_covariance = bool(self.arch.get("covariance", False))
        self.scale_m_s = float(config.get("scale_m_s", 0.0))
        ensemble, _, self.precision, self.base_precision, self.covariance_scale = ensemble_fields(config)
        self.dtype = np.dtype(self.precision).type
        self.members = [SimpleNamespace(w=layer_weights(m["weights"], self.dtype), mean=m["mean"], sd=m["sd"])
                        for m in ensemble_members(weights, config)]
        self.w = None if ensemble else self.members[0].w
        """A single correction's network (raw inputs, float64; None for an ensemble: see :attr:`members`)."""
        if self.base_precision != "float64":
            if not callable(getattr(base, "with_precision", None)):
                raise ValueError(f"base_precision {self.base_precision!r} needs a recurrent q-policy base (its GRU "
                                 f"runs in that precision), got a {type(base).__name__}")
            self.base = base.with_precision(self.base_precision)

    def base_run(self, episodes, name="base"):
        """The base tracker on ``episodes`` (a :class:`baselines.trackers.TrackRun`), as the evaluation runs it."""
        if getattr(self.base, "is_tracker", False):
            return self.base.run(episodes, name)
        from baselines.trackers import run_q_policy
        return run_q_policy(episodes, self.base, name, self.cfg)

    def corrected_at(self, batch, x, P, rows, looks, q=None):
        """The correction at the looks ``(rows[i], looks[i])`` (the base estimate finite there): ``(d (n, 2), C)``,
        ``d`` the move in m, east and north, and ``C (n, 4, 4)`` the corrected estimate's covariance from the
        covariance head (:func:`head_covariance`), or ``None`` without one. ``q``: the base's q (B, L), read only
        with ``q_looks``."""
        F, frame = look_features(batch.t_s, batch.z_m, batch.R_m2, batch.detected, x, P, rows, looks,
                                 self.window_looks, self.scale_m, self.fit_looks, q, self.q_looks)
        ca, sa = frame[:, 0], frame[:, 1]
        ds, Cs = [], []
        for m in self.members:
            out = network_forward(m.w, self.n_layers, F, self.has_covariance, self.dtype, m.mean, m.sd)
            o, raw = (out[0], out[1]) if self.has_covariance else (out, None)
            o = o * self.scale_m
            ds.append(np.stack([o[:, 0] * ca - o[:, 1] * sa, o[:, 0] * sa + o[:, 1] * ca], -1))
            Cs.append(None if raw is None else head_covariance(raw, frame, self.scale_m, self.scale_m_s))
        if len(ds) == 1:
            d, C = ds[0], Cs[0]
        else:
            d = np.mean(ds, 0)
            C = None if Cs[0] is None else np.mean(Cs, 0)
            if C is not None:
                e = np.stack(ds) - d                       # the members' moves about their mean: the mixture's spread
                C[:, :2, :2] += np.einsum("mni,mnj->nij", e, e) / len(ds)
        if C is not None and self.covariance_scale != 1.0:
            C *= self.covariance_scale
        return d, C

    def correct(self, batch, run, name):
        """``run`` (the base tracker's :class:`baselines.trackers.TrackRun` on ``batch``) with its positions moved
        by the correction from its first track look on, wherever its estimate is finite (a non-finite estimate
        stays as it is: a failure is reported, never hidden); ``P``, q and the extra series are the base's, plus
        ``correction_m``, the length of the move (m) at each corrected look. With a covariance head, ``P`` at the
        corrected looks is the head's (the base's elsewhere)."""
        from baselines.trackers import TrackRun
        x, P = run.x.copy(), run.P
        after = np.arange(x.shape[1])[None, :] >= np.asarray(run.start_index)[:, None]
        rows, looks = np.nonzero(after & np.isfinite(run.x).all(-1))
        d, C = self.corrected_at(batch, run.x, run.P, rows, looks, run.q_m_s2)
        x[rows, looks, :2] += d
        if C is not None:
            P = run.P.copy()
            P[rows, looks] = C
        corr = np.full(x.shape[:2], np.nan)
        corr[rows, looks] = np.hypot(d[:, 0], d[:, 1])
        extra = dict(run.extra)
        extra["correction_m"] = corr
        return TrackRun(name, x, P, run.start_index, run.q_m_s2, run.declared, extra)

    def run(self, episodes, name="policy_window"):
        """The base tracker on ``episodes`` from the common track start, then :meth:`correct`."""
        from radar_env.sim.episode import stack_fields
        episodes = list(episodes)
        looks = SimpleNamespace(**stack_fields(episodes, ("t_s", "z_m", "R_m2", "detected")))   # what it reads
        return self.correct(looks, self.base_run(episodes), name)


def ensemble_fields(config):
    """The ensemble fields of a correction's ``policy.json`` dict, checked: ``(ensemble, members, precision,
    base_precision, covariance_scale)``; a single correction (version 1) is ``(False, 1, "float64", "float64", 1.0)``
    and may not carry them. ``ValueError`` naming the field otherwise (the loader adds the file)."""
    version = config.get("version", VERSION)
    if version not in (VERSION, ENSEMBLE_VERSION) or isinstance(version, bool):
        raise ValueError(f"field 'version' must be {VERSION} or {ENSEMBLE_VERSION} (an ensemble), got {version!r}")
    if version == VERSION:
        for field in ("precision", "base_precision", "members", "covariance_scale"):
            if field in config:
                raise ValueError(f"field {field!r} belongs to an ensemble's folder (version {ENSEMBLE_VERSION}); a "
                                 f"single correction (version {VERSION}) runs in float64")
        return False, 1, "float64", "float64", 1.0
    m = config.get("members")
    if not isinstance(m, int) or isinstance(m, bool) or not 1 <= m <= MAX_MEMBERS:
        raise ValueError(f"field 'members' must be an integer in [1, {MAX_MEMBERS}], got {m!r}")
    for field in ("precision", "base_precision"):
        if config.get(field) not in PRECISIONS:
            raise ValueError(f"field {field!r} must be one of {list(PRECISIONS)}, got {config.get(field)!r}"[:300])
    c = config.get("covariance_scale", 1.0)
    lo, hi = COVARIANCE_SCALE_RANGE
    if not isinstance(c, (int, float)) or isinstance(c, bool) or not lo <= c <= hi:
        raise ValueError(f"field 'covariance_scale' must be a number in [{lo:g}, {hi:g}] (the reported covariance's "
                         f"factor), got {c!r}"[:300])
    arch = config.get("architecture")
    if c != 1.0 and not (isinstance(arch, dict) and arch.get("covariance") is True):
        raise ValueError("field 'covariance_scale' needs a covariance head (architecture.covariance true)")
    return True, m, config["precision"], config["base_precision"], float(c)


def ensemble_members(weights, config):
    """The networks of a correction's weights: ``[{"weights", "mean", "sd"}]``, one per member (``config``'s
    ``members``, version 2: ``member{j}.`` names and standardisations) or the one network of a version-1 correction
    (its standardisation folded in: ``mean`` and ``sd`` None)."""
    if config.get("version", VERSION) != ENSEMBLE_VERSION:
        return [{"weights": weights, "mean": None, "sd": None}]
    out = []
    for j in range(int(config["members"])):
        p = f"member{j}."
        out.append({"weights": {k[len(p):]: v for k, v in weights.items()
                                if k.startswith(p) and k[len(p):] not in ("input_mean", "input_sd")},
                    "mean": np.asarray(weights[p + "input_mean"], np.float64),
                    "sd": np.asarray(weights[p + "input_sd"], np.float64)})
    return out


def save_window_ensemble(directory, members, config, env_kwargs):
    """Write an ensemble's folder (version :data:`ENSEMBLE_VERSION`): ``members`` a list of ``(weights, mean, sd)``,
    each network as trained on inputs standardised by ``mean`` and ``sd`` (:func:`network_shapes` names), all of
    ``config``'s architecture; ``config`` as a single correction's plus ``precision`` and ``base_precision``
    (``members`` is set here). Returns the ``.npz`` path."""
    from agents.policies.layout import write_weights_folder
    w = {}
    for j, (weights, mean, sd) in enumerate(members):
        w.update({f"member{j}.{k}": v for k, v in weights.items()})
        w[f"member{j}.input_mean"], w[f"member{j}.input_sd"] = mean, sd
    return write_weights_folder(directory, "window_correction", FORMAT, ENSEMBLE_VERSION, w,
                                {**config, "members": len(members)}, env_kwargs)


def save_window_correction(directory, weights, config, env_kwargs):
    """Write a correction folder (``policy.npz``, ``policy.json``, ``env_config.json``); returns the ``.npz`` path."""
    from agents.policies.layout import write_weights_folder
    return write_weights_folder(directory, "window_correction", FORMAT, VERSION, weights, config, env_kwargs)


def is_window_correction(path):
    """Whether ``path`` (a ``policy.npz`` or its folder) is a window correction (its ``policy.json`` says so)."""
    from agents.policies.checks import manifest_format
    return manifest_format(path) == FORMAT


def _positive_int(meta_file, value, field, hi):
    if not isinstance(value, int) or isinstance(value, bool) or not 0 < value <= hi:
        raise ValueError(f"{meta_file}: field {field!r} must be an integer in [1, {hi}], got {value!r}")
    return value


def load_window_correction(path, load_base):
    """A :class:`WindowCorrection` from its folder or ``policy.npz`` (no pickle), every file checked
    (:mod:`agents.policies.checks`) before anything runs. Its base (``policy.json``'s ``base``: a bundled name, else
    a folder relative to the correction's) must be a q-policy or a learned IMM whose ``policy.json`` names its kind;
    ``load_base(file)`` loads that folder's weights file (:func:`agents.policies.loading.load_policy` passes itself).
    ``ValueError`` (one line, naming the file and the field) for a missing or malformed file or base."""
    from agents.policies import checks
    from agents.policies.layout import BUNDLED_LEARNED, IMM_KINDS, Q_POLICY_KINDS, weights_file
    d, config, env_file, npz = checks.open_weights_folder(path, "a window correction", FORMAT,
                                                          (VERSION, ENSEMBLE_VERSION))
    meta_file = d / "policy.json"
    try:
        ensemble, members, _, base_precision, _ = ensemble_fields(config)
    except ValueError as e:
        raise ValueError(f"{meta_file}: {e}") from None
    window = _positive_int(meta_file, config.get("window_looks"), "window_looks", 64)
    checks.check_finite_numbers(meta_file, config.get("scale_m"), "scale_m")
    if not config["scale_m"] > 0:
        raise ValueError(f"{meta_file}: field 'scale_m' must be > 0 (m), got {config['scale_m']!r}")
    arch = config.get("architecture")
    layers = arch.get("layers") if isinstance(arch, dict) else None
    if not isinstance(layers, list) or not 1 <= len(layers) <= 4:
        raise ValueError(f"{meta_file}: field 'architecture.layers' must be a list of 1-4 widths, got {layers!r}")
    for i, h in enumerate(layers):
        _positive_int(meta_file, h, f"architecture.layers[{i}]", 1024)
    fits = check_fit_looks(config.get("fit_looks", []), window, f"{meta_file}: field 'fit_looks'")
    q_looks = check_q_looks(config.get("q_looks", 0), window, f"{meta_file}: field 'q_looks'")
    if arch.get("input_size") != feature_count(window, fits, q_looks):
        raise ValueError(f"{meta_file}: field 'architecture.input_size' must be {feature_count(window, fits, q_looks)}"
                         f" for window_looks {window}, fit_looks {list(fits)} and q_looks {q_looks}, got "
                         f"{arch.get('input_size')!r}")
    cov = arch.get("covariance", False)
    if not isinstance(cov, bool):
        raise ValueError(f"{meta_file}: field 'architecture.covariance' must be true or false, got {cov!r}")
    if cov:
        checks.check_finite_numbers(meta_file, config.get("scale_m_s"), "scale_m_s")
        if not config["scale_m_s"] > 0:
            raise ValueError(f"{meta_file}: field 'scale_m_s' must be > 0 (m/s) with a covariance head, got "
                             f"{config['scale_m_s']!r}")
    base = config.get("base")
    if not isinstance(base, str) or not base:
        raise ValueError(f"{meta_file}: field 'base' must name the base tracker (a bundled name such as "
                         f"'policy_bp_prior', or a folder relative to {d}), got {base!r}")
    shapes = network_shapes(arch)
    if ensemble:
        n_in = arch["input_size"]
        shapes = {f"member{j}.{k}": v for j in range(members)
                  for k, v in {**shapes, "input_mean": (n_in,), "input_sd": (n_in,)}.items()}
    weights = checks.read_npz(npz)
    checks.check_weights(npz, weights, shapes)
    if ensemble:
        for j in range(members):
            if not (weights[f"member{j}.input_sd"] > 0).all():
                raise ValueError(f"{npz}: member{j}.input_sd must be positive (a standard deviation)")
    checks.check_env_config(env_file)
    folder = BUNDLED_LEARNED[base] if base in BUNDLED_LEARNED else d / base
    try:
        if not (folder / "policy.json").is_file():
            raise ValueError(f"{folder}: no policy.json naming the base tracker's kind (a bundled name is one of "
                             f"{', '.join(BUNDLED_LEARNED)})")
        kind = checks.read_json_object(folder / "policy.json", "a learned tracker's policy.json").get("kind")
        if kind not in Q_POLICY_KINDS + IMM_KINDS:
            raise ValueError(f"{folder}: kind {kind!r}; a base must be a q-policy or a learned IMM "
                             f"({', '.join(Q_POLICY_KINDS + IMM_KINDS)})")
    except ValueError as e:
        raise ValueError(f"{meta_file}: field 'base' ({base!r}): {e}"[:400]) from None
    if q_looks and kind not in Q_POLICY_KINDS:      # whole (the base's own errors are cut)
        raise ValueError(f"{meta_file}: field 'base' ({base!r}): {folder}: kind {kind!r} has no q; q_looks {q_looks} "
                         f"needs a q-policy base ({', '.join(Q_POLICY_KINDS)})")
    if base_precision != "float64" and kind != "gru_q_policy":
        raise ValueError(f"{meta_file}: field 'base_precision' {base_precision!r} needs a recurrent "
                         f"q-policy base (kind 'gru_q_policy'), got kind {kind!r}")
    try:
        policy, cfg = load_base(weights_file(folder, kind))
    except ValueError as e:
        raise ValueError(f"{meta_file}: field 'base' ({base!r}): {e}"[:400]) from None
    return WindowCorrection(weights, config, policy, cfg)


class CorrectedEstimate(gym.Wrapper):
    """A Gymnasium wrapper of a single ``RadarTrack-v0`` env that adds the window correction's estimate to ``info``.

    The agent acting in the env is the correction's base (the correction has no action: the base's choices drive the
    filter, as in the evaluation). After every ``step``, ``info["corrected_estimate"]`` is the env's
    ``info["estimate"]`` with its position moved by the correction, computed from the plots of the looks up to the
    current one (``env.unwrapped.episode()``, read up to the current look only: causal) and the env's estimate and
    covariance; ``info["corrected_covariance"]`` its covariance (the covariance head's, else the env's). After
    ``reset`` (the track start's look, which the evaluation does not score or correct) they are the env's. The same
    numbers as :meth:`WindowCorrection.run` on the same episode when the agent is the base
    (tests/test_window_correction.py).

    It is stateful: with ``q_looks`` the correction reads the base's q at the last looks, which the episode does not
    hold, so the wrapper keeps the history of ``info["q_m_s2"]`` since the last ``reset``. It must therefore see
    every ``reset`` and ``step`` of the env (a step taken on the inner env leaves its look without q: read as the
    floor, :data:`Q_FLOOR_M_S2`, and the numbers are no longer the evaluation's).

    Args:
        env: a single ``RadarTrack-v0`` env (or a wrapper of one). correction: a :class:`WindowCorrection` (e.g.
            ``load_learned("policy_window").policy``).
    """

    def __init__(self, env, correction):
        if not isinstance(correction, WindowCorrection):
            raise ValueError(f"correction must be a WindowCorrection (load_learned(...).policy of kind "
                             f"window_correction), got {type(correction).__name__}")
        super().__init__(env)
        self.correction = correction
        self._q = {}                # look index -> the base's q there (q_looks: the correction reads it)

    def _corrected(self, info):
        ep = self.env.unwrapped.episode()
        k = int(np.searchsorted(ep["t_s"], info["time_s"]))      # the current look (times strictly increase)
        lo = max(0, k - self.correction.window_looks + 1)
        looks = SimpleNamespace(**{f: ep[f][None, lo:k + 1] for f in ("t_s", "z_m", "R_m2", "detected")})
        n = k + 1 - lo
        self._q[k] = float(info["q_m_s2"])
        q = np.array([[self._q.get(j, np.nan) for j in range(lo, k + 1)]])
        x = np.broadcast_to(np.asarray(info["estimate"], np.float64), (1, n, 4))
        P = np.broadcast_to(np.asarray(info["covariance"], np.float64), (1, n, 4, 4))
        out, cov = np.array(info["estimate"], np.float64), np.array(info["covariance"], np.float64)
        if np.isfinite(out).all():
            d, C = self.correction.corrected_at(looks, x, P, [0], [n - 1], q)      # the current look only
            out[:2] += d[0]
            if C is not None:
                cov = C[0]
        return out, cov

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        ep = self.env.unwrapped.episode()
        self._q = {int(np.searchsorted(ep["t_s"], info["time_s"])): float(info["q_m_s2"])}
        info["corrected_estimate"] = np.array(info["estimate"], np.float64)
        info["corrected_covariance"] = np.array(info["covariance"], np.float64)
        return obs, info

    def step(self, action):
        obs, reward, term, trunc, info = self.env.step(action)
        info["corrected_estimate"], info["corrected_covariance"] = self._corrected(info)
        return obs, reward, term, trunc, info
