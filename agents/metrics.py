"""Tracking metrics on per-look results (:class:`baselines.trackers.TrackRun`) against the episodes' truth.

Looks used: those after the track start (two hits + warm-up, ``TrackRun.start_index``) up to each episode's end.
They are split by the truth into

* ``maneuver``: the aircraft is turning or changing speed (``Episode.maneuvering``);
* ``after``: not maneuvering, within ``after_window_s`` (default 60 s) after a maneuver ended (convergence back);
* ``straight``: the rest.

Per tracker (all computed here from the arrays, none typed in):

* ``pos_rmse_m`` / ``vel_rmse_m_s`` overall and per region (pooled over runs and looks), with a 95% bootstrap
  confidence interval over runs (runs resampled with replacement, ``n_boot`` = 2000, fixed seed);
* ``peak_pos_err_m``: mean over runs of the largest position error of the run;
* ``anees``: mean over looks of NEES / 4 (1 for a consistent filter), ``nees_in_95``: fraction of looks with
  NEES <= chi2_4(0.95) = 9.49 (0.95 for a consistent filter);
* ``track_loss_rate``: fraction of runs whose normalised position error ever exceeds the env's track-loss gate;
* ``npe``: Kim & Lee's normalised position error, RMS position error / RMS plot error (detected looks);
* for trackers that declare maneuvers: ``detection_delay_looks`` (mean looks from a maneuver's first look to the
  first declaration within the maneuver or the window after it), ``missed_maneuvers`` (fraction never declared),
  ``false_alarm_rate`` (declarations per look on straight legs).

:func:`ratio_ci` gives the ratio of two trackers' pooled RMSE with a paired bootstrap interval over runs (same
runs resampled for both), so that "A beats B" is said only when the interval excludes 1.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from radar_env.observation import measurement_sigma_m

__all__ = ["region_masks", "evaluate_run", "ratio_ci", "NEES_95_4DOF"]

NEES_95_4DOF = float(chi2.ppf(0.95, 4))


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
    boots = np.sqrt(ss[ok] / nn[ok])
    return float(est), (float(np.percentile(boots, 2.5)), float(np.percentile(boots, 97.5)))


def errors(batch, run):
    """Position and velocity errors (B, K) of a run (NaN where the run produced nothing)."""
    d = run.x - batch.truth
    return np.hypot(d[..., 0], d[..., 1]), np.hypot(d[..., 2], d[..., 3])


def evaluate_run(batch, run, track_loss_gate_sigma=30.0, after_window_s=60.0, n_boot=2000, seed=0):
    """All metrics of one tracker on one suite, as a flat dict of floats (see module docstring)."""
    rng = np.random.default_rng(seed)
    masks = region_masks(batch, run.start_index, after_window_s)
    used = masks["used"]
    ep, ev = errors(batch, run)
    out = {"runs": int(batch.valid.shape[0]), "looks": int(used.sum())}
    for region, m in masks.items():
        key = "" if region == "used" else f"_{region}"
        for name, e in (("pos_rmse_m", ep), ("vel_rmse_m_s", ev)):
            s, n = _pooled_rmse(np.nan_to_num(e) ** 2, m)
            est, (lo, hi) = _boot_rmse(s, n, rng, n_boot)
            out[f"{name}{key}"], out[f"{name}{key}_ci95"] = est, [lo, hi]
    out["peak_pos_err_m"] = float(np.mean(np.max(np.where(used, ep, 0.0), axis=1)))
    # NEES (4 dof)
    d = run.x - batch.truth
    P = np.where(used[..., None, None], run.P, np.eye(4))
    sol = np.linalg.solve(P, np.where(used[..., None], d, 0.0)[..., None])[..., 0]
    nees = np.einsum("bki,bki->bk", np.where(used[..., None], d, 0.0), sol)
    out["anees"] = float(nees[used].mean() / 4.0)
    out["nees_in_95"] = float((nees[used] <= NEES_95_4DOF).mean())
    # track loss: normalised error beyond the env's gate at any used look
    r = np.hypot(batch.truth[..., 0] - batch.site_xy_m[..., 0], batch.truth[..., 1] - batch.site_xy_m[..., 1])
    sig = measurement_sigma_m(r, batch.range_noise_std_m, batch.bearing_noise_std_rad)
    lost = np.any(used & (ep / sig > track_loss_gate_sigma), axis=1)
    out["track_loss_rate"] = float(lost.mean())
    # Kim & Lee NPE
    det = used & batch.detected
    ez = np.hypot(*(np.nan_to_num(batch.z_m) - batch.truth[..., :2]).transpose(2, 0, 1))
    out["npe"] = float(np.sqrt(np.mean(ep[used] ** 2)) / np.sqrt(np.mean(ez[det] ** 2))) if det.any() else np.nan
    if run.declared is not None:
        out.update(detection_stats(batch, run.declared, masks, after_window_s))
    return out


def detection_stats(batch, declared, masks, after_window_s=60.0):
    """Maneuver detection delay (looks), missed-maneuver fraction and false-alarm rate per straight look."""
    used = masks["used"]
    man = batch.maneuvering & used
    delays, missed = [], 0
    B, K = man.shape
    for b in range(B):
        m = man[b]
        onsets = np.flatnonzero(m & ~np.r_[False, m[:-1]])
        for k0 in onsets:
            # maneuver runs until m goes False; the search window extends after_window_s beyond its end
            end = k0 + np.argmax(~m[k0:]) if np.any(~m[k0:]) else K
            t_end = batch.t_s[b, end - 1] + after_window_s
            win = np.flatnonzero((np.arange(K) >= k0) & (batch.t_s[b] <= t_end) & batch.valid[b])
            hits = win[declared[b, win]]
            if hits.size:
                delays.append(int(hits[0] - k0))
            else:
                missed += 1
    n_man = len(delays) + missed
    straight = masks["straight"]
    return {
        "detection_delay_looks": float(np.mean(delays)) if delays else np.nan,
        "missed_maneuvers": float(missed / n_man) if n_man else np.nan,
        "false_alarm_rate": float(declared[straight].mean()) if straight.any() else np.nan,
    }


def ratio_ci(batch, run_a, run_b, region="used", n_boot=2000, seed=0, after_window_s=60.0):
    """Pooled position RMSE of ``run_a`` / ``run_b`` over the looks both use, with a paired 95% bootstrap CI."""
    rng = np.random.default_rng(seed)
    ma = region_masks(batch, np.maximum(run_a.start_index, run_b.start_index), after_window_s)[region]
    ea, _ = errors(batch, run_a)
    eb, _ = errors(batch, run_b)
    sa, n = _pooled_rmse(np.nan_to_num(ea) ** 2, ma)
    sb, _ = _pooled_rmse(np.nan_to_num(eb) ** 2, ma)
    if n.sum() == 0 or sb.sum() == 0:
        return np.nan, (np.nan, np.nan)
    est = np.sqrt(sa.sum() / sb.sum())
    idx = rng.integers(0, sa.size, size=(n_boot, sa.size))
    den = sb[idx].sum(axis=1)
    ok = den > 0
    r = np.sqrt(sa[idx].sum(axis=1)[ok] / den[ok])
    return float(est), (float(np.percentile(r, 2.5)), float(np.percentile(r, 97.5)))
