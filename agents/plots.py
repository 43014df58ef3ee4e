"""Evaluation figures (matplotlib, PNG). Called by :func:`agents.evaluate.write_plots` with the Agg backend.

Per suite:

* ``<suite>_errors.png``: position and speed error vs time, mean over runs and the 2.5-97.5 percentile band per
  tracker (as Bizup's figures 7 and 8);
* ``<suite>_trajectory.png``: run 0's true path, its plots and each tracker's track;
* ``<suite>_q.png``: the q each q-choosing tracker used over time in run 0, against the truth's acceleration;
* ``<suite>_features.png``: c_min and Adrian's turn-rate estimates over time in run 0, against the truth.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from radar_env.units import G0_M_S2

__all__ = ["suite_figures"]


def _time_axis(batch):
    """Median look time per look index (the looks of named scenarios coincide across runs)."""
    t = np.where(batch.valid, batch.t_s, np.nan)
    return np.nanmedian(t, axis=0)


def _used(batch, run):
    K = batch.valid.shape[1]
    return batch.valid & (np.arange(K)[None, :] >= run.start_index[:, None])


def suite_figures(suite, batch, runs, out_dir):
    out_dir = Path(out_dir)
    files = []
    t = _time_axis(batch)
    speed_true = np.hypot(batch.truth[..., 2], batch.truth[..., 3])

    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for name, run in runs.items():
        used = _used(batch, run)
        ep = np.where(used, np.hypot(*(run.x[..., :2] - batch.truth[..., :2]).transpose(2, 0, 1)), np.nan)
        es = np.where(used, np.abs(np.hypot(run.x[..., 2], run.x[..., 3]) - speed_true), np.nan)
        for ax, e in ((axes[0], ep), (axes[1], es)):
            ok = np.sum(np.isfinite(e), axis=0) > 0
            with np.errstate(all="ignore"):
                mean = np.nanmean(e[:, ok], axis=0)
                lo, hi = np.nanpercentile(e[:, ok], [2.5, 97.5], axis=0)
            line, = ax.plot(t[ok], mean, lw=1.2, label=name)
            ax.fill_between(t[ok], lo, hi, color=line.get_color(), alpha=0.12, lw=0)
    man = np.nanmean(np.where(batch.valid, batch.maneuvering, np.nan), axis=0)
    for ax in axes:
        ax.set_yscale("log")
        ymin, ymax = ax.get_ylim()
        ax.fill_between(t, ymin, ymax, where=man > 0.5, color="0.85", zorder=0, label="maneuver (truth)")
        ax.set_ylim(ymin, ymax)
    axes[0].set_ylabel("position error (m)")
    axes[1].set_ylabel("speed error (m/s)")
    axes[1].set_xlabel("time (s)")
    axes[0].set_title(f"{suite}: mean and 95% band over {batch.valid.shape[0]} runs")
    axes[0].legend(fontsize=8, ncol=3)
    files.append(_save(fig, out_dir / f"{suite}_errors.png"))

    fig, ax = plt.subplots(figsize=(8, 8))
    n = int(batch.n_looks[0])
    tr = batch.truth[0, :n] / 1e3
    ax.plot(tr[:, 0], tr[:, 1], "k-", lw=2, label="truth")
    z = batch.z_m[0, :n] / 1e3
    ax.plot(z[:, 0], z[:, 1], ".", color="0.5", ms=3, label="plots")
    for name, run in runs.items():
        x = run.x[0, :n] / 1e3
        ax.plot(x[:, 0], x[:, 1], lw=1, label=name)
    sites = np.unique(batch.site_xy_m[0, :n], axis=0) / 1e3
    ax.plot(sites[:, 0], sites[:, 1], "^", color="tab:red", ms=10, label="radar")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_title(f"{suite}: run 0")
    ax.legend(fontsize=8)
    files.append(_save(fig, out_dir / f"{suite}_trajectory.png"))

    q_runs = {k: r for k, r in runs.items() if np.any(np.isfinite(r.q_m_s2[0]))}
    if q_runs:
        fig, ax = plt.subplots(figsize=(10, 4))
        tt = batch.t_s[0, :n]
        acc = np.hypot(*batch.truth_accel_m_s2[0, :n].T) / G0_M_S2
        ax.plot(tt, np.maximum(acc, 1e-3), "k-", lw=2, label="|a| truth")
        for name, run in q_runs.items():
            ax.step(tt, run.q_m_s2[0, :n] / G0_M_S2, where="pre", lw=1, label=f"q {name}")
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("g")
        ax.set_title(f"{suite}: process-noise level chosen (run 0)")
        ax.legend(fontsize=8, ncol=2)
        files.append(_save(fig, out_dir / f"{suite}_q.png"))

    feat_run = next((r for r in runs.values() if "c_min_g" in r.extra), None)
    if feat_run is not None:
        fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        tt = batch.t_s[0, :n]
        acc = np.hypot(*batch.truth_accel_m_s2[0, :n].T) / G0_M_S2
        axes[0].plot(tt, acc, "k-", lw=2, label="|a| truth (g)")
        axes[0].plot(tt, feat_run.extra["c_min_g"][0, :n], ".-", lw=0.8, ms=3, label="c_min (g)")
        axes[0].axhline(1.0, color="tab:red", ls=":", label="c_min tracker threshold 1 g")
        axes[0].legend(fontsize=8)
        axes[1].plot(tt, np.degrees(batch.truth_turn_rate_rad_s[0, :n]), "k-", lw=2, label="turn rate truth")
        axes[1].plot(tt, feat_run.extra["turn_rate_alg1_deg_s"][0, :n], lw=0.8, label="Adrian alg. 1")
        axes[1].plot(tt, feat_run.extra["turn_rate_alg2_deg_s"][0, :n], lw=0.8, label="Adrian alg. 2")
        axes[1].set_ylabel("deg/s (+ right)")
        axes[1].set_xlabel("time (s)")
        axes[1].legend(fontsize=8)
        axes[0].set_title(f"{suite}: maneuver features in run 0 (tracker {feat_run.name})")
        files.append(_save(fig, out_dir / f"{suite}_features.png"))
    return files


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
