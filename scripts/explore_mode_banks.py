"""Where the gap between the learned trackers and ``rbpf`` is, and whether a classical bank of turn modes closes it
(issue 38; docs/training.md, "Closing the gap to rbpf"). An experiment, not a tracker: numpy over rows with a Python
loop over looks (about a second per variant on 100 episodes).

    python scripts/explore_mode_banks.py [--runs 100] [--seed 900000] [--out results.json]

On ``random`` episodes of TRAINING-range seeds (default the selection suites' 900_000 + i; never the held-out seeds),
from the common track start, on the same converted plots and R as every tracker, it prints the pooled position RMSE
(m) overall and by region (maneuver / after / straight, :func:`agents.evaluation.metrics.region_masks`) of:

* ``imm_cv_ct``, ``rbpf`` and the bundled learned trackers (as the evaluation runs them);
* ``rbpf`` at small particle counts, with its wall time over imm_cv_ct's in the same process (one thread): what a
  particle filter gives at the cost cap of issue 38's learned tracker (5x imm_cv_ct);
* three mode banks, each an IMM (moment-matched mixing, log-space mode probabilities, the chain's update):
  ``linear_bank``, a CV mode and coordinated turns at fixed rates (linear 4-state KFs, the turn-rate prior of the
  random flights' laws over the grid); ``interval_bank``, the same with the switch between two modes placed inside
  the look interval (the motion of mode i for tau, then of mode j, at ``n_tau`` points); ``ekf_bank``, imm_cv_ct's
  tuned modes with its CT-EKF mode replaced by several, each entered from CV at its own turn rate (``one``: a single
  CT mode at 0 +- 7.1 deg/s, which is imm_cv_ct itself, a check of this implementation; ``tuned``: its settings
  tuned by Nelder-Mead on the default episodes, so in-sample there).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np
from scipy.linalg import expm

from agents.evaluation.metrics import errors, region_masks
from agents.evaluation.suites import draw_suite
from baselines.imm_cv_ct_runner import common_start, run_imm_cv_ct
from baselines.rbpf import DEFAULT_RBPF, run_rbpf
from baselines.registry import run_tracker
from baselines.trackers import TrackRun
from radar_env.common.units import DEG, G0_M_S2, KNOT_M_S

REGIONS = ("used", "maneuver", "after", "straight")


# ----------------------------------------------------------------------------------------------- models
def f_ct(w, dt):
    """4x4 coordinated-turn transition at rate ``w`` (rad/s, positive = clockwise), ``F_cv`` at 0."""
    th = w * dt
    if abs(th) < 1e-9:
        a, b, c, s = dt, 0.0, 1.0, 0.0
    else:
        a, b, c, s = np.sin(th) / w, (1 - np.cos(th)) / w, np.cos(th), np.sin(th)
    return np.array([[1, 0, a, b], [0, 1, -b, a], [0, 0, c, s], [0, 0, -s, c]], float)


def q_white(dt, q):
    g = np.array([[dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
    return q * q * g @ g.T


def ct_ekf_predict(x, P, dt, q, sw2):
    """CT-EKF prediction of 5-states ``x (n, 5)``, ``P (n, 5, 5)`` (imm_cv_ct's model, series near omega dt = 0)."""
    vx, vy, w = x[:, 2], x[:, 3], x[:, 4]
    th = w * dt
    small = np.abs(th) < 1e-4
    ths, ws = np.where(small, 1.0, th), np.where(small, 1.0, w)
    s, c = np.sin(th), np.cos(th)
    a = np.where(small, dt * (1 - th ** 2 / 6), np.sin(ths) / ws)
    b = np.where(small, dt * th / 2, (1 - np.cos(ths)) / ws)
    da = np.where(small, -dt * dt * th / 3, dt * dt * (ths * np.cos(ths) - np.sin(ths)) / ths ** 2)
    db = np.where(small, dt * dt * (0.5 - th ** 2 / 8), dt * dt * (ths * np.sin(ths) - 1 + np.cos(ths)) / ths ** 2)
    xn = np.stack([x[:, 0] + a * vx + b * vy, x[:, 1] - b * vx + a * vy, c * vx + s * vy, -s * vx + c * vy, w], 1)
    n = x.shape[0]
    J = np.zeros((n, 5, 5))
    J[:, 0, 0] = J[:, 1, 1] = J[:, 4, 4] = 1
    J[:, 0, 2], J[:, 0, 3], J[:, 1, 2], J[:, 1, 3] = a, b, -b, a
    J[:, 2, 2], J[:, 2, 3], J[:, 3, 2], J[:, 3, 3] = c, s, -s, c
    J[:, 0, 4], J[:, 1, 4] = da * vx + db * vy, -db * vx + da * vy
    J[:, 2, 4], J[:, 3, 4] = dt * (-s * vx + c * vy), -dt * (c * vx + s * vy)
    g = np.zeros((n, 5, 2))
    g[:, 0, 0] = g[:, 1, 1] = dt * dt / 2
    g[:, 2, 0] = g[:, 3, 1] = dt
    Q = (q ** 2)[:, None, None] * np.einsum("nik,njk->nij", g, g)
    Q[:, 4, 4] += sw2 * dt
    Pn = np.einsum("nij,njk,nlk->nil", J, P, J) + Q
    return xn, 0.5 * (Pn + np.swapaxes(Pn, 1, 2))


def _update_and_combine(batch, idx, k, xp, Pp, lc, dim):
    """Every mode's update on look ``k``'s plot, the new log mode probabilities and the combined 4-state estimate."""
    det = batch.detected[idx, k]
    z, R = batch.z_m[idx, k], batch.R_m2[idx, k]
    S = Pp[:, :, :2, :2] + R[:, None]
    Si = np.linalg.inv(S)
    nu = np.where(det[:, None, None], z[:, None, :] - xp[:, :, :2], 0.0)
    K = np.einsum("bjdk,bjke->bjde", Pp[:, :, :, :2], Si)
    H = np.zeros((2, dim))
    H[0, 0] = H[1, 1] = 1
    IKH = np.eye(dim) - np.einsum("bjde,ef->bjdf", K, H)
    Pu = np.einsum("bjde,bjef,bjgf->bjdg", IKH, Pp, IKH) + np.einsum("bjde,bef,bjgf->bjdg", K, R, K)
    Pu = 0.5 * (Pu + np.swapaxes(Pu, -1, -2))
    xu = xp + np.einsum("bjde,bje->bjd", K, nu)
    ll = -0.5 * np.einsum("bjd,bjde,bje->bj", nu, Si, nu) - 0.5 * np.log(np.linalg.det(S)) - np.log(2 * np.pi)
    lm = lc + np.where(det[:, None], ll, 0.0)
    lm -= np.logaddexp.reduce(lm, axis=1)[:, None]
    xu = np.where(det[:, None, None], xu, xp)
    Pu = np.where(det[:, None, None, None], Pu, Pp)
    mu = np.exp(lm)
    xc = np.einsum("bj,bjd->bd", mu, xu[:, :, :4])
    d = xu[:, :, :4] - xc[:, None]
    Pc = np.einsum("bj,bjde->bde", mu, Pu[:, :, :4, :4]) + np.einsum("bj,bjd,bje->bde", mu, d, d)
    return xu, Pu, lm, xc, Pc


def _run_imm(start, M, dim, predict, name):
    """An IMM over the episodes of ``start`` (:func:`common_start`): ``predict(idx, dts, x, P, log_mu) -> (xp, Pp,
    log c)`` (mixing and prediction), then the shared update."""
    batch, k0, x4, P4 = start
    B, K = batch.t_s.shape
    x = np.zeros((B, M, dim))
    x[:, :, :4] = x4[:, None]
    P = np.zeros((B, M, dim, dim))
    P[:, :, :4, :4] = P4[:, None]
    lmu = np.full((B, M), -50.0)
    lmu[:, 0] = 0.0
    lmu -= np.logaddexp.reduce(lmu, axis=1)[:, None]
    X, PP = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan)
    rows = np.arange(B)
    X[rows, k0], PP[rows, k0] = x4, P4
    for k in range(1, K):
        idx = np.flatnonzero((k >= k0 + 1) & (k < batch.n_looks))
        if not idx.size:
            continue
        dts = batch.t_s[idx, k] - batch.t_s[idx, k - 1]
        xp, Pp, lc = predict(idx, dts, x[idx], P[idx], lmu[idx])
        x[idx], P[idx], lmu[idx], X[idx, k], PP[idx, k] = _update_and_combine(batch, idx, k, xp, Pp, lc, dim)
    return TrackRun(name, X, PP, k0 + 1, np.full((B, K), np.nan))


def _log_pi(L, dt, cache):
    key = round(float(dt), 6)
    if key not in cache:
        G = np.array(L, float)
        np.fill_diagonal(G, 0.0)
        np.fill_diagonal(G, -G.sum(1))
        Pm = np.clip(expm(G * dt), 1e-300, None)
        cache[key] = np.log(Pm / Pm.sum(1, keepdims=True))
    return cache[key]


def turn_prior(omegas_deg, n=200_000, seed=0):
    """Probability of each grid rate at a turn's onset under the random flights' laws (speed U(100, 600) kt, lateral
    acceleration U(0.5, 7) g, rate capped at 20 deg/s; nearest grid rate in log, either direction)."""
    rng = np.random.default_rng(seed)
    w = np.minimum(rng.uniform(0.5, 7, n) * G0_M_S2 / (rng.uniform(100, 600, n) * KNOT_M_S), 20 * DEG) / DEG
    pos = sorted({abs(o) for o in omegas_deg})
    p = np.bincount(np.argmin(np.abs(np.log(w[:, None]) - np.log(np.array(pos)[None])), 1), minlength=len(pos)) / n
    return np.array([0.5 * p[pos.index(abs(o))] for o in omegas_deg])


def rate_generator(omegas_deg, leg_mean_s=165.0, heading_mean_deg=140.0, q_hi=False):
    """Transition rates (1/s): a leg ends at 1/leg_mean_s into a turn rate drawn from :func:`turn_prior`; a turn at
    ``w`` ends at ``|w| / heading_mean_deg``; optional high-noise CV mode entered at 1e-3/s, left at 1/20 s."""
    p_on = turn_prior(omegas_deg)
    n = len(omegas_deg)
    M = 1 + n + int(q_hi)
    L = np.zeros((M, M))
    for k in range(n):
        L[0, 1 + k] = p_on[k] / leg_mean_s
        L[1 + k, 0] = abs(omegas_deg[k]) / heading_mean_deg
    if q_hi:
        L[0, M - 1], L[M - 1, 0] = 1e-3, 1 / 20.0
    return L


def linear_bank(start, omegas_deg, q_cv_g, q_ct_g, q_hi_g=None, n_tau=0):
    """CV + fixed-rate CT modes (+ high-noise CV); ``n_tau`` > 0: switches inside the interval at ``n_tau`` points
    (``interval_bank``), else at the look (a standard IMM)."""
    om = np.array([0.0] + list(omegas_deg) + ([0.0] if q_hi_g is not None else [])) * DEG
    qs = np.array([q_cv_g] + [q_ct_g] * len(omegas_deg) + ([q_hi_g] if q_hi_g is not None else [])) * G0_M_S2
    M = len(om)
    L = rate_generator(omegas_deg, q_hi=q_hi_g is not None)
    cache, fq = {}, {}
    taus = (np.arange(max(n_tau, 1)) + 0.5) / max(n_tau, 1)

    def consts(dt):
        key = round(float(dt), 6)
        if key not in fq:
            F = np.zeros((M, M, len(taus), 4, 4))
            Q = np.zeros_like(F)
            for i in range(M):
                for j in range(M):
                    for s, f in enumerate(taus):
                        if i == j or n_tau == 0:
                            F[i, j, s], Q[i, j, s] = f_ct(om[j], dt), q_white(dt, qs[j])
                        else:
                            F2 = f_ct(om[j], (1 - f) * dt)
                            F[i, j, s] = F2 @ f_ct(om[i], f * dt)
                            Q[i, j, s] = F2 @ q_white(f * dt, qs[i]) @ F2.T + q_white((1 - f) * dt, qs[j])
            fq[key] = F, Q
        return fq[key]

    def predict(idx, dts, x, P, lm):
        lP = np.stack([_log_pi(L, d, cache) for d in dts])
        F = np.stack([consts(d)[0] for d in dts])
        Q = np.stack([consts(d)[1] for d in dts])
        a = lP + lm[:, :, None]
        lc = np.logaddexp.reduce(a, axis=1)
        w = np.exp(a - lc[:, None, :]) / len(taus)
        xs = np.einsum("bijsde,bie->bijsd", F, x)
        Ps = np.einsum("bijsde,bief,bijsgf->bijsdg", F, P, F) + Q
        xp = np.einsum("bij,bijsd->bjd", w, xs)
        d = xs - xp[:, None, :, None]
        Pp = np.einsum("bij,bijsde->bjde", w, Ps) + np.einsum("bij,bijsd,bijse->bjde", w, d, d)
        return xp, Pp, lc

    return _run_imm(start, M, 4, predict, "interval_bank" if n_tau else "linear_bank")


def ekf_bank(start, ct_modes, q_cv_g=1.12e-5, q_ct_g=0.399, walk_deg_s15=0.00119, q_hi_g=7.1,
             p_stay_cv=0.9877, p_stay_ct=0.99147, p_stay_hi=0.99743, T=5.0):
    """imm_cv_ct's tuned modes (baselines/tuned.json) with its CT-EKF mode replaced by ``ct_modes``, each
    ``(omega0_deg_s, sigma0_deg_s, share)``: a CV mode entering it starts its turn rate at ``omega0 +- sigma0``.
    The per-look stays are turned into rates at the random suite's scan period T."""
    n = len(ct_modes)
    M = n + 2
    is_ct = np.array([False] + [True] * n + [False])
    q = np.array([q_cv_g] + [q_ct_g] * n + [q_hi_g]) * G0_M_S2
    w0 = np.array([0.0] + [m[0] for m in ct_modes] + [0.0]) * DEG
    s0 = np.array([0.0] + [m[1] for m in ct_modes] + [0.0]) * DEG
    sw2 = np.where(is_ct, (walk_deg_s15 * DEG) ** 2, 0.0)
    r_cv, r_ct, r_hi = (-np.log(p) / T for p in (p_stay_cv, p_stay_ct, p_stay_hi))
    L = np.zeros((M, M))
    for k, (_, _, share) in enumerate(ct_modes):
        L[0, 1 + k] = r_cv / 2 * share
        L[1 + k, 0] = L[1 + k, M - 1] = r_ct / 2
        L[M - 1, 1 + k] = r_hi / 2 * share
    L[0, M - 1], L[M - 1, 0] = r_cv / 2, r_hi / 2
    cache = {}

    def predict(idx, dts, x, P, lm):
        lP = np.stack([_log_pi(L, d, cache) for d in dts])
        a = lP + lm[:, :, None]
        lc = np.logaddexp.reduce(a, axis=1)
        w = np.exp(a - lc[:, None, :])
        xs = np.repeat(x[:, :, None, :], M, 2)
        Ps = np.repeat(P[:, :, None], M, 2)
        for i in np.flatnonzero(~is_ct):        # a CV source enters a CT target at that target's turn-rate prior
            for j in np.flatnonzero(is_ct):
                xs[:, i, j, 4] = w0[j]
                Ps[:, i, j, 4, :] = Ps[:, i, j, :, 4] = 0.0
                Ps[:, i, j, 4, 4] = s0[j] ** 2
        x0 = np.einsum("bij,bijd->bjd", w, xs)
        dx = xs - x0[:, None]
        P0 = np.einsum("bij,bijde->bjde", w, Ps) + np.einsum("bij,bijd,bije->bjde", w, dx, dx)
        xp, Pp = np.empty_like(x0), np.empty_like(P0)
        nb = len(idx)
        for j in range(M):
            xj = x0[:, j].copy()
            if not is_ct[j]:
                xj[:, 4] = 0.0
                P0[:, j, 4, :] = P0[:, j, :, 4] = 0.0
            xp[:, j], Pp[:, j] = ct_ekf_predict(xj, P0[:, j], dts, np.full(nb, q[j]), np.full(nb, sw2[j]))
            if not is_ct[j]:
                Pp[:, j, 4, :] = Pp[:, j, :, 4] = 0.0
        return xp, Pp, lc

    return _run_imm(start, M, 5, predict, "ekf_bank")


# ----------------------------------------------------------------------------------------------- the measurement
def regions(batch, run):
    m = region_masks(batch, run.start_index)
    ep, _ = errors(batch, run)
    return {k: float(np.sqrt(np.mean(ep[m[k]] ** 2))) for k in REGIONS}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=900_000, help="base seed (training range only)")
    ap.add_argument("--out", default=None, help="write the rows as JSON here")
    args = ap.parse_args(argv)
    if not 0 <= args.seed and args.seed + args.runs <= 1_000_000:
        ap.error("--seed/--runs: training-range seeds only ([0, 1,000,000))")
    import numba
    numba.set_num_threads(1)
    eps = draw_suite("random", args.runs, seed=args.seed)
    start = common_start(eps)
    batch = start[0]
    rows = {}

    def show(name, run, extra=""):
        rows[name] = r = regions(batch, run)
        ref = rows.get("imm_cv_ct", r)["used"]
        print(f"{name:34s} {r['used']:7.1f} {r['used'] / ref:6.3f}  {r['maneuver']:7.1f} {r['after']:7.1f} "
              f"{r['straight']:7.1f}  {extra}", flush=True)

    print(f"{'tracker':34s} {'RMSE':>7s} {'/imm':>6s}  {'maneuv':>7s} {'after':>7s} {'straight':>7s}")
    show("imm_cv_ct", run_tracker("imm_cv_ct", eps))
    t = time.perf_counter()
    for _ in range(5):          # compiled and started: the filter's own time, as rbpf's below
        run_imm_cv_ct(eps, start=start)
    t_imm = (time.perf_counter() - t) / 5
    from agents.evaluation.runner import run_one
    from agents.policies.learned import load_learned
    for name in ("policy_bp", "policy_imm_bp", "policy_imm_bp_prior"):
        lt = load_learned(name)
        show(name, run_one(name, eps, lt.policy, lt.env_config))
    run_rbpf(eps[:2], replace(DEFAULT_RBPF, n_particles=16))      # compiled before it is timed
    for n in (16, 64, 256, 1024, 4096):
        t = time.perf_counter()
        run = run_rbpf(eps, replace(DEFAULT_RBPF, n_particles=n), start=start)
        show(f"rbpf N={n}", run, f"time {(time.perf_counter() - t) / t_imm:.0f}x imm_cv_ct")
    fine = list(np.geomspace(0.8, 20, 14))
    grid = [s * g for g in fine for s in (1, -1)]
    show("linear_bank (28 rates, q_ct 0.05 g)", linear_bank(start, grid, 0.005, 0.05, q_hi_g=0.5))
    coarse = [s * g for g in (1.5, 3, 6, 12, 20) for s in (1, -1)]
    show("linear_bank (10 rates, q_ct 0.1 g)", linear_bank(start, coarse, 1e-4, 0.1))
    show("interval_bank (10 rates, 2 points)", linear_bank(start, coarse, 1e-4, 0.1, n_tau=2))
    show("ekf_bank one (= imm_cv_ct)", ekf_bank(start, [(0.0, 7.1, 1.0)]))
    show("ekf_bank +-5", ekf_bank(start, [(5, 3, .5), (-5, 3, .5)]))
    show("ekf_bank +-3, +-10", ekf_bank(start, [(3, 1.5, .25), (-3, 1.5, .25), (10, 4, .25), (-10, 4, .25)]))
    show("ekf_bank +-2, +-5, +-12", ekf_bank(start, [(w, s, 1 / 6) for a, s in ((2, 1), (5, 2), (12, 4))
                                                      for w in (a, -a)]))
    # Nelder-Mead (120 evaluations) on the default 100 episodes (seeds 900_000 + i) over the three rates, the spread
    # as a fraction of the rate, q_ct, the two stays and the turn-rate walk: in-sample there, run --seed 950000 for
    # episodes it was not tuned on
    show("ekf_bank +-2.1, +-4.6, +-13.6 tuned", ekf_bank(
        start, [(w, abs(w) * 0.372, 1 / 6) for a in (2.112, 4.618, 13.558) for w in (a, -a)], q_ct_g=0.2285,
        p_stay_cv=0.9918, p_stay_ct=0.9676, walk_deg_s15=0.0559))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
