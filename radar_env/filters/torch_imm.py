r"""The CV / CT-EKF IMM in torch: ``baselines.imm_cv_ct_runner``'s filter, differentiable in its per-look parameters.

Built from :mod:`radar_env.filters.torch_chain`'s blocks (:func:`~radar_env.filters.torch_chain.predict_cv` for the CV modes,
:func:`~radar_env.filters.torch_chain.transition`, :func:`~radar_env.filters.torch_chain.ct_omega_partials` and
:func:`~radar_env.filters.torch_chain.propagate` for the CT-EKF, :func:`~radar_env.filters.torch_chain.update` and
:func:`~radar_env.filters.torch_chain.log_likelihood` for every mode), so the project keeps one torch filter. float64;
equal to the numba kernel of ``baselines/imm_cv_ct_runner.py`` to 1e-9 on drawn episodes, with constant and with per-look
parameters (tests/test_torch_imm.py, which states the measured differences). The models and equations are that
module's docstring; per look ``j`` of a row, with this look's parameters ``q_m_s2 (M,)``, ``sig_w2`` (the turn-rate
random walk, rad^2/s^3) and ``log_Pi (M, M)`` (``Pi[i, k] = P(mode k | mode i)``)::

    a[i, k]  = log Pi[i, k] + log mu[i];   log c[k] = logsumexp_i a[i, k];   w[i, k] = exp(a[i, k] - log c[k])
    x0_k, P0_k = moment-matched mixture of the modes' 5-state (x_i, P_i) with weights w[:, k]
                 (a CV mode enters as [x, 0], blockdiag(P, sigma_omega0^2), into CT mode k of a bank as [x, w_k],
                 and keeps only its 4-state marginal)
    CT mode:  x0[4] clipped to +- min(omega_max, a_max / max(|v|, v_min));  x- = f_ct(x0),  P- = sym(J P0 J^T + Q5)
    CV mode:  x-, P- = F_cv x0, F_cv P0 F_cv^T + q^2 Gamma Gamma^T
    update:   Joseph form (a missed look: posterior = prior, log-likelihood 0); the CT mode's omega clipped again
    log mu[k] = log c[k] + l_k - logsumexp_k(log c + l)
    output:   the mu-weighted moment match of the 4-state marginals; omega = sum over CT modes of mu omega, its
              variance sum_k mu_k (var omega_k + (omega_k - omega)^2) with a CV mode's turn rate exactly 0

Log-space mode probabilities: the mixing and the mode update are logsumexps of log-probabilities and
log-likelihoods, so a 40-sigma innovation (log-likelihood ~ -800, ``exp`` of which is 0 in float64) moves the mode
probabilities without underflow (tested).

The turn-rate clip: the clipped mean is the mode of the Gaussian truncated to the interval; the covariance is left
unchanged (as the numba kernel). Where the clip is active the clipped turn rate is the bound itself: its gradient
with respect to the unclipped mean is 0, and the gradient flows into the bound instead -- nowhere when
``omega_max`` is the smaller bound, into the mode's speed estimate through ``a_max / |v|`` when the g-limit is (the
speed floor ``v_min`` cuts that below 1 m/s). Near ``omega dt = 0`` the CT entries and their derivatives are Taylor
series (:data:`radar_env.filters.torch_chain.SERIES_THETA`, :data:`radar_env.filters.torch_chain.SERIES_THETA_PARTIALS`): smooth,
finite gradients at ``omega = 0`` (gradcheck in the tests).

Layout: as torch_chain, components first inside. Modes are held grouped, the CV modes ``x_cv (4, Mcv, B)`` then the
CT modes ``x_ct (5, Mct, B)``; inputs and outputs are in the spec's mode order (``IMMConstants.is_ct``).

Data flow::

    state = start(chain_state, consts)              # every mode at the track start (torch_chain.handover / start_tracks)
    out = run(state, looks, params, consts)         # params: IMMParams (B, J, ...) -> IMMRun, batch-first outputs
    loss = torch_chain.pooled_position_mse(out.x, looks)

or one look at a time (:func:`step`, :func:`collect`) when the parameters of a look come from a network that reads
the previous look's output.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import torch

from . import torch_chain as tc

__all__ = ["IMMConstants", "IMMState", "IMMParams", "IMMRecord", "IMMRun", "start", "step", "look", "collect", "run",
           "clip_turn_rate", "switch_log_probs"]

DTYPE = tc.DTYPE


class IMMConstants(NamedTuple):
    """What the IMM holds fixed (``baselines.imm_cv_ct_runner.IMMCVCTSpec`` gives them): ``is_ct`` (M,) bool per mode in
    mode order, ``log_mu0`` (M,) initial log mode probabilities, ``sig_w0_2`` the CV augmentation's turn-rate
    variance (rad^2/s^2), the turn-rate bound ``omega_max_rad_s``, ``accel_max_m_s2`` and its speed floor
    ``min_speed_m_s``; ``entry_w`` (M,) each CT mode's entry rate (rad/s; a bank of CT modes: a CV mode mixes into
    CT mode ``k`` with the turn rate ``entry_w[k]``), empty for 0."""

    is_ct: tuple
    log_mu0: tuple
    sig_w0_2: float
    omega_max_rad_s: float
    accel_max_m_s2: float
    min_speed_m_s: float = 1.0
    entry_w: tuple = ()

    @property
    def entry_ct(self) -> tuple:
        """The CT modes' entry rates (rad/s) in the grouped order (``entry_w`` is per mode in the spec's order,
        empty: 0 for every CT mode)."""
        return tuple(float(self.entry_w[m]) if self.entry_w else 0.0 for m in range(self.M) if self.is_ct[m])

    @property
    def M(self) -> int:
        return len(self.is_ct)

    @property
    def order(self) -> torch.Tensor:
        """Mode indices in the grouped order (CV modes, then CT modes)."""
        return torch.tensor([m for m in range(self.M) if not self.is_ct[m]] + [m for m in range(self.M)
                                                                                 if self.is_ct[m]])

    @property
    def n_cv(self) -> int:
        return self.M - sum(bool(c) for c in self.is_ct)


class IMMState(NamedTuple):
    """The modes of a batch (components first, grouped): ``x_cv (4, Mcv, *b)``, ``P_cv (4, 4, Mcv, *b)``,
    ``x_ct (5, Mct, *b)``, ``P_ct (5, 5, Mct, *b)``, ``log_mu (M, *b)`` (grouped order)."""

    x_cv: torch.Tensor
    P_cv: torch.Tensor
    x_ct: torch.Tensor
    P_ct: torch.Tensor
    log_mu: torch.Tensor

    def detach(self) -> "IMMState":
        """The same state cut from the autograd graph (between chunks of truncated backpropagation)."""
        return IMMState(*(t.detach() for t in self))


class IMMParams(NamedTuple):
    """Per-look parameters, batch-first, modes in the spec's order: ``q_m_s2 (B, J, M)`` (each mode's
    acceleration noise; the CT mode's too), ``sig_w2 (B, J)`` (the CT turn-rate random walk, rad^2/s^3:
    ``var(d omega) = sig_w2 dt``), ``log_Pi (B, J, M, M)`` (log transition probabilities, rows = from). Anything
    that broadcasts to those shapes (e.g. ``(1, 1, M)`` constants)."""

    q_m_s2: torch.Tensor
    sig_w2: torch.Tensor
    log_Pi: torch.Tensor


class IMMRecord(NamedTuple):
    """One look of :func:`step` (components first, modes grouped): the combined ``x (4, B)``, ``P (4, 4, B)``,
    ``omega (B)``, ``omega_var (B)``, the NIS of the combined prediction ``nis (B)`` (None unless asked for) and
    the modes after the look (:class:`IMMState`)."""

    x: torch.Tensor
    P: torch.Tensor
    omega: torch.Tensor
    omega_var: torch.Tensor
    nis: torch.Tensor | None
    modes: IMMState


def switch_log_probs(log_stay, log_leave) -> torch.Tensor:
    """``log_Pi (..., M, M)`` of modes that stay with probability ``p_m`` and leave with ``1 - p_m`` split equally
    among the others (``baselines.imm_cv_ct_runner``'s model): from ``log_stay = log p (..., M)`` and
    ``log_leave = log(1 - p) (..., M)`` (e.g. ``-softplus(-u)``, ``-softplus(u)`` of ``u = logit p``: exact in the
    tails)."""
    M = log_stay.shape[-1]
    shape = log_stay.shape + (M,)
    return torch.where(torch.eye(M, dtype=torch.bool), log_stay[..., :, None].expand(shape),
                       (log_leave - math.log(M - 1))[..., :, None].expand(shape))


def clip_turn_rate(x5, consts: IMMConstants) -> torch.Tensor:
    """``x5 (5, *b)`` with its turn rate clipped to ``+- min(omega_max, a_max / max(|v|, v_min))`` (the mode of the
    truncated Gaussian; gradient: module docstring)."""
    speed = torch.clamp(torch.hypot(x5[2], x5[3]), min=consts.min_speed_m_s)
    bound = torch.clamp(consts.accel_max_m_s2 / speed, max=consts.omega_max_rad_s)
    w = x5[4]
    w = torch.where(w > bound, bound, torch.where(w < -bound, -bound, w))
    return torch.cat((x5[:4], w[None]))


def start(state: tc.ChainState, consts: IMMConstants) -> IMMState:
    """Every mode at the chain's state ``x (4, B)``, ``P``: the CT modes with turn rate 0 and variance
    ``sig_w0_2`` (as ``baselines.imm_cv_ct_runner.run_imm_cv_ct`` starts), mode probabilities ``exp(log_mu0)``."""
    x, P = state.x_c, state.P_c
    n_cv, n_ct = consts.n_cv, consts.M - consts.n_cv
    x_cv = x[:, None].expand((4, n_cv) + x.shape[1:]).clone()
    P_cv = P[:, :, None].expand((4, 4, n_cv) + x.shape[1:]).clone()
    x5, P5 = _augment(x[:, None], P[:, :, None], consts.sig_w0_2)
    x_ct = x5.expand((5, n_ct) + x.shape[1:]).clone()
    P_ct = P5.expand((5, 5, n_ct) + x.shape[1:]).clone()
    log_mu = torch.as_tensor(consts.log_mu0, dtype=DTYPE)[consts.order]
    log_mu = log_mu.reshape((consts.M,) + (1,) * (x.dim() - 1)).expand((consts.M,) + x.shape[1:]).clone()
    return IMMState(x_cv, P_cv, x_ct, P_ct, log_mu)


def _augment(x4, P4, sig_w0_2):
    """``[x, 0]``, ``blockdiag(P, sig_w0_2)`` of 4-state ``x4 (4, *b)``, ``P4 (4, 4, *b)``."""
    zx = torch.zeros_like(x4[:1])
    zP = torch.zeros_like(P4[:1])                      # (1, 4, *b)
    corner = torch.full_like(zx[None], sig_w0_2)        # (1, 1, *b)
    P5 = torch.cat((torch.cat((P4, zP.transpose(0, 1)), 1), torch.cat((zP, corner), 1)), 0)
    return torch.cat((x4, zx)), P5


def _mix(w, A):
    """``sum_i A[..., i, :] w[i]`` for ``A (..., Mi, B)`` and mixing weights ``w (Mi, Mk, B)``: ``(..., Mk, B)``
    (a sum over the few modes, written out: small temporaries)."""
    out = A[..., :1, :] * w[0]
    for i in range(1, w.shape[0]):
        out = out + A[..., i:i + 1, :] * w[i]
    return out


def _mixture(w, x, P):
    """Moment-matched mixtures ``(x0 (n, Mk, B), P0 (n, n, Mk, B))`` of the modes ``x (n, Mi, B)``,
    ``P (n, n, Mi, B)`` with weights ``w (Mi, Mk, B)`` (``Mk = 1``: ``w (Mi, 1, B)``): ``x0 = sum_i w_i x_i``,
    ``P0 = sum_i w_i (P_i + (x_i - x0)(x_i - x0)^T)``, computed about the first mode (``e_i = x_i - x_1``,
    ``m = sum_i w_i e_i``: ``P0 = sum_i w_i (P_i + e_i e_i^T) - m m^T``, the same algebra, the products at the
    scale of the modes' differences). Exactly symmetric if every ``P_i`` is."""
    e = x - x[:, :1]
    m = _mix(w, e)
    return x[:, :1] + m, _mix(w, P + e[:, None] * e[None]) - m[:, None] * m[None]


def _ct_predict(x0, P0, dt, q, sig_w2, G5):
    """CT-EKF prediction of ``x0 (5, Mct, B)``: the exact CT motion and its analytic Jacobian
    (baselines/imm_cv_ct_runner.py), ``Q = blockdiag(q^2 Gamma Gamma^T, sig_w2 dt)``."""
    px, py, vx, vy, w = x0.unbind(0)
    a, b, c, s = tc.ct_entries(dt, w)
    da, db = tc.ct_omega_partials(dt, w)
    xp = torch.stack((px + a * vx + b * vy, py - b * vx + a * vy, c * vx + s * vy, -s * vx + c * vy, w))
    zero, one = torch.zeros_like(w), torch.ones_like(w)
    J = torch.stack((one, zero, a, b, da * vx + db * vy,
                     zero, one, -b, a, -db * vx + da * vy,
                     zero, zero, c, s, dt * (-s * vx + c * vy),
                     zero, zero, -s, c, -dt * (c * vx + s * vy),
                     zero, zero, zero, zero, one)).view((5, 5) + w.shape)
    Q = (q * q) * G5[:, :, None] + _E44 * (sig_w2 * dt)
    return xp, tc.propagate(P0, J, Q)


_E44 = torch.zeros((5, 5, 1, 1), dtype=DTYPE)
_E44[4, 4] = 1.0


def step(state: IMMState, looks: tc.ChainLooks, j: int, q_m_s2, sig_w2, log_Pi, consts: IMMConstants,
         with_nis=False):
    """Look ``j`` of ``looks`` from ``state`` with this look's parameters, components first and modes in the
    spec's order: ``q_m_s2 (M, B)``, ``sig_w2 (B,)``, ``log_Pi (M, M, B)``. Returns ``(new_state, IMMRecord)``;
    ``with_nis``: also the NIS of the combined prediction (diagnostics; the loss does not need it)."""
    return look(state, looks.dt_s[j], looks.G[j], looks.z_m[j], looks.R_m2[j], looks.mask[j], q_m_s2, sig_w2,
                log_Pi, consts, with_nis, looks.rdot_at(j))


def look(state: IMMState, dt_s, G, z_m, R_m2, mask, q_m_s2, sig_w2, log_Pi, consts: IMMConstants, with_nis=False,
         rr=None):
    """:func:`step` on one look's tensors (``dt_s (B,)``, ``G (4, 4, B)``, ``z_m (2, B)``, ``R_m2 (2, 2, B)``,
    ``mask (B,)``, ``rr``: None or the range-rate inputs ``(rdot (B,), var (B,), site (2, B))``: column ``j`` of a
    :class:`radar_env.filters.torch_chain.ChainLooks`), for a caller that compiles it (``torch.compile``: tensors
    and constants only)."""
    o = consts.order
    return _step(state, dt_s, G, z_m, R_m2, mask, q_m_s2[o], sig_w2, log_Pi[o][:, o], consts, with_nis, rr)


def _step(state, dt, G, z, R, mask, q, sig_w2, log_Pi, consts, with_nis, rr=None):
    """:func:`step` with the parameters in the grouped order (CV modes, then CT modes)."""
    n_cv = consts.n_cv
    # ---- mixing (log space) in 5 states; a CV mode enters as [x, 0], blockdiag(P, sig_w0_2)
    a = log_Pi + state.log_mu[:, None]                         # (Mi, Mk, B)
    log_c = torch.logsumexp(a, 0)                              # (Mk, B)
    w = torch.exp(a - log_c[None])
    x4 = torch.cat((state.x_cv, state.x_ct[:4]), 1)            # every mode's 4-state part (4, M, B)
    P4 = torch.cat((state.P_cv, state.P_ct[:4, :4]), 2)
    x0, P0 = _mixture(w, x4, P4)                               # the 4-state marginals of the mixtures (4, Mk, B)
    # the CT targets' turn-rate row: modes' [P[4, :4], P[4, 4]] and turn rates; a CV mode's: 0, sig_w0_2 and,
    # into CT mode k, its entry rate (om (Mi, Mct, B): the sources' turn rates as seen by each CT target)
    B = x4.shape[-1]
    cv_row = torch.zeros((5, n_cv, B), dtype=DTYPE)
    cv_row[4] = consts.sig_w0_2
    row = torch.cat((cv_row, state.P_ct[4]), 1)                # (5, M, B)
    n_ct = consts.M - n_cv
    entry = torch.tensor(consts.entry_ct, dtype=DTYPE)[None, :, None].expand(n_cv, n_ct, B)
    om = torch.cat((entry, state.x_ct[4][:, None].expand(n_ct, n_ct, B)))
    e, e4 = x4 - x4[:, :1], om - om[:1]
    wc = w[:, n_cv:]
    we4 = wc * e4                                              # (Mi, Mct, B)
    m, m4 = _mix(wc, e), we4.sum(0)                            # (4, Mct, B), (Mct, B)
    r4 = _mix(wc, row[:4]) + _mix(we4, e) - m4 * m              # (4, Mct, B)
    r44 = _mix(wc, row[4:])[0] + (we4 * e4).sum(0) - m4 * m4    # (Mct, B)
    r = torch.cat((r4, r44[None]))
    x0_ct = clip_turn_rate(torch.cat((x0[:, n_cv:], (om[0] + m4)[None])), consts)
    P0_ct = torch.cat((torch.cat((P0[:, :, n_cv:], r[:4, None]), 1), r[None]), 0)
    # ---- mode-matched prediction
    xp_cv, Pp_cv = tc.predict_cv(x0[:, :n_cv], P0[:, :, :n_cv], dt, (q[:n_cv] * q[:n_cv]) * G[:, :, None])
    G5 = torch.nn.functional.pad(G, (0, 0, 0, 1, 0, 1))
    xp_ct, Pp_ct = _ct_predict(x0_ct, P0_ct, dt, q[n_cv:], sig_w2, G5)
    # ---- mode-matched update (a missed look: posterior = prior, log-likelihood 0)
    zb, Rb, mb = z[:, None], R[:, :, None], mask[None]
    x_cv, P_cv, nu, S, S_inv = tc.update(xp_cv, Pp_cv, zb, Rb, mb)
    ll_cv = tc.log_likelihood(nu, S, S_inv, mb)
    x_ct, P_ct, nu, S, S_inv = tc.update(xp_ct, Pp_ct, zb, Rb, mb)
    ll_ct = tc.log_likelihood(nu, S, S_inv, mb)
    if rr is not None:      # then the radial velocity, its likelihood joining the position's (as the kernel)
        rd, var, site = rr[0][None], rr[1][None], rr[2][:, None]
        x_cv, P_cv, l_r = tc.update_rdot(x_cv, P_cv, rd, var, site, mb)
        ll_cv = ll_cv + l_r
        x_ct, P_ct, l_r = tc.update_rdot(x_ct, P_ct, rd, var, site, mb)
        ll_ct = ll_ct + l_r
    x_ct = torch.where(mb > 0.0, clip_turn_rate(x_ct, consts), x_ct)
    # ---- mode probabilities
    t = torch.cat((ll_cv, ll_ct)) + log_c
    log_mu = t - torch.logsumexp(t, 0)
    # ---- combination of the 4-state marginals; the combined turn rate (a CV mode's is 0) and its variance
    mu = torch.exp(log_mu)
    x, P = _mixture(mu[:, None], torch.cat((x_cv, x_ct[:4]), 1), torch.cat((P_cv, P_ct[:4, :4]), 2))
    mu_ct = mu[n_cv:]
    om = (mu_ct * x_ct[4]).sum(0)
    om_var = (mu_ct * (P_ct[4, 4] + (x_ct[4] - om) ** 2)).sum(0) + mu[:n_cv].sum(0) * om * om
    nis = None
    if with_nis:        # NIS of the combined prediction (weights c normalised), as the numba kernel
        xc, Pc = _mixture(torch.softmax(log_c, 0)[:, None], torch.cat((xp_cv, xp_ct[:4]), 1),
                          torch.cat((Pp_cv, Pp_ct[:4, :4]), 2))
        _, _, nu, _, S_inv = tc.update(xc[:, 0], Pc[:, :, 0], z, R, mask)
        nis = tc.nis(nu, S_inv)
    new = IMMState(x_cv, P_cv, x_ct, P_ct, log_mu)
    return new, IMMRecord(x[:, 0], P[:, :, 0], om, om_var, nis, new)


class IMMRun:
    """The per-look outputs of :func:`run` / :func:`collect`, batch-first, modes in the spec's order; each stacked
    when first read.

    Attributes:
        x (B, J, 4), P (B, J, 4, 4): the combined estimate. mu, log_mu (B, J, M): mode probabilities.
        omega, omega_std (B, J): the combined turn rate (rad/s) and its standard deviation. nis (B, J): NIS of the
        combined prediction (0 where missed; only if asked for). x_modes (B, J, M, 5), P_modes (B, J, M, 5, 5):
        every mode's posterior (a CV mode's with its augmentation ``[x, 0]``, ``blockdiag(P, sig_w0_2)``).
        state: the :class:`IMMState` after the last look; records: the :class:`IMMRecord` of each look.
    """

    def __init__(self, records, state, consts: IMMConstants):
        self.records, self.state, self.consts = list(records), state, consts
        self._inverse = torch.argsort(consts.order)

    def _stack(self, f, dims):     # J x (*comp, B) -> (B, J, *comp in the order dims)
        a = torch.stack([f(r) for r in self.records])
        return a.permute(a.dim() - 1, 0, *(1 + d for d in dims))

    x = functools.cached_property(lambda self: self._stack(lambda r: r.x, (0,)))
    P = functools.cached_property(lambda self: self._stack(lambda r: r.P, (0, 1)))
    omega = functools.cached_property(lambda self: self._stack(lambda r: r.omega, ()))
    omega_std = functools.cached_property(lambda self: torch.sqrt(self._stack(lambda r: r.omega_var, ())))
    log_mu = functools.cached_property(lambda self: self._stack(lambda r: r.modes.log_mu[self._inverse], (0,)))

    @functools.cached_property
    def mu(self):
        return torch.exp(self.log_mu)

    @functools.cached_property
    def nis(self):
        if self.records[0].nis is None:
            raise ValueError("the NIS was not computed: run(..., with_nis=True)")
        return self._stack(lambda r: r.nis, ())

    def _modes5(self, r):
        m = r.modes
        x5, P5 = _augment(m.x_cv, m.P_cv, self.consts.sig_w0_2)
        return torch.cat((x5, m.x_ct), 1)[:, self._inverse], torch.cat((P5, m.P_ct), 2)[:, :, self._inverse]

    x_modes = functools.cached_property(lambda self: self._stack(lambda r: self._modes5(r)[0], (1, 0)))
    P_modes = functools.cached_property(lambda self: self._stack(lambda r: self._modes5(r)[1], (2, 0, 1)))


def collect(records, state: IMMState, consts: IMMConstants) -> IMMRun:
    """:class:`IMMRun` of the :class:`IMMRecord` of consecutive looks and the final state."""
    return IMMRun(records, state, consts)


def run(state: IMMState, looks: tc.ChainLooks, params: IMMParams, consts: IMMConstants, with_nis=False) -> IMMRun:
    """The IMM over every column of ``looks`` from ``state`` (:func:`start`, or a previous chunk's
    ``run(...).state``) with per-look ``params`` (:class:`IMMParams`; values on padding columns do not matter).
    ``with_nis``: also the NIS of the combined prediction."""
    B, J, M = looks.B, looks.J, consts.M
    if J == 0:
        raise ValueError("run: looks has no columns")
    o = consts.order
    q = torch.as_tensor(params.q_m_s2, dtype=DTYPE).expand(B, J, M)[..., o].permute(1, 2, 0).contiguous()
    sw = torch.as_tensor(params.sig_w2, dtype=DTYPE).expand(B, J).T.contiguous()
    lp = torch.as_tensor(params.log_Pi, dtype=DTYPE).expand(B, J, M, M)[..., o, :][..., o]
    lp = lp.permute(1, 2, 3, 0).contiguous()                   # (J, M, M, B), like q (J, M, B) and sw (J, B)
    records = []
    for j, (qj, swj, lpj) in enumerate(zip(q.unbind(0), sw.unbind(0), lp.unbind(0))):
        state, rec = _step(state, looks.dt_s[j], looks.G[j], looks.z_m[j], looks.R_m2[j], looks.mask[j], qj, swj,
                           lpj, consts, with_nis, looks.rdot_at(j))
        records.append(rec)
    return IMMRun(records, state, consts)
