"""Tracking metrics on per-look results (:class:`baselines.trackers.TrackRun`) against the episodes' truth.

Looks used: those after the track start (two hits + warm-up, ``TrackRun.start_index``) up to each episode's end.
They are split by the truth into

* ``maneuver``: the aircraft is turning or changing speed (``Episode.maneuvering``);
* ``after``: not maneuvering, within ``after_window_s`` (default 60 s) after a maneuver ended (convergence back);
* ``straight``: the rest.

Failed and lost runs (a NaN or Inf estimate is never a zero error):

* a run is **failed** for a tracker (:func:`failed_runs`) when its estimate ``x`` or covariance ``P`` is not finite
  at some used look (or an error exceeds ``MAX_ERROR_M`` = 1e100 m, whose squares would overflow the pooled sums).
  Failed runs are left out of that tracker's pooled metrics and counted: ``failed_runs``, ``failed_rate``,
  ``runs_scored`` (= runs - failed runs);
* a run is **lost** (:func:`lost_runs`) when it failed or its normalised position error ever exceeds the env's
  track-loss gate (30 sigma of the plot noise); ``track_loss_rate`` = lost runs / runs, ``lost_runs`` the count;
* the **common** runs of a suite (:func:`common_runs`) are those no compared tracker lost (nor failed):
  ``pos_rmse_m_common`` (with its interval) is taken over exactly those runs for every tracker, so two trackers are
  compared on the same runs; ``common_runs`` counts them. ``pos_rmse_m`` stays the pooled RMSE over all runs the
  tracker did not fail (lost runs included, so one divergence can dominate it).

Per tracker (all computed here from the arrays, none typed in):

* ``pos_rmse_m`` / ``vel_rmse_m_s`` overall and per region (pooled over scored runs and looks), with a 95%
  bootstrap confidence interval over runs (runs resampled with replacement, ``n_boot`` = 2000, fixed seed);
* ``peak_pos_err_m``: mean over scored runs of the largest position error of the run;
* ``anees``: mean over looks of NEES / 4 (1 for a consistent filter), ``nees_in_95``: fraction of looks with
  NEES <= chi2_4(0.95) = 9.49 (0.95 for a consistent filter). The NEES is taken by Cholesky (never negative); a look
  whose P is not a covariance (not symmetric positive definite, :func:`nees_values`) has no NEES: it is left out of
  ``anees``, counted as outside the bound in ``nees_in_95`` and counted in ``nees_invalid_looks``
  (``nees_valid_looks`` the others); it never raises. Where fewer than ``MIN_VALID_NEES_SHARE`` (90 %) of the
  scored looks are valid, ``anees_few_valid_looks`` is set and the tables flag the ANEES;
* ``track_loss_rate`` (above);
* ``npe``: Kim & Lee's normalised position error, RMS position error / RMS plot error (detected looks);
* for trackers that declare maneuvers: ``detection_delay_looks`` (mean looks from a maneuver's first look to the
  first declaration within the maneuver or the window after it), ``missed_maneuvers`` (fraction never declared),
  ``false_alarm_rate`` (declarations per look on straight legs).

Intervals from fewer than ``FEW_RUNS`` = 20 runs are flagged (``few_runs``, ``few_common_runs``): the tables print
``(n<20)`` beside them, as a handful of runs is no evidence whatever the interval says. A value that is not defined
(no looks in a region, every run failed, no common run) is NaN here and its reason is in ``undefined``
(``{key: reason}``); the JSON writes it as null.

:func:`ratio_ci` gives the ratio of two trackers' pooled RMSE with a paired bootstrap interval over runs (same
runs resampled for both), over the runs neither failed (or a given subset, e.g. the common runs), so that
"A beats B" is said only when the interval excludes 1.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import chdtri

from radar_env.envs.observation import measurement_sigma_m

__all__ = ["region_masks", "evaluate_run", "ratio_ci", "failed_runs", "lost_runs", "common_runs", "errors",
           "RunScore", "score_run", "positive_definite", "nees_values", "NEES_95_4DOF", "FEW_RUNS", "MAX_ERROR_M",
           "MIN_VALID_NEES_SHARE", "comparable_rmse"]

def comparable_rmse(m):
    """Whether a tracker's metrics ``m`` (:func:`evaluate_run`'s dict, or a report's copy of it) have a pooled position
    RMSE that compares with the other trackers' of its suite and with references pooled over every run: finite, and
    no failed run (a pooled RMSE over the runs a tracker did not fail covers other runs than theirs)."""
    v = m.get("pos_rmse_m")
    return v is not None and bool(np.isfinite(v)) and not m.get("failed_runs")


NEES_95_4DOF = float(chdtri(4, 1.0 - 0.95))   # chi2.ppf(0.95, 4), bit for bit, without importing scipy.stats
FEW_RUNS = 20
MIN_VALID_NEES_SHARE = 0.9
"""``anees_few_valid_looks`` is set (and the tables say so) when fewer than this share of the scored looks have a
positive-definite covariance to take the NEES from."""
MAX_ERROR_M = 1e100


def region_masks(batch, start_index, after_window_s=60.0):
    """Boolean (B, K) masks ``used``, ``maneuver``, ``after``, ``straight`` (see module docstring)."""
    B, K = batch.valid.shape
    used = batch.valid & (np.arange(K)[None, :] >= np.asarray(start_index)[:, None])
    man = batch.maneuvering & batch.valid
    # time since the last maneuvering look (inf before any)
    t = batch.t_s
    last_man_t = np.where(man, t, -np.inf)
    last_man_t = np.maximum.accumulate(last_man_t, axis=1)
    after = (~man) & (t - last_man_t <= after_window_s) & batch.valid
    return {"used": used, "maneuver": used & man, "after": used & after, "straight": used & ~man & ~after}


def _pooled_rmse(sq, mask):
    """Per-run sums and counts -> pooled RMSE; sq, mask (B, K)."""
    s = np.where(mask, sq, 0.0).sum(axis=1)
    n = mask.sum(axis=1)
    return s, n


def _boot_rmse(s, n, rng, n_boot):
    B = s.size
    if n.sum() == 0:
        return np.nan, (np.nan, np.nan)
    est = np.sqrt(s.sum() / n.sum())
    idx = rng.integers(0, B, size=(n_boot, B))
    ss, nn = s[idx].sum(axis=1), n[idx].sum(axis=1)
    ok = nn > 0
    lo, hi = np.percentile(np.sqrt(ss[ok] / nn[ok]), (2.5, 97.5))
    return float(est), (float(lo), float(hi))


def errors(batch, run):
    """Position and velocity errors (B, K) of a run (NaN where the run produced nothing)."""
    d = run.x - batch.truth
    return np.hypot(d[..., 0], d[..., 1]), np.hypot(d[..., 2], d[..., 3])


def nees_values(d, P):
    """NEES ``d^T P^-1 d`` per look (``d`` (n, 4) errors, ``P`` (n, 4, 4)), by Cholesky (so never negative); NaN
    where ``P`` is not a covariance: not finite, not symmetric (to 1e-9 of its largest entry) or not positive
    definite (the Cholesky factorisation fails)."""
    d, P = np.asarray(d, dtype=np.float64), np.asarray(P, dtype=np.float64)
    out = np.full(d.shape[0], np.nan)
    if not d.shape[0]:
        return out
    with np.errstate(invalid="ignore"):
        scale = np.abs(P).max(axis=(1, 2))
        ok = np.isfinite(P).all(axis=(1, 2)) & np.isfinite(d).all(axis=1) & (scale > 0)
        ok &= (np.abs(P - np.swapaxes(P, 1, 2)).max(axis=(1, 2)) <= 1e-9 * scale)
    idx = np.flatnonzero(ok)
    if idx.size:
        idx = idx[positive_definite(P[idx])]   # a cheap screen; Cholesky has the last word
    try:
        L = np.linalg.cholesky(P[idx])
    except np.linalg.LinAlgError:   # a few matrices the screen passed: one by one
        keep = []
        for i in idx:
            try:
                np.linalg.cholesky(P[i])
                keep.append(i)
            except np.linalg.LinAlgError:
                pass
        idx = np.asarray(keep, dtype=np.int64)
        L = np.linalg.cholesky(P[idx])
    y = np.linalg.solve(L, d[idx][..., None])[..., 0]
    out[idx] = np.einsum("ni,ni->n", y, y)
    return out


def failed_runs(batch, run, used=None):
    """(B,) bool: the run's estimate or covariance is not finite at some used look (looks >= ``start_index``, valid),
    or an error exceeds ``MAX_ERROR_M``. ``used``: the (B, K) mask of :func:`region_masks` if already computed."""
    if used is None:
        used = region_masks(batch, run.start_index)["used"]
    ep, ev = errors(batch, run)
    finite = np.isfinite(run.x).all(axis=-1) & np.isfinite(run.P).all(axis=(-2, -1))
    bad = ~finite | ~(ep <= MAX_ERROR_M) | ~(ev <= MAX_ERROR_M)   # NaN compares False: caught here too
    return np.any(used & bad, axis=1)


def lost_runs(batch, run, track_loss_gate_sigma=30.0, used=None, failed=None):
    """(B,) bool: the run failed (:func:`failed_runs`) or its position error exceeds ``track_loss_gate_sigma`` times
    the plot noise (:func:`radar_env.envs.observation.measurement_sigma_m` at the true range) at some used look."""
    if used is None:
        used = region_masks(batch, run.start_index)["used"]
    if failed is None:
        failed = failed_runs(batch, run, used)
    ep, _ = errors(batch, run)
    r = np.hypot(batch.truth[..., 0] - batch.site_xy_m[..., 0], batch.truth[..., 1] - batch.site_xy_m[..., 1])
    sig = measurement_sigma_m(r, batch.range_noise_std_m, batch.bearing_noise_std_rad)
    return failed | np.any(used & (ep / sig > track_loss_gate_sigma), axis=1)


def common_runs(batch, runs, track_loss_gate_sigma=30.0, scores=None):
    """(B,) bool: the runs that none of ``runs`` (iterable of :class:`TrackRun`) lost or failed. ``scores``: their
    :class:`RunScore` (same gate) if already computed."""
    common = np.ones(batch.valid.shape[0], dtype=bool)
    for i, run in enumerate(runs):
        common &= ~(lost_runs(batch, run, track_loss_gate_sigma) if scores is None else scores[i].lost)
    return common


class RunScore(NamedTuple):
    """What every metric of one run on one batch starts from, computed once (:func:`score_run`)."""

    masks: dict             # region_masks(batch, run.start_index, after_window_s)
    pos_err_m: np.ndarray   # (B, K), errors(batch, run)
    vel_err_m_s: np.ndarray
    failed: np.ndarray      # (B,) failed_runs
    lost: np.ndarray        # (B,) lost_runs at the gate


def score_run(batch, run, track_loss_gate_sigma=30.0, after_window_s=60.0):
    """The :class:`RunScore` of ``run``: its region masks, errors, failed and lost runs, each computed once, for
    :func:`evaluate_run`, :func:`ratio_ci` and :func:`common_runs` (their ``score(s)`` arguments)."""
    masks = region_masks(batch, run.start_index, after_window_s)
    ep, ev = errors(batch, run)
    finite = np.isfinite(run.x).all(axis=-1) & np.isfinite(run.P).all(axis=(-2, -1))
    bad = ~finite | ~(ep <= MAX_ERROR_M) | ~(ev <= MAX_ERROR_M)   # as failed_runs
    failed = np.any(masks["used"] & bad, axis=1)
    r = np.hypot(batch.truth[..., 0] - batch.site_xy_m[..., 0], batch.truth[..., 1] - batch.site_xy_m[..., 1])
    sig = measurement_sigma_m(r, batch.range_noise_std_m, batch.bearing_noise_std_rad)
    lost = failed | np.any(masks["used"] & (ep / sig > track_loss_gate_sigma), axis=1)   # as lost_runs
    return RunScore(masks, ep, ev, failed, lost)


_PD_SURE = 1e-9
""":func:`positive_definite`'s margin: a covariance whose LDL^T pivots give det(C) min_i P_ii / tr P above this
(C = the correlation matrix of P) has its smallest eigenvalue above 1.6e-11 tr P (lambda_min(C) >= det(C) / 64 for
a 4 x 4 correlation matrix, whose trace is 4; lambda_min(P) >= lambda_min(C) min_i P_ii), a thousand times what
rounding in the factorisation and in LAPACK's eigvalsh (about 1e-14 tr P) can move it."""


def positive_definite(P):
    """(n,) bool for symmetric (n, 4, 4) covariances (their lower triangles, as ``np.linalg.eigvalsh`` reads them):
    exactly ``np.linalg.eigvalsh(P)[:, 0] > 0``, without the eigenvalues where a vectorised LDL^T decides it with
    a margin (:data:`_PD_SURE`); the rest go to eigvalsh."""
    n = P.shape[0]
    L = np.tril(P)
    d = np.empty((n, 4))
    ell = np.zeros((n, 4, 4))
    with np.errstate(all="ignore"):          # a failed pivot makes NaN / inf here; those go to eigvalsh
        for j in range(4):
            d[:, j] = L[:, j, j] - np.einsum("nk,nk,nk->n", ell[:, j, :j], ell[:, j, :j], d[:, :j])
            for i in range(j + 1, 4):
                ell[:, i, j] = (L[:, i, j] - np.einsum("nk,nk,nk->n", ell[:, i, :j], ell[:, j, :j], d[:, :j])) / d[:, j]
        diag = np.einsum("nii->ni", L)
        margin = np.prod(d / diag, axis=1) * diag.min(axis=1) / diag.sum(axis=1)
        sure = (d > 0).all(axis=1) & (diag > 0).all(axis=1) & (margin > _PD_SURE)
    pd = sure.copy()
    rest = ~sure
    if rest.any():
        pd[rest] = np.linalg.eigvalsh(P[rest])[:, 0] > 0
    return pd


def evaluate_run(batch, run, track_loss_gate_sigma=30.0, after_window_s=60.0, n_boot=2000, seed=0, common=None,
                 score=None):
    """All metrics of one tracker on one suite, as a flat dict (see module docstring).

    Args:
        common: optional (B,) bool mask of the suite's common runs (:func:`common_runs`); adds
            ``pos_rmse_m_common``, ``pos_rmse_m_common_ci95``, ``common_runs`` and ``few_common_runs``.
        score: the run's :class:`RunScore` (same gate and window) if already computed.
    """
    rng = np.random.default_rng(seed)
    if score is None:
        score = score_run(batch, run, track_loss_gate_sigma, after_window_s)
    masks, ep, ev, failed = score.masks, score.pos_err_m, score.vel_err_m_s, score.failed
    used = masks["used"]
    ok = ~failed
    n_ok = int(ok.sum())
    B = int(batch.valid.shape[0])
    out = {"runs": B, "looks": int(used.sum()), "failed_runs": B - n_ok, "failed_rate": (B - n_ok) / B,
           "runs_scored": n_ok, "few_runs": n_ok < FEW_RUNS}
    undefined = {}
    no_runs = f"all {B} runs failed (non-finite estimate or covariance)"
    for region, m in masks.items():
        key = "" if region == "used" else f"_{region}"
        m = m & ok[:, None]
        for name, e in (("pos_rmse_m", ep), ("vel_rmse_m_s", ev)):
            s, n = _pooled_rmse(np.where(m, e, 0.0) ** 2, m)
            est, (lo, hi) = _boot_rmse(s[ok], n[ok], rng, n_boot)
            out[f"{name}{key}"], out[f"{name}{key}_ci95"] = est, [lo, hi]
            if not np.isfinite(est):
                undefined[f"{name}{key}"] = undefined[f"{name}{key}_ci95"] = (
                    no_runs if n_ok == 0 else f"no looks in region '{region}'")
    peak = np.max(np.where(used & ok[:, None], ep, 0.0), axis=1)[ok]
    out["peak_pos_err_m"] = float(np.mean(peak)) if n_ok else np.nan
    # NEES (4 dof) at the used looks of the scored runs, from the looks whose P is a covariance (nees_values)
    cand = used & ok[:, None]
    nees = nees_values((run.x - batch.truth)[cand], run.P[cand])
    nees = nees[np.isfinite(nees)]
    n_cand = int(cand.sum())
    out["nees_valid_looks"] = int(nees.size)
    out["nees_invalid_looks"] = n_cand - int(nees.size)
    out["anees"] = float(nees.mean() / 4.0) if nees.size else np.nan
    out["anees_few_valid_looks"] = bool(nees.size < MIN_VALID_NEES_SHARE * n_cand)
    out["nees_in_95"] = float((nees <= NEES_95_4DOF).sum() / n_cand) if n_cand else np.nan
    if not nees.size:
        undefined["anees"] = no_runs if n_ok == 0 else "no look with a positive-definite covariance"
    # track loss: failed, or normalised error beyond the env's gate at any used look
    lost = score.lost
    out["track_loss_rate"] = float(lost.mean())
    out["lost_runs"] = int(lost.sum())
    # Kim & Lee NPE
    det = cand & batch.detected
    ez = np.hypot(*(np.nan_to_num(batch.z_m) - batch.truth[..., :2]).transpose(2, 0, 1))
    out["npe"] = float(np.sqrt(np.mean(ep[cand] ** 2)) / np.sqrt(np.mean(ez[det] ** 2))) if det.any() else np.nan
    if run.declared is not None:
        out.update(detection_stats(batch, run.declared, {k: v & ok[:, None] for k, v in masks.items()},
                                   after_window_s))
    if common is not None:
        c = np.asarray(common, dtype=bool) & ok
        s, n = _pooled_rmse(np.where(used & c[:, None], ep, 0.0) ** 2, used & c[:, None])
        # the same resamples as pos_rmse_m's (fresh generator, same seed): equal intervals when no run is left out
        est, (lo, hi) = _boot_rmse(s[c], n[c], np.random.default_rng(seed), n_boot)
        out["pos_rmse_m_common"], out["pos_rmse_m_common_ci95"] = est, [lo, hi]
        out["common_runs"], out["few_common_runs"] = int(c.sum()), int(c.sum()) < FEW_RUNS
        if not np.isfinite(est):
            undefined["pos_rmse_m_common"] = undefined["pos_rmse_m_common_ci95"] = (
                "no common run (every run was lost or failed by some tracker)")
    why = {"npe": "no detected look", "detection_delay_looks": "no maneuver declared in time (or no maneuver)",
           "missed_maneuvers": "no maneuver", "false_alarm_rate": "no straight look"}
    for k, v in out.items():         # whatever is left undefined: say which key and why
        if isinstance(v, float) and not np.isfinite(v) and k not in undefined:
            undefined[k] = no_runs if n_ok == 0 else why.get(k, "not finite")
    out["undefined"] = undefined
    return out


def detection_stats(batch, declared, masks, after_window_s=60.0):
    """Maneuver detection delay (looks), missed-maneuver fraction and false-alarm rate per straight look.

    A maneuver starts at a used maneuvering look after a look that is not; it is detected at the first declared
    valid look from its start until ``after_window_s`` after its last look (look times increase within a run)."""
    used = masks["used"]
    man = batch.maneuvering & used
    B, K = man.shape
    k = np.arange(K)
    onset = man & ~np.concatenate([np.zeros((B, 1), dtype=bool), man[:, :-1]], axis=1)

    def first_from(flags):     # (B, K): the first look >= k where flags holds, K if none
        return np.minimum.accumulate(np.where(flags, k, K)[:, ::-1], axis=1)[:, ::-1]

    rows, k0 = np.nonzero(onset)               # row-major: the order the delays are averaged in
    end = first_from(~man)[rows, k0]           # the maneuver runs until its first look that is not one
    t_end = batch.t_s[rows, end - 1] + after_window_s
    first = first_from(declared & batch.valid)[rows, k0]
    hit = (first < K) & (batch.t_s[rows, np.minimum(first, K - 1)] <= t_end)
    delays = (first - k0)[hit]
    n_man = int(k0.size)
    straight = masks["straight"]
    return {
        "detection_delay_looks": float(np.mean(delays)) if delays.size else np.nan,
        "missed_maneuvers": float(int((~hit).sum()) / n_man) if n_man else np.nan,
        "false_alarm_rate": float(declared[straight].mean()) if straight.any() else np.nan,
    }


def ratio_ci(batch, run_a, run_b, region="used", n_boot=2000, seed=0, after_window_s=60.0, runs=None, scores=None):
    """Pooled position RMSE of ``run_a`` / ``run_b`` over the looks both use, with a paired 95% bootstrap CI.

    Pooled over the runs neither tracker failed (:func:`failed_runs`), restricted to ``runs`` ((B,) bool, e.g. the
    common runs) if given; ``scores``: the two runs' :class:`RunScore` if already computed. Returns ``(ratio, (lo,
    hi))``, NaN if no run is left."""
    rng = np.random.default_rng(seed)
    start = np.maximum(run_a.start_index, run_b.start_index)
    if region == "used":       # the only mask that depends on the start: no need for the others
        K = batch.valid.shape[1]
        ma = batch.valid & (np.arange(K)[None, :] >= np.asarray(start)[:, None])
    else:
        ma = region_masks(batch, start, after_window_s)[region]
    if scores is None:
        scores = [score_run(batch, r, after_window_s=after_window_s) for r in (run_a, run_b)]
    sel = ~scores[0].failed & ~scores[1].failed
    if runs is not None:
        sel &= np.asarray(runs, dtype=bool)
    ma = ma & sel[:, None]
    ea, eb = scores[0].pos_err_m, scores[1].pos_err_m
    sa, n = _pooled_rmse(np.where(ma, ea, 0.0) ** 2, ma)
    sb, _ = _pooled_rmse(np.where(ma, eb, 0.0) ** 2, ma)
    sa, sb, n = sa[sel], sb[sel], n[sel]
    if n.sum() == 0 or sb.sum() == 0:
        return np.nan, (np.nan, np.nan)
    est = np.sqrt(sa.sum() / sb.sum())
    idx = rng.integers(0, sa.size, size=(n_boot, sa.size))
    den = sb[idx].sum(axis=1)
    ok = den > 0
    lo, hi = np.percentile(np.sqrt(sa[idx].sum(axis=1)[ok] / den[ok]), (2.5, 97.5))
    return float(est), (float(lo), float(hi))


def jsonable(o):
    """``o`` with numpy scalars as Python numbers and every NaN or Inf as None (the metrics dicts say why in
    ``undefined``), so ``json.dumps(..., allow_nan=False)`` accepts it."""
    if isinstance(o, dict):
        return {k: jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [jsonable(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.ndarray):
        return jsonable(o.tolist())
    return o
