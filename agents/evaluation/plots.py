"""Evaluation figures (matplotlib, PNG). Called by :func:`agents.evaluation.evaluate.write_plots` with the Agg backend.

Per suite:

* ``<suite>_errors.png``: position and speed error vs time, mean over runs and the 2.5-97.5 percentile band per
  tracker (as Bizup's figures 7 and 8). Where every run has the same look times (named scenarios) the curves are
  per look against the scenario clock and the truth's maneuvers are shaded; otherwise (random flights, random
  radars with their own scan periods, ADS-B flights of different lengths) each run's errors are averaged in
  common time bins since its track start and the band is taken over the runs present in a bin;
* ``<suite>_trajectory.png``: run 0's true path, its plots and each tracker's track, with a zoom on its maneuvers;
* ``<suite>_q.png``: the q each q-choosing tracker used over time in run 0, against the truth's acceleration;
* ``<suite>_features.png``: c_min and Adrian's turn-rate estimates over time in run 0, against the truth.

Each ``*_figure`` function returns the open figure (for tests and notebooks); :func:`suite_figures` saves and closes
them. Legends sit outside the axes so they never cover data.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from radar_env.units import G0_M_S2

from agents.evaluation.metrics import failed_runs

__all__ = ["suite_figures", "error_figure", "trajectory_figure", "q_figure", "features_figure",
           "training_curve_figure", "shared_look_times", "binned_error_stats"]

MAX_TIME_BINS = 200
"""Bins of the error curves at most (the bin width is the longest scan period or longer)."""


def _used(batch, run):
    K = batch.valid.shape[1]
    return batch.valid & (np.arange(K)[None, :] >= run.start_index[:, None])


def shared_look_times(batch):
    """True if, at every look index, every run that has the look looks at the same time and the truth maneuvers
    (or not) alike: then per-look statistics are statistics at one time and the maneuvers can be shaded."""
    v = batch.valid
    longest = np.argmax(batch.n_looks)
    t0, m0 = batch.t_s[longest], batch.maneuvering[longest]
    return bool(np.all((batch.t_s == t0) | ~v) and np.all((batch.maneuvering == m0) | ~v))


def _nice_ceil(x):
    """Smallest of 1, 2, 5 x 10^k that is >= x."""
    if not x > 0:
        return 1.0
    e = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0 ** e >= x * (1 - 1e-12):
            return m * 10.0 ** e
    return 10.0 ** (e + 1)  # pragma: no cover - unreachable


def _min_runs(B):
    """Bins (or looks) with fewer runs than this are hidden: a mean and band over 1-2 runs is noise."""
    return min(B, max(3, math.ceil(B / 4)))


def error_bin_width_s(batch):
    """Width of the common time bins: the longest per-run median look interval, rounded up to 1/2/5 x 10^k s,
    widened so that the longest run spans at most ``MAX_TIME_BINS`` bins."""
    dts, spans = [], []
    for b in range(batch.batch_size):
        t = batch.t_s[b, :int(batch.n_looks[b])]
        if t.size > 1:
            dts.append(float(np.median(np.diff(t))))
            spans.append(float(t[-1] - t[0]))
    return _nice_ceil(max(max(dts, default=1.0), max(spans, default=1.0) / MAX_TIME_BINS))


def binned_error_stats(t_since_start_s, err, width_s, min_runs):
    """Per-run means of ``err`` (B, K; NaN where not used) in bins ``[i w, (i + 1) w)`` of ``t_since_start_s``
    (B, K), then over the runs present in each bin: centre (s), mean, 2.5 and 97.5 percentiles. Bins with fewer
    than ``min_runs`` runs are left out, so the returned centres are strictly increasing."""
    ok = np.isfinite(err) & np.isfinite(t_since_start_s) & (t_since_start_s >= 0)
    B = err.shape[0]
    idx = np.floor(np.where(ok, t_since_start_s, 0.0) / width_s).astype(np.int64)
    n_bins = int(idx[ok].max()) + 1 if ok.any() else 0
    flat = (np.arange(B)[:, None] * n_bins + idx)[ok]
    s = np.bincount(flat, weights=err[ok], minlength=B * n_bins).reshape(B, n_bins)
    c = np.bincount(flat, minlength=B * n_bins).reshape(B, n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_run = np.where(c > 0, s / c, np.nan)
    keep = np.sum(c > 0, axis=0) >= min_runs
    per_run = per_run[:, keep]
    centres = (np.nonzero(keep)[0] + 0.5) * width_s
    if not keep.any():
        return centres, np.empty(0), np.empty(0), np.empty(0)
    mean = np.nanmean(per_run, axis=0)
    lo, hi = np.nanpercentile(per_run, [2.5, 97.5], axis=0)
    return centres, mean, lo, hi


def _spans(t, mask):
    """``[(t_start, t_end)]`` of the runs of True in ``mask`` (looks at times ``t``)."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0] - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def error_figure(suite, batch, runs):
    """Position and speed error against time (see the module docstring for the time axis). Returns the figure.

    A tracker's failed runs (:func:`agents.evaluation.metrics.failed_runs`: a non-finite estimate or covariance after its
    track start) are left out of its curves and counted in its legend entry."""
    B = batch.batch_size
    shared = shared_look_times(batch)
    min_runs = _min_runs(B)
    width = error_bin_width_s(batch)
    speed_true = np.hypot(batch.truth[..., 2], batch.truth[..., 3])
    fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=True, layout="constrained")
    for name, run in runs.items():
        used = _used(batch, run)
        ep = np.where(used, np.hypot(*(run.x[..., :2] - batch.truth[..., :2]).transpose(2, 0, 1)), np.nan)
        es = np.where(used, np.abs(np.hypot(run.x[..., 2], run.x[..., 3]) - speed_true), np.nan)
        # a failed run (non-finite estimate, as agents.evaluation.metrics scores it) must not vanish from the mean as a NaN
        # would: it is left out whole, and the legend says how many were
        failed = failed_runs(batch, run, used)
        ep[failed], es[failed] = np.nan, np.nan
        label = name if not failed.any() else f"{name} ({int(failed.sum())} failed run(s) left out)"
        for ax, e in ((axes[0], ep), (axes[1], es)):
            if shared:
                t = batch.t_s[np.argmax(batch.n_looks)]
                ok = np.sum(np.isfinite(e), axis=0) >= min_runs
                with np.errstate(all="ignore"):
                    mean = np.nanmean(e[:, ok], axis=0)
                    lo, hi = np.nanpercentile(e[:, ok], [2.5, 97.5], axis=0)
                x = t[ok]
            else:
                k0 = np.asarray(run.start_index)
                t_start = np.take_along_axis(batch.t_s, np.minimum(k0, batch.t_s.shape[1] - 1)[:, None], axis=1)
                x, mean, lo, hi = binned_error_stats(np.where(used, batch.t_s - t_start, np.nan), e, width,
                                                     min_runs)
            line, = ax.plot(x, mean, lw=1.2, label=label)
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.12, lw=0)
    for ax in axes:
        ax.set_yscale("log")
    if shared:
        longest = np.argmax(batch.n_looks)
        spans = _spans(batch.t_s[longest], batch.maneuvering[longest])
        for ax in axes:
            for i, (a, b) in enumerate(spans):
                ax.axvspan(a, b, color="0.85", zorder=0, lw=0,
                           label="maneuver (truth, the same in every run)" if i == 0 else None)
        note = "per look; maneuvers shaded (the same in every run)"
        if np.any(batch.n_looks < batch.n_looks.max()):
            note += f"; looks present in < {min_runs} runs hidden"
        axes[1].set_xlabel(f"time since scenario start (s)\n{note}")
    else:
        axes[1].set_xlabel(f"time since track start (s)\nruns have different look times: each run is aligned at "
                           f"its track start and its errors averaged in {width:g} s bins;\nbins with < {min_runs} "
                           f"of {B} runs hidden; maneuver times differ per run: not shaded", fontsize=9)
    axes[0].set_ylabel("position error (m)")
    axes[1].set_ylabel("speed error (m/s)")
    axes[0].set_title(f"{suite}: mean and 2.5-97.5 % band over {B} runs")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    return fig


def _maneuver_window(xy_km, t_s, maneuvering, k_start, tracks_km=()):
    """Run 0's first maneuver that begins at or after the track start (look ``k_start``; else the first one).

    Returns ``(sel, box, elongated, (t_start_s, t_end_s))`` or None if the run never maneuvers: ``sel`` the looks
    from half its duration before it to its duration after it (at least 3 and 5 look intervals: where the tracks
    lag and overshoot); ``box`` ``(x0, x1, y0, y1)`` km around the truth and ``tracks_km`` there, with a margin;
    ``elongated`` if the box is too long and thin to draw east and north to one scale."""
    spans = _spans(np.arange(len(maneuvering)), maneuvering)
    if not spans:
        return None
    a, b = next(((int(i), int(j)) for i, j in spans if i >= k_start), (int(spans[0][0]), int(spans[0][1])))
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    dur = float(t_s[b] - t_s[a])
    sel = (t_s >= t_s[a] - max(3 * dt, 0.5 * dur)) & (t_s <= t_s[b] + max(5 * dt, dur))
    p = np.concatenate([xy_km[sel]] + [x[sel] for x in tracks_km])   # truth and tracks inside the box
    p = p[np.all(np.isfinite(p), axis=1)]
    lo, hi = p.min(axis=0), p.max(axis=0)
    size = np.maximum(hi - lo, 0.05)                       # km; a straight leg still gets some height
    elongated = bool(size.max() > 4 * size.min())
    if not elongated:
        size[:] = size.max()
    half = 0.5 * size * 1.15
    c = 0.5 * (lo + hi)
    return sel, (c[0] - half[0], c[0] + half[0], c[1] - half[1], c[1] + half[1]), elongated, (
        float(t_s[a]), float(t_s[b]))


def trajectory_figure(suite, batch, runs):
    """Run 0: truth, plots, tracks and radar sites; beside it a zoom on its first maneuver after the track start
    (only the looks around it, so other legs crossing the box do not clutter it). Returns the figure."""
    n = int(batch.n_looks[0])
    tr = batch.truth[0, :n] / 1e3
    z = batch.z_m[0, :n] / 1e3
    sites = np.unique(batch.site_xy_m[0, :n], axis=0) / 1e3
    k_start = int(min(int(r.start_index[0]) for r in runs.values())) if runs else 0
    win = _maneuver_window(tr[:, :2], batch.t_s[0, :n], batch.maneuvering[0, :n], k_start,
                           [r.x[0, :n, :2] / 1e3 for r in runs.values()])
    fig, axes = plt.subplots(1, 2 if win else 1, figsize=(14 if win else 8, 7), layout="constrained",
                             squeeze=False)
    axes = axes[0]
    for ax, sel in zip(axes, (np.ones(n, bool), win[0] if win else None)):
        ax.plot(tr[sel, 0], tr[sel, 1], "k-", lw=2, label="truth")
        ax.plot(z[sel, 0], z[sel, 1], ".", color="0.5", ms=3, label="plots")
        for name, run in runs.items():
            x = run.x[0, :n][sel] / 1e3
            ax.plot(x[:, 0], x[:, 1], lw=1, label=name)
        ax.plot(sites[:, 0], sites[:, 1], "^", color="tab:red", ms=10, label="radar")
        ax.set_xlabel("east (km)")
        ax.set_ylabel("north (km)")
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[0].set_title(f"{suite}: run 0")
    if win:
        sel, (x0, x1, y0, y1), elongated, (ta, tb) = win
        axes[1].set_xlim(x0, x1)
        axes[1].set_ylim(y0, y1)
        if not elongated:
            axes[1].set_aspect("equal", adjustable="box")
        tw = batch.t_s[0, :n][sel]
        axes[1].set_title(f"zoom (box at left): maneuver at t = {ta:.0f}-{tb:.0f} s, looks {tw[0]:.0f}-{tw[-1]:.0f} s"
                          + ("\neast and north NOT to the same scale" if elongated else ""), fontsize=10)
        axes[0].indicate_inset((x0, y0, x1 - x0, y1 - y0), edgecolor="tab:blue", lw=1.2)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    return fig


def q_figure(suite, batch, runs):
    """The q each q-choosing tracker used in run 0 against the truth's |a|, in g, log scale. Values below the floor
    (the truth's 0 on straight legs, a q of 0) are drawn on the labelled floor line. None if no tracker has a q."""
    q_runs = {k: r for k, r in runs.items() if np.any(np.isfinite(r.q_m_s2[0]))}
    if not q_runs:
        return None
    n = int(batch.n_looks[0])
    tt = batch.t_s[0, :n]
    acc = np.hypot(*batch.truth_accel_m_s2[0, :n].T) / G0_M_S2
    qs = {k: r.q_m_s2[0, :n] / G0_M_S2 for k, r in q_runs.items()}
    # the floor sits a decade-step under the smallest positive q (the truth's |a| can be tiny but nonzero on
    # ADS-B flights, and stretching the axis to it would squash the q steps)
    qv = np.concatenate(list(qs.values()))
    qpos = qv[np.isfinite(qv) & (qv > 0)]
    apos = acc[np.isfinite(acc) & (acc > 0)]
    ref = qpos if qpos.size else apos
    floor = 10.0 ** math.floor(math.log10(ref.min())) if ref.size else 1e-3
    top = float(max(qpos.max(initial=floor), apos.max(initial=floor)))
    fig, ax = plt.subplots(figsize=(11, 4), layout="constrained")
    below = lambda v: np.any(np.isfinite(v) & (v < floor))  # noqa: E731
    lab = lambda s, v: s + (" (values < floor drawn on it)" if below(v) else "")  # noqa: E731
    ax.plot(tt, np.maximum(acc, floor), "k-", lw=2, label=lab("|a| truth", acc))
    for name, q in qs.items():
        ax.step(tt, np.where(np.isfinite(q), np.maximum(q, floor), np.nan), where="pre", lw=1,
                label=lab(f"q {name}", q))
    ax.axhline(floor, color="0.4", ls=":", lw=1, label=f"floor {floor:g} g: smaller values, 0 included")
    ax.set_yscale("log")
    ax.set_ylim(floor / 2, top * 2)
    ax.set_xlabel("time since scenario start (s)")
    ax.set_ylabel("|a| and q (g)")
    ax.set_title(f"{suite}: process-noise level chosen in run 0 (q from the track start)")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=8)
    return fig


def features_figure(suite, batch, runs):
    """c_min and Adrian's turn-rate estimates in run 0 against the truth. None if no tracker records them."""
    feat_run = next((r for r in runs.values() if "c_min_g" in r.extra), None)
    if feat_run is None:
        return None
    n = int(batch.n_looks[0])
    tt = batch.t_s[0, :n]
    acc = np.hypot(*batch.truth_accel_m_s2[0, :n].T) / G0_M_S2
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True, layout="constrained")
    axes[0].plot(tt, acc, "k-", lw=2, label="|a| truth")
    axes[0].plot(tt, feat_run.extra["c_min_g"][0, :n], ".-", lw=0.8, ms=3, label="c_min")
    axes[0].axhline(1.0, color="tab:red", ls=":", label="c_min tracker threshold 1 g")
    axes[0].set_ylabel("acceleration (g)")
    axes[1].plot(tt, np.degrees(batch.truth_turn_rate_rad_s[0, :n]), "k-", lw=2, label="turn rate truth")
    axes[1].plot(tt, feat_run.extra["turn_rate_alg1_deg_s"][0, :n], lw=0.8, label="Adrian alg. 1")
    axes[1].plot(tt, feat_run.extra["turn_rate_alg2_deg_s"][0, :n], lw=0.8, label="Adrian alg. 2")
    axes[1].set_ylabel("turn rate (deg/s, + right)")
    axes[1].set_xlabel("time since scenario start (s)")
    for ax in axes:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    axes[0].set_title(f"{suite}: maneuver features in run 0 (tracker {feat_run.name})")
    return fig


def training_curve_figure(stages, returns=None):
    """Selection-suite ratios (position RMSE / imm2) over env steps, one or more training stages in order.

    Args:
        stages: list of ``(label, selection_history, selected_timesteps_or_None)``; the stages are drawn end to
            end (a fine-tuning stage starts from the previous stage's selected checkpoint, marked on its curve).
        returns: optional ``(steps, mean_episode_return)`` of the (last) stage's TensorBoard log.
    Returns the figure.
    """
    ncols = 2 if returns is not None else 1
    fig, axs = plt.subplots(1, ncols, figsize=(7 * ncols + 3, 4), layout="constrained", squeeze=False)
    axs = axs[0]
    a2 = axs[-1]
    offset, colors = 0, {}
    for i, (label, hist, chosen) in enumerate(stages):
        if not hist:
            continue
        steps = np.array([h["timesteps"] for h in hist], float)
        keys = [k for k in hist[0] if k.endswith("_ratio_imm2")]
        for k in keys:
            name = k.replace("_ratio_imm2", "")
            ln, = a2.plot((offset + steps) / 1e6, [h[k] for h in hist], "o-", ms=2.5, lw=1,
                          color=colors.get(name), label=name if name not in colors else None)
            colors[name] = ln.get_color()
        if len(stages) > 1:
            a2.axvline(offset / 1e6, color="0.5", lw=0.8)
            a2.text(offset / 1e6, 1.0, f" {label}", transform=a2.get_xaxis_transform(), va="top", ha="left",
                    fontsize=7, color="0.3", rotation=0)
        if chosen is not None:
            a2.axvline((offset + chosen) / 1e6, color="tab:red", ls=":", lw=1.2,
                       label=("selected checkpoint" + (" of each stage\n(the next stage starts from it)"
                                                        if len(stages) > 1 else "")) if i == 0 else None)
        offset += steps.max()
    a2.axhline(1.0, color="k", lw=0.8, ls="--")
    a2.set_xlabel("env steps (millions" + (", stages end to end)" if len(stages) > 1 else ")"))
    a2.set_ylabel("position RMSE / imm2 (ratio)")
    a2.set_title("selection suite (training-range seeds)" + ("" if len(stages) > 1 else f": {stages[0][0]}"),
                 fontsize=10)
    a2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if returns is not None:
        axs[0].plot(np.asarray(returns[0]) / 1e6, returns[1], lw=1)
        axs[0].set_xlabel("env steps (millions)")
        axs[0].set_ylabel("mean episode return (reward units)")
        axs[0].set_title(f"training episodes: {stages[-1][0]}", fontsize=10)
    return fig


def suite_figures(suite, batch, runs, out_dir):
    """Write the suite's PNGs (see the module docstring) into ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    files = []
    for kind, make in (("errors", error_figure), ("trajectory", trajectory_figure), ("q", q_figure),
                       ("features", features_figure)):
        fig = make(suite, batch, runs)
        if fig is not None:
            files.append(_save(fig, out_dir / f"{suite}_{kind}.png"))
    return files


def _save(fig, path):
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
