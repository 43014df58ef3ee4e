"""Evaluation figures (matplotlib, PNG). Called by :func:`agents.evaluation.evaluate.write_plots` with the Agg backend.

Per suite:

* ``<suite>_errors.png``: position and velocity error against time (the errors the table's ``pos RMSE`` and ``vel
  m/s`` columns pool), the median over runs per tracker and, beside each, every tracker's median divided by the
  reference tracker's (``imm2``), so curves that lie on one another in metres separate. One shared spread: the
  reference's 10-90 % of runs (from 20 runs up; with fewer, its runs are drawn one by one). Where every run has the
  same look times (named scenarios) the curves are per look against the scenario clock and the truth's maneuvers
  are shaded; otherwise (random flights, random radars with their own scan periods, ADS-B flights of different
  lengths) each run's errors are averaged in common time bins since its track start. A tracker far below every
  other (the clairvoyant bound's velocity error) is left out of that panel and its legend entry says so;
* ``<suite>_trajectory.png``: run 0's exact true path with its plots and the radar; beside it a zoom on its first
  maneuver after the track start with every tracker's track (east/north for a turn; speed against time, with the
  measured range rate on a radial flight, for a speed change, which an east/north view cannot show);
* ``<suite>_q.png``: the q each q-choosing tracker used over time in run 0, against the truth's |a|;
* ``<suite>_features.png``: c_min and Adrian's turn-rate estimates over time in run 0, against the truth;
* ``<suite>_maneuver.png``: the IMMs' maneuver-mode probabilities and turn-rate estimates in run 0, against the
  truth, and each learned IMM's per-look parameters as factors of imm_cv_ct's tuned values (what it changed).

The truth's maneuver times, |a| and turn rate come from run 0's scenario when it is given (``scenario``: its exact
segment times, drawn as steps; :func:`agents.evaluation.suites.run_scenario`), else from the looks. The maneuver
intervals are :func:`maneuver_intervals_s` here and in the paper figures (:mod:`agents.reports.paper_figures`).

Each ``*_figure`` function returns the open figure (for tests and notebooks); :func:`suite_figures` saves and closes
them. The layout is fixed in inches (no layout engine: the main job draws about 30 figures) with the legends
outside the axes, so they never cover data.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from radar_env.common.units import G0_M_S2

from agents.evaluation.metrics import FEW_RUNS, errors, failed_runs

__all__ = ["suite_figures", "FIGURE_KINDS", "error_figure", "trajectory_figure", "q_figure", "features_figure",
           "maneuver_figure", "training_curve_figure", "shared_look_times", "binned_error_stats", "error_bin_width_s",
           "maneuver_intervals_s", "truth_model", "tracker_color"]

MAX_TIME_BINS = 200
"""Bins of the error curves at most (the bin width is the longest scan period or longer)."""

BAND_PERCENTILES = (10.0, 90.0)
"""The reference tracker's spread over runs in the error figure (drawn from ``FEW_RUNS`` runs up)."""

OFF_SCALE_FACTOR = 30.0
"""A tracker whose typical error is this many times below the median tracker's is left out of that panel."""

RATIO_PANEL_FACTOR = 2.5
"""The ratio panels show the trackers whose typical ratio to the reference lies within this factor of 1 (those
whose curves in metres overlap the reference's); the others are apart in the left panel already."""

_COLORS = {"policy": "tab:blue", "imm2": "tab:orange", "imm_cv_ct": "tab:green", "imm2_bizup": "tab:olive",
           "kf_tuned": "tab:red", "cmin": "tab:purple", "clairvoyant": "0.25", "kf_low": "tab:brown",
           "kf_high": "tab:pink", "oracle_q": "tab:cyan"}
_MORE_COLORS = ("tab:brown", "tab:pink", "tab:cyan", "tab:gray", "gold", "navy", "teal", "maroon", "darkviolet",
                "crimson", "steelblue", "yellowgreen", "sienna", "slategray")
"""The colours of the other trackers, in order of appearance: the main job draws 18 trackers, 11 of them without a
colour of their own, so each gets its own colour (8 repeated colours before 2026-12-06)."""
_BOUND_STYLE = {"clairvoyant": "--", "oracle_q": "--", "hindsight_q": "--", "hindsight_q_turn": "--"}
_TRUTH = {"color": "0.6", "lw": 4.0}      # drawn under the tracks, which stay visible
_TRUTH_ZOOM = {"color": "0.78", "lw": 7.0}   # a halo the tracks lie in
_SHADE = {"color": "0.9", "zorder": 0, "lw": 0}


def tracker_color(name, others=()):
    """The colour of tracker ``name`` in every figure (known trackers keep theirs; others take the next free one)."""
    if name in _COLORS:
        return _COLORS[name]
    used = {_COLORS.get(o) for o in others}
    free = [c for c in _MORE_COLORS if c not in used] or list(_MORE_COLORS)
    return free[sum(1 for o in others if o not in _COLORS) % len(free)]


def _colors(names):
    out = {}
    for n in names:
        out[n] = tracker_color(n, [o for o in out])
    return out


# ------------------------------------------------------------------------------------------------ layout
def _figure(width_in, height_in, nrows=1, ncols=1, left_in=0.9, right_in=0.25, top_in=0.45, bottom_in=0.6,
            hspace_in=0.35, wspace_in=0.75, **kw):
    """A figure and its axes grid with margins fixed in inches (a layout engine measures every text again, about
    half of a figure's drawing time; these figures are drawn by the dozen)."""
    fig = plt.figure(figsize=(width_in, height_in))
    axes_h = (height_in - top_in - bottom_in - hspace_in * (nrows - 1)) / nrows
    axes_w = (width_in - left_in - right_in - wspace_in * (ncols - 1)) / ncols
    axes = fig.subplots(nrows, ncols, squeeze=False, gridspec_kw=dict(
        left=left_in / width_in, right=1 - right_in / width_in, top=1 - top_in / height_in,
        bottom=bottom_in / height_in, hspace=hspace_in / axes_h, wspace=wspace_in / axes_w,
        **{k: v for k, v in kw.items() if k in ("height_ratios", "width_ratios")}),
        **{k: v for k, v in kw.items() if k in ("sharex", "sharey")})
    return fig, axes


def _bottom_legend(fig, handles, labels, ncol, y_in=0.08):
    """One legend for the whole figure, below the axes (the bottom margin leaves room for it)."""
    return fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, y_in / fig.get_figheight()),
                      ncol=ncol, fontsize=8, frameon=False, handlelength=2.2, columnspacing=1.4)


def _not_drawn(names, width_chars):
    """``(not drawn: a, b, c)`` in one line of at most ``width_chars`` characters: the names that fit, then how
    many more (every name is in the legend and the left panel; a second line would run into the panel above)."""
    for k in range(len(names), 0, -1):
        more = f" and {len(names) - k} more" if k < len(names) else ""
        text = f"(not drawn: {', '.join(names[:k])}{more})"
        if len(text) <= width_chars:
            return text
    return f"(not drawn: {len(names)} trackers)"


def _legend_rows(n, ncol):
    return max(1, math.ceil(n / ncol))


# ------------------------------------------------------------------------------------------------ the truth
def truth_model(scenario, batch, row=0):
    """``scenario`` if it is run ``row``'s truth (its states at the run's look times match the batch's truth to
    1 m and 0.1 m/s), else None: a figure never draws the path or the maneuver times of another flight."""
    if scenario is None or not hasattr(scenario, "states_at"):
        return None
    n = int(batch.n_looks[row])
    try:
        x = np.asarray(scenario.states_at(batch.t_s[row, :n]), float)
    except ValueError:
        return None
    d = np.abs(x - batch.truth[row, :n])
    return scenario if x.shape == (n, 4) and d[:, :2].max() < 1.0 and d[:, 2:].max() < 0.1 else None


def _segment_table(scenario):
    """``(edges_s (n + 1,), |a| m/s^2 (n,), turn rate rad/s (n,))`` of a segment scenario, or None."""
    segs = getattr(scenario, "segments", None)
    if not segs:
        return None
    edges = np.concatenate([[0.0], np.cumsum([s.duration_s for s in segs])])
    mid = 0.5 * (edges[:-1] + edges[1:])
    acc = np.hypot(*np.asarray(scenario.accelerations_at(mid), float).T)
    return edges, acc, np.array([s.turn_rate_rad_s for s in segs], float)


def _dense_times(scenario, t0, t1, step_s=1.0, max_points=20000):
    n = int(min(max_points, max(2, math.ceil((t1 - t0) / step_s) + 1)))
    return np.linspace(t0, t1, n)


def maneuver_intervals_s(scenario=None, t_s=None, maneuvering=None, t0=None, t1=None):
    """``[(start_s, end_s)]`` of the truth's maneuvers.

    From ``scenario``'s segment times when it has segments (exact: bizup2002's first turn is 290-330 s), else from
    its maneuver flag on a 1 s grid, else from per-look flags ``maneuvering`` at times ``t_s``: from the first
    flagged look to the next look (a maneuver that starts at a look lasts until at most the next look). ``t0``,
    ``t1`` clip the intervals (default: the scenario's duration, or the looks)."""
    if scenario is not None:
        tab = _segment_table(scenario)
        if tab is not None:
            edges, acc, _ = tab
            man = acc > float(getattr(scenario, "maneuver_threshold_m_s2", 0.0))
            t_grid, flags, end_at_next = edges, np.append(man, False), False
        else:
            t_grid = _dense_times(scenario, 0.0, float(scenario.duration_s))
            flags, end_at_next = np.asarray(scenario.maneuvering_at(t_grid), bool), True
    else:
        t_grid, flags, end_at_next = np.asarray(t_s, float), np.asarray(maneuvering, bool), True
    on = np.flatnonzero(flags & ~np.r_[False, flags[:-1]])
    off = np.flatnonzero(flags & ~np.r_[flags[1:], False])
    ends = np.minimum(off + 1, len(t_grid) - 1) if end_at_next else off + 1
    lo = -np.inf if t0 is None else t0
    hi = np.inf if t1 is None else t1
    out = [(max(float(t_grid[a]), lo), min(float(t_grid[b]), hi)) for a, b in zip(on, ends)]
    return [(a, b) for a, b in out if b > a]


def _shade(ax, intervals, label=None):
    for i, (a, b) in enumerate(intervals):
        ax.axvspan(a, b, **_SHADE, label=label if i == 0 else None)


def _truth_steps(ax, scenario, batch, quantity, t0, t1, floor=None, label=None):
    """Draw the truth's |a| (g) or turn rate (deg/s) in run 0 at its real times: steps at the segment times of a
    segment scenario, a 1 s line for a sampled trajectory, markers at the looks without a scenario."""
    tab = _segment_table(scenario) if scenario is not None else None
    conv = (1.0 / G0_M_S2) if quantity == "accel" else np.degrees(1.0)
    clip = (lambda v: np.maximum(v, floor)) if floor is not None else (lambda v: v)   # noqa: E731
    if tab is not None:
        edges, acc, w = tab
        vals = (acc if quantity == "accel" else w) * conv
        keep = (edges[1:] > t0) & (edges[:-1] < t1)
        e = np.clip(np.concatenate([edges[:-1][keep], edges[1:][keep][-1:]]), t0, t1)
        return ax.stairs(clip(vals[keep]), e, baseline=None, **_TRUTH, label=label)
    if scenario is not None:
        t = _dense_times(scenario, t0, t1)
        v = (np.hypot(*np.asarray(scenario.accelerations_at(t), float).T) if quantity == "accel"
             else np.asarray(scenario.turn_rates_at(t), float)) * conv
        return ax.plot(t, clip(v), **_TRUTH, label=label)[0]
    n = int(batch.n_looks[0])
    v = (np.hypot(*batch.truth_accel_m_s2[0, :n].T) if quantity == "accel" else batch.truth_turn_rate_rad_s[0, :n])
    return ax.plot(batch.t_s[0, :n], clip(v * conv), "s", color="0.55", ms=3,
                   label=(label or "truth") + " (at the looks)")[0]


def _run0_intervals(batch, scenario):
    n = int(batch.n_looks[0])
    t = batch.t_s[0, :n]
    if scenario is not None:
        return maneuver_intervals_s(scenario, t0=float(t[0]), t1=float(t[-1]))
    return maneuver_intervals_s(None, t, batch.maneuvering[0, :n])


# ------------------------------------------------------------------------------------------------ statistics
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
    """Bins (or looks) with fewer runs than this are hidden: a median over 1-2 runs is noise."""
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


def _nanquantile0(a, qs):
    """Quantiles (``qs`` in [0, 1]) over axis 0 ignoring NaN, as ``np.nanquantile(a, qs, axis=0)`` (linear
    interpolation) but in one sort: numpy's nanquantile loops over the columns."""
    s = np.sort(a, axis=0)                               # NaN sorts last
    n = np.sum(np.isfinite(a), axis=0)
    out = np.full((len(qs), a.shape[1]), np.nan)
    cols = np.arange(a.shape[1])
    ok = n > 0
    for i, q in enumerate(qs):
        pos = q * np.maximum(n - 1, 0)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
        f = pos - lo
        v = s[lo, cols] * (1 - f) + s[hi, cols] * f
        out[i] = np.where(ok, np.where(f > 0, v, s[lo, cols]), np.nan)
    return out


def _binned_per_run(t_since_start_s, err, width_s, min_runs):
    """Per-run means of ``err`` (B, K; NaN where not used) in bins ``[i w, (i + 1) w)`` of ``t_since_start_s``:
    ``(centres_s, per_run (B, bins))``, bins with fewer than ``min_runs`` runs left out."""
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
    return (np.nonzero(keep)[0] + 0.5) * width_s, per_run[:, keep]


def binned_error_stats(t_since_start_s, err, width_s, min_runs):
    """Per-run means of ``err`` (B, K; NaN where not used) in bins ``[i w, (i + 1) w)`` of ``t_since_start_s``
    (B, K), then over the runs present in each bin: centre (s), median and the :data:`BAND_PERCENTILES`. Bins with
    fewer than ``min_runs`` runs are left out, so the returned centres are strictly increasing."""
    centres, per_run = _binned_per_run(t_since_start_s, err, width_s, min_runs)
    if not centres.size:
        return centres, np.empty(0), np.empty(0), np.empty(0)
    med, lo, hi = _nanquantile0(per_run, (0.5, BAND_PERCENTILES[0] / 100, BAND_PERCENTILES[1] / 100))
    return centres, med, lo, hi


def _error_series(batch, runs, shared, width, min_runs):
    """Per tracker: ``(x_s, per_run (B, n) position error, per_run velocity error, failed runs)`` on the figure's
    time axis: per look (shared look times, ``width`` None), per ``width`` s bin of the scenario clock (shared,
    long runs), or per bin since each run's track start."""
    out = {}
    longest = int(np.argmax(batch.n_looks))
    for name, run in runs.items():
        used = _used(batch, run)
        ep, ev = errors(batch, run)
        # a failed run (non-finite estimate, as the metrics score it) must not vanish from the median look by look
        # as a NaN would: it is left out whole, and the legend says how many were
        failed = failed_runs(batch, run, used)
        keep = used & ~failed[:, None]
        ep, ev = np.where(keep, ep, np.nan), np.where(keep, ev, np.nan)
        if shared and width is None:
            ok = np.sum(np.isfinite(ep), axis=0) >= min_runs
            out[name] = (batch.t_s[longest][ok], ep[:, ok], ev[:, ok], failed)
        else:
            k0 = np.minimum(np.asarray(run.start_index), batch.t_s.shape[1] - 1)
            t_start = 0.0 if shared else np.take_along_axis(batch.t_s, k0[:, None], axis=1)
            ts = np.where(used, batch.t_s - t_start, np.nan)
            x, pp = _binned_per_run(ts, ep, width, min_runs)
            _, pv = _binned_per_run(ts, ev, width, min_runs)
            out[name] = (x, pp, pv, failed)
    return out


def _plain_log_ticks(ax):
    """Log-axis tick labels as plain numbers (0.1, 2, 500), minor ones (2, 5 x 10^k) labelled only where the
    axis spans less than two decades."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator
    lo, hi = ax.get_ylim()
    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_locator(LogLocator(base=10))
    ax.yaxis.set_major_formatter(fmt)
    if hi / lo < 100:
        ax.yaxis.set_minor_locator(LogLocator(base=10, subs=(2.0, 5.0)))
        ax.yaxis.set_minor_formatter(fmt)
    else:                                 # no minor ticks: each costs a line and a label to lay out
        ax.yaxis.set_minor_locator(NullLocator())


def _typical(y):
    y = y[np.isfinite(y) & (y > 0)]
    return float(np.median(y)) if y.size else np.nan


# ------------------------------------------------------------------------------------------------ figures
def error_figure(suite, batch, runs, scenario=None, reference="imm2"):
    """Position and velocity error against time (see the module docstring for the time axis and the panels).
    Returns the figure.

    A tracker's failed runs (:func:`agents.evaluation.metrics.failed_runs`: a non-finite estimate or covariance
    after its track start) are left out of its curves and counted in its legend entry."""
    B = batch.batch_size
    shared = shared_look_times(batch)
    min_runs = _min_runs(B)
    width = error_bin_width_s(batch)
    per_look = shared and int(batch.n_looks.max()) <= 2 * MAX_TIME_BINS     # else too dense to read: binned
    series = _error_series(batch, runs, shared, None if per_look else width, min_runs)
    names = list(runs)
    ref = reference if reference in runs else next((n for n in names if n not in _BOUND_STYLE), names[0])
    colors = _colors(names)
    panels = []                                   # per row: quantity, unit, medians, trackers off the scale
    notes = {}
    for row, (qty, unit) in enumerate((("position", "m"), ("velocity", "m/s"))):
        med = {n: _nanquantile0(s[1 + row], (0.5,))[0] for n, s in series.items()}
        levels = {n: _typical(m) for n, m in med.items()}
        mid = np.nanmedian([v for v in levels.values() if np.isfinite(v)] or [np.nan])
        off = {n for n, v in levels.items() if np.isfinite(v) and v < mid / OFF_SCALE_FACTOR and n != ref}
        for n in off:
            notes.setdefault(n, []).append(f"{qty} error {levels[n]:.2g} {unit}, far below the others: not drawn "
                                           f"in the {qty} panels")
        panels.append((qty, unit, med, off))
    intervals = []
    if shared:
        k = int(np.argmax(batch.n_looks))
        intervals = maneuver_intervals_s(truth_model(scenario, batch, k), batch.t_s[k], batch.maneuvering[k])
    # the legend's entries, known before the figure so that its bottom margin fits them
    labels = {}
    for n in names:
        failed = int(series[n][3].sum())
        labels[n] = n + (f" ({failed} failed run(s) left out)" if failed else "") + "".join(
            f"; {t}" for t in notes.get(n, []))
    band_label = (f"{ref}: {BAND_PERCENTILES[0]:g}-{BAND_PERCENTILES[1]:g} % of runs" if B >= FEW_RUNS else
                  f"{ref}: each of its {B} runs (fewer than {FEW_RUNS}: no percentile band)")
    n_entries = len(names) + 1 + bool(intervals)
    ncol = 4 if max(len(s) for s in list(labels.values()) + [band_label]) <= 40 else 2
    xlabel_lines = 2 if shared else 3
    fig, axes = _figure(13.0, 7.2 + 0.2 * _legend_rows(n_entries, ncol), 2, 2, sharex=True, width_ratios=(3, 2),
                        bottom_in=0.55 + 0.16 * xlabel_lines + 0.2 * _legend_rows(n_entries, ncol), top_in=0.6,
                        hspace_in=0.45, wspace_in=0.85, left_in=1.05)
    for row, (qty, unit, med, off) in enumerate(panels):
        ax, axr = axes[row]
        x_ref, per_ref = series[ref][0], series[ref][1 + row]
        if B >= FEW_RUNS:
            lo, hi = _nanquantile0(per_ref, [p / 100 for p in BAND_PERCENTILES])
            ax.fill_between(x_ref, lo, hi, color=colors[ref], alpha=0.18, lw=0, label=band_label)
            spread = [lo, hi]
        else:
            ax.plot(x_ref, per_ref.T, color=colors[ref], lw=0.5, alpha=0.3)
            ax.plot([], [], color=colors[ref], lw=0.5, alpha=0.6, label=band_label)
            spread = [per_ref]
        shown = [n for n in names if n not in off]
        near, rv = [], []
        for n in shown:
            x, m = series[n][0], med[n]
            ax.plot(x, m, color=colors[n], ls=_BOUND_STYLE.get(n, "-"), lw=1.6 if n == ref else 1.2, label=labels[n])
            if n == ref or not x.size or not x_ref.size:
                continue
            with np.errstate(invalid="ignore", divide="ignore"):
                r = m / np.interp(x, x_ref, med[ref])
            if 1 / RATIO_PANEL_FACTOR <= _typical(r) <= RATIO_PANEL_FACTOR:     # the curves that overlap it
                axr.plot(x, r, color=colors[n], ls=_BOUND_STYLE.get(n, "-"), lw=1.1)
                near.append(n)
                rv.append(r[np.isfinite(r) & (r > 0)])
        axr.axhline(1.0, color=colors[ref], lw=1.6)
        ys = np.concatenate([med[n][np.isfinite(med[n]) & (med[n] > 0)] for n in shown]
                            + [np.ravel(s)[np.isfinite(np.ravel(s)) & (np.ravel(s) > 0)] for s in spread])
        if ys.size:
            lo_y, hi_y = np.percentile(ys, [0.5, 99.8]) if ys.size > 50 else (ys.min(), ys.max())
            ax.set_ylim(lo_y / 1.6, hi_y * 1.6)
        rv = np.concatenate(rv) if rv else np.empty(0)
        m = max(float(np.exp(np.abs(np.log(rv)).max())) * 1.1 if rv.size else 1.25, 1.25)
        ax.set_yscale("log")
        axr.set_yscale("log")
        axr.set_ylim(1 / m, m)
        for a in (ax, axr):
            _plain_log_ticks(a)
            a.grid(alpha=0.25, which="major")
            _shade(a, intervals, "truth maneuvering (the same in every run)" if a is axes[0, 0] else None)
        sym = "p" if row == 0 else "v"
        ax.set_ylabel(f"median {qty} error\n|{sym}_est - {sym}| ({unit})")
        axr.set_ylabel(f"median / {ref}'s median (ratio)")
        far = [n for n in shown if n != ref and n not in near]
        width_chars = int(axr.get_position().width * fig.get_figwidth() / 0.062)   # 8 pt characters per line
        axr.set_title(f"{qty}: the trackers within a factor {RATIO_PANEL_FACTOR:g} of {ref}"
                      + (f"\n{_not_drawn(far, width_chars)}" if far else ""), fontsize=8, color="0.3", y=1.0, pad=5)
    clock = "scenario start" if shared else "track start"
    if shared:
        how = ("per look" if per_look else f"each run's errors averaged in {width:g} s bins") + (
            f"; {'looks' if per_look else 'bins'} with fewer than {min_runs} of {B} runs hidden")
    else:
        how = (f"each run aligned at its track start, its errors averaged in {width:g} s bins;\nbins with fewer "
               f"than {min_runs} of {B} runs hidden; maneuver times differ per run: not shaded")
    axes[1, 0].set_xlabel(f"time since {clock} (s)\n{how}", fontsize=9)
    axes[1, 1].set_xlabel(f"time since {clock} (s)")
    fig.suptitle(f"{suite}: median error over {B} runs; right: each tracker's median divided by {ref}'s "
                 "(below 1: better)", fontsize=11, y=1 - 0.12 / fig.get_figheight(), va="top")
    h, lab = axes[0, 0].get_legend_handles_labels()
    for n in names:                        # a tracker left out of the top panel still gets its legend entry
        if n in panels[0][3]:
            h.append(plt.Line2D([], [], color=colors[n], ls=_BOUND_STYLE.get(n, "-")))
            lab.append(labels[n])
    _bottom_legend(fig, h, lab, ncol=ncol, y_in=0.05)
    return fig


def _maneuver_window(t_s, intervals, k_start, max_looks=20):
    """Run 0's first maneuver that begins at or after the track start (look ``k_start``; else the first one).

    Returns ``(sel, (t_start_s, t_end_s), (t_lo_s, t_hi_s))`` or None if the run never maneuvers: ``sel`` the looks
    from half the maneuver's duration before it to its duration after it (at least 3 and 5 look intervals: where
    the tracks lag and overshoot; a maneuver longer than ``max_looks`` looks is shown from its start for that
    many), ``t_lo_s``, ``t_hi_s`` that window's ends."""
    if not intervals:
        return None
    t_track = t_s[min(k_start, len(t_s) - 1)]
    a, b = next(((i, j) for i, j in intervals if i >= t_track), intervals[0])
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    shown = min(b - a, max_looks * dt)
    t_lo, t_hi = a - max(3 * dt, 0.5 * shown), a + shown + max(5 * dt, shown)
    return (t_s >= t_lo) & (t_s <= t_hi), (float(a), float(b)), (float(t_lo), float(t_hi))


def _zoom_box(points_km):
    """``((x0, x1, y0, y1), elongated)``: a box (km) around the finite rows of the ``(n, 2)`` arrays
    ``points_km``, with a margin; square unless it is too long and thin to draw east and north to one scale."""
    p = np.concatenate(points_km)
    p = p[np.all(np.isfinite(p), axis=1)]
    lo, hi = p.min(axis=0), p.max(axis=0)
    size = np.maximum(hi - lo, 0.05)                       # km; a straight leg still gets some height
    elongated = bool(size.max() > 4 * size.min())
    if not elongated:
        size[:] = size.max()
    half = 0.5 * size * 1.15
    c = 0.5 * (lo + hi)
    return (c[0] - half[0], c[0] + half[0], c[1] - half[1], c[1] + half[1]), elongated


def _exact_path(scenario, t0, t1):
    """Times and states of the true path between ``t0`` and ``t1``: every segment boundary plus one point per
    degree of turn for a segment scenario, a 1 s grid for a sampled trajectory."""
    tab = _segment_table(scenario)
    if tab is None:
        t = _dense_times(scenario, t0, t1)
    else:
        edges, _, w = tab
        pts = [np.array([t0, t1])]
        for e0, e1, wi in zip(edges[:-1], edges[1:], w):
            a, b = max(e0, t0), min(e1, t1)
            if b > a:
                n = max(2, int(math.ceil(abs(wi) * (b - a) / math.radians(1.0))) + 1)
                pts.append(np.linspace(a, b, n))
        t = np.unique(np.concatenate(pts))
    return t, np.asarray(scenario.states_at(t), float)


def _is_turn(scenario, batch, window):
    """True if run 0 turns in the maneuver ``window`` (s), False if it only changes speed there."""
    a, b = window
    if scenario is not None:
        t = np.linspace(a, b, 50)[1:-1]
        return bool(np.any(np.abs(np.asarray(scenario.turn_rates_at(t), float)) > 1e-9))
    n = int(batch.n_looks[0])
    t = batch.t_s[0, :n]
    m = (t >= a) & (t <= b)
    return bool(np.any(np.abs(batch.truth_turn_rate_rad_s[0, :n][m]) > 1e-9))


def trajectory_figure(suite, batch, runs, scenario=None):
    """Run 0: its exact true path, its plots and the radar sites; beside it a zoom on its first maneuver after the
    track start with every tracker's track (see the module docstring). Returns the figure."""
    n = int(batch.n_looks[0])
    t = batch.t_s[0, :n]
    sc = truth_model(scenario, batch)
    if sc is not None:
        tt, states = _exact_path(sc, float(t[0]), float(t[-1]))
    else:
        tt, states = t, batch.truth[0, :n]
    path = states[:, :2] / 1e3
    z = batch.z_m[0, :n] / 1e3
    sites = np.unique(batch.site_xy_m[0, :n], axis=0) / 1e3
    k_start = int(min(int(r.start_index[0]) for r in runs.values())) if runs else 0
    intervals = _run0_intervals(batch, sc)
    colors = _colors(list(runs))
    win = _maneuver_window(t, intervals, k_start)
    turn = win is not None and _is_turn(sc, batch, win[1])
    fig, axes = _figure(14.0 if win else 8.0, 7.4, 1, 2 if win else 1, bottom_in=1.2, top_in=0.5, wspace_in=0.9,
                        left_in=0.85)
    axes = axes[0]
    ax = axes[0]
    dense = n > 1500
    # the plots over the path; on a long flight the path over them (they would hide it), both visible
    ax.plot(path[:, 0], path[:, 1], "-", color="k", lw=0.6 if dense else 0.8, label="truth (exact path)",
            zorder=4 if dense else 2)
    ax.plot(z[:, 0], z[:, 1], "o", color="tab:blue", ms=2.0 if dense else 2.8, alpha=0.45 if dense else 0.9, mew=0,
            label="plots (radar measurements)", zorder=3)
    ax.plot(sites[:, 0], sites[:, 1], "^", color="tab:red", ms=10, label="radar", zorder=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_title(f"{suite}: run 0, truth and plots ({t[-1] - t[0]:.0f} s, {n} looks)", fontsize=10, y=1.0, pad=5)
    handles, labels = ax.get_legend_handles_labels()
    if win:
        sel, (ta, tb), (tlo, thi) = win
        az = axes[1]
        span = f"{ta:.0f}-{tb:.0f} s" + (" (its start)" if tb > thi else "")
        if turn:
            in_win = (tt >= tlo) & (tt <= thi)
            (x0, x1, y0, y1), elongated = _zoom_box([path[in_win]] + [r.x[0, :n, :2][sel] / 1e3 for r in runs.values()])
            az.plot(path[in_win, 0], path[in_win, 1], **_TRUTH_ZOOM, zorder=1)
            for name, run in runs.items():
                x = run.x[0, :n][sel] / 1e3
                az.plot(x[:, 0], x[:, 1], color=colors[name], ls=_BOUND_STYLE.get(name, "-"), lw=1.1,
                        marker=".", ms=3, label=name, zorder=2)
            az.plot(z[sel, 0], z[sel, 1], "o", mfc="none", mec="tab:blue", ms=5, mew=0.9, zorder=3)
            az.set_xlim(x0, x1)
            az.set_ylim(y0, y1)
            if not elongated:
                az.set_aspect("equal", adjustable="box")
            az.set_xlabel("east (km)")
            az.set_ylabel("north (km)")
            az.set_title(f"zoom (box at left) on the turn at {span}\ntruth, plots and tracks from {tlo:.0f} to "
                         f"{thi:.0f} s" + ("; east and north NOT to the same scale" if elongated else ""),
                         fontsize=10, y=1.0, pad=5)
            ax.indicate_inset((x0, y0, x1 - x0, y1 - y0), edgecolor="tab:blue", lw=1.2)
        else:
            _speed_view(az, batch, runs, sc, sel, (tlo, thi), intervals, colors)
            az.set_title(f"speed around the speed change at {span}\n(a change along the flight path: invisible in "
                         "an east/north view)", fontsize=10, y=1.0, pad=5)
        h2, l2 = az.get_legend_handles_labels()
        handles += h2
        labels += l2
        handles.append(plt.Line2D([], [], **(_TRUTH_ZOOM if turn else _TRUTH)))
        labels.append("truth (in the zoom)")
    _bottom_legend(fig, handles, labels, ncol=min(6, len(labels)), y_in=0.05)
    return fig


def _speed_view(ax, batch, runs, sc, sel, window, intervals, colors):
    """Speed against time in the zoom window: the truth, each tracker's |v_est| and, when the flight is radial (its
    range rate within 10 % of its speed), the plots' measured range rate."""
    n = int(batch.n_looks[0])
    t = batch.t_s[0, :n]
    tlo, thi = window
    if sc is not None:
        td = _dense_times(sc, tlo, thi, step_s=0.25)
        v = np.asarray(sc.states_at(td), float)
        ax.plot(td, np.hypot(v[:, 2], v[:, 3]), **_TRUTH, zorder=1)
    else:
        ax.plot(t[sel], np.hypot(*batch.truth[0, :n][sel, 2:].T), **_TRUTH, zorder=1)
    _shade(ax, [(max(a, tlo), min(b, thi)) for a, b in intervals if b > tlo and a < thi], "truth maneuvering")
    for name, run in runs.items():
        x = run.x[0, :n][sel]
        ax.plot(t[sel], np.hypot(x[:, 2], x[:, 3]), color=colors[name], ls=_BOUND_STYLE.get(name, "-"), lw=1.1,
                marker=".", ms=3, label=name, zorder=2)
    tr = batch.truth[0, :n][sel]
    rel = tr[:, :2] - batch.site_xy_m[0, :n][sel]
    rdot = np.sum(rel * tr[:, 2:], axis=1) / np.hypot(rel[:, 0], rel[:, 1])
    if np.all(np.abs(np.abs(rdot) - np.hypot(tr[:, 2], tr[:, 3])) <= 0.1 * np.hypot(tr[:, 2], tr[:, 3])):
        rv = batch.radial_velocity_m_s[0, :n][sel]
        ax.plot(t[sel], np.abs(rv), "o", mfc="none", mec="tab:blue", ms=5, mew=0.9, zorder=3,
                label="plots: measured range rate (radial flight)")
    ax.set_xlim(tlo, thi)
    ax.set_xlabel("time since scenario start (s)")
    ax.set_ylabel("speed (m/s)")
    ax.grid(alpha=0.25)


def q_figure(suite, batch, runs, scenario=None):
    """The q each q-choosing tracker used in run 0 against the truth's |a|, in g, log scale. Values below the floor
    (the truth's 0 on straight legs, a q of 0) are drawn on the labelled floor line; a correction's (a run with the
    ``correction_m`` series, such as ``policy_window``) is its base's q and says so. None if no tracker has a q."""
    q_runs = {k: r for k, r in runs.items() if np.any(np.isfinite(r.q_m_s2[0]))}
    if not q_runs:
        return None
    n = int(batch.n_looks[0])
    tt = batch.t_s[0, :n]
    sc = truth_model(scenario, batch)
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
    colors = _colors(list(runs))
    fig, axes = _figure(12.0, 4.8, bottom_in=1.25, top_in=0.45)
    ax = axes[0, 0]
    _shade(ax, _run0_intervals(batch, sc), "truth maneuvering")
    _truth_steps(ax, sc, batch, "accel", float(tt[0]), float(tt[-1]), floor=floor, label="true |a|")
    for name, q in qs.items():
        ax.step(tt, np.where(np.isfinite(q), np.maximum(q, floor), np.nan), where="pre", color=colors[name],
                ls=_BOUND_STYLE.get(name, "-"), lw=1.6 if name in _BOUND_STYLE else 1.1,
                label=f"q of {name}" + (" (its base's)" if "correction_m" in q_runs[name].extra else ""))
    ax.axhline(floor, color="0.3", ls=":", lw=1, label=f"0 g, and anything below {floor:g} g, is drawn on this line")
    ax.set_yscale("log")
    ax.set_ylim(floor / 2, top * 2)
    _plain_log_ticks(ax)
    ax.set_xlim(tt[0], tt[-1])
    ax.set_xlabel("time since scenario start (s)")
    ax.set_ylabel("|a| and q (g)")
    ax.set_title(f"{suite}: the process-noise level q each tracker chose in run 0 (from its track start), and the "
                 "truth's acceleration", fontsize=10, y=1.0, pad=5)
    h, lab = ax.get_legend_handles_labels()
    _bottom_legend(fig, h, lab, ncol=4, y_in=0.05)
    return fig


def features_figure(suite, batch, runs, scenario=None):
    """c_min and Adrian's turn-rate estimates in run 0 against the truth. None if no tracker records them."""
    feat_run = next((r for r in runs.values() if "c_min_g" in r.extra), None)
    if feat_run is None:
        return None
    n = int(batch.n_looks[0])
    tt = batch.t_s[0, :n]
    sc = truth_model(scenario, batch)
    intervals = _run0_intervals(batch, sc)
    fig, axes = _figure(12.0, 6.8, 2, 1, sharex=True, bottom_in=1.2, top_in=0.45, hspace_in=0.25)
    a0, a1 = axes[:, 0]
    for ax in (a0, a1):
        _shade(ax, intervals, "truth maneuvering" if ax is a0 else None)
    _truth_steps(a0, sc, batch, "accel", float(tt[0]), float(tt[-1]), label="true |a|")
    a0.plot(tt, feat_run.extra["c_min_g"][0, :n], ".-", color="tab:purple", lw=0.8, ms=3, label="c_min")
    a0.axhline(1.0, color="tab:red", ls=":", label="the c_min tracker's threshold, 1 g")
    a0.set_ylabel("acceleration (g)")
    _truth_steps(a1, sc, batch, "turn", float(tt[0]), float(tt[-1]), label="true turn rate")
    a1.plot(tt, feat_run.extra["turn_rate_alg1_deg_s"][0, :n], color="tab:blue", lw=0.9, label="Adrian alg. 1")
    a1.plot(tt, feat_run.extra["turn_rate_alg2_deg_s"][0, :n], color="tab:orange", lw=0.9, label="Adrian alg. 2")
    a1.set_ylabel("turn rate (deg/s, + right)")
    a1.set_xlabel("time since scenario start (s)")
    a1.set_xlim(tt[0], tt[-1])
    for ax in (a0, a1):
        ax.grid(alpha=0.25)
    a0.set_title(f"{suite}: maneuver features in run 0 (as tracker {feat_run.name} computed them)", fontsize=10,
                 y=1.0, pad=5)
    h0, l0 = a0.get_legend_handles_labels()
    h1, l1 = a1.get_legend_handles_labels()
    _bottom_legend(fig, h0 + h1, l0 + l1, ncol=4, y_in=0.05)
    return fig


MANEUVER_WINDOW_LOOKS = 300
"""The maneuver figure of a longer run 0 shows this many looks (from a little before its first maneuver)."""
_SWITCH = {"p_stay_cv": "CV -> other", "p_stay_ct": "CT -> other", "p_stay_high": "high -> other"}
_PARAM_STYLE = {  # a mode's noise (solid) and its switch probability (dashed) share a colour
    "q_cv_g": ("tab:blue", "-"), "p_stay_cv": ("tab:blue", "--"), "q_ct_g": ("tab:green", "-"),
    "p_stay_ct": ("tab:green", "--"), "sigma_omega_deg_s15": ("tab:purple", ":"), "q_high_g": ("tab:red", "-"),
    "p_stay_high": ("tab:red", "--")}


def maneuver_figure(suite, batch, runs, scenario=None):
    """The IMMs' maneuver detection in run 0: every tracker's maneuver-mode probability and turn-rate estimate
    against the truth, and each learned IMM's per-look parameters as factors of imm_cv_ct's tuned values (a noise:
    value / tuned; a stay probability: its switch probability ``1 - p`` / the tuned one). None if no tracker records
    a maneuver probability."""
    from baselines.imm_cv_ct_runner import tuned_imm_cv_ct_spec
    from radar_env.filters.imm_cv_ct import look_parameter_names, look_parameter_vector

    man = {k: r for k, r in runs.items() if "maneuver_probability" in r.extra}
    if not man:
        return None
    learned = {k: r for k, r in man.items() if any(e.startswith("param_") for e in r.extra)}
    turn = {k: r for k, r in man.items() if "turn_rate_deg_s" in r.extra}
    n = int(batch.n_looks[0])
    tt = batch.t_s[0, :n]
    sc = truth_model(scenario, batch)
    intervals = _run0_intervals(batch, sc)
    colors = _colors(list(runs))
    nrows = 2 + len(learned)
    # a long flight (an ADS-B one: thousands of looks) shows MANEUVER_WINDOW_LOOKS looks from a little before its
    # first maneuver after the track start: the per-look lines of the whole flight would be a solid block
    k0, k1 = 0, n
    if n > MANEUVER_WINDOW_LOOKS:
        start = int(min(r.start_index[0] for r in man.values()))
        later = np.flatnonzero(batch.maneuvering[0, start:n])
        k0 = max(start, start + int(later[0]) - MANEUVER_WINDOW_LOOKS // 10) if later.size else start
        k1 = min(n, k0 + MANEUVER_WINDOW_LOOKS)
        k0 = max(0, k1 - MANEUVER_WINDOW_LOOKS)
    fig, axes = _figure(12.0, 2.6 * nrows + 1.6, nrows, 1, sharex=True, bottom_in=1.3, top_in=0.45, hspace_in=0.3,
                        left_in=1.25, right_in=2.0 if learned else 0.25)   # room for 1e5's tick labels
    axes = axes[:, 0]
    for i, ax in enumerate(axes):
        _shade(ax, intervals, "truth maneuvering" if i == 0 else None)
        ax.grid(alpha=0.25)
    a0, a1 = axes[0], axes[1]
    for name, r in man.items():
        a0.plot(tt[k0:k1], r.extra["maneuver_probability"][0, k0:k1], color=colors[name], lw=1.1, label=name)
    a0.set_ylim(-0.03, 1.03)
    a0.set_ylabel("P(maneuver modes)")
    _truth_steps(a1, sc, batch, "turn", float(tt[k0]), float(tt[k1 - 1]), label="true turn rate")
    for name, r in turn.items():
        a1.plot(tt[k0:k1], r.extra["turn_rate_deg_s"][0, k0:k1], color=colors[name], lw=1.0)
    a1.set_ylabel("turn rate (deg/s, + right)")
    spec = tuned_imm_cv_ct_spec()
    base = dict(zip(look_parameter_names(spec), look_parameter_vector(spec)))
    for ax, (name, r) in zip(axes[2:], learned.items()):
        for p, v0 in base.items():
            v = r.extra.get(f"param_{p}")
            if v is None:
                continue
            v = v[0, k0:k1]
            f = (1.0 - v) / (1.0 - v0) if p in _SWITCH else v / v0
            lab = f"switch {_SWITCH[p]}" if p in _SWITCH else p
            color, ls = _PARAM_STYLE.get(p, ("0.3", "-."))
            ax.plot(tt[k0:k1], f, color=color, ls=ls, lw=1.0, label=lab)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_yscale("log")
        _plain_log_ticks(ax)
        ax.set_ylabel(f"{name}:\nfactor of imm_cv_ct's")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, frameon=False)
    axes[-1].set_xlim(tt[k0], tt[k1 - 1])
    axes[-1].set_xlabel("time since scenario start (s)")
    a0.set_title(f"{suite}: maneuver detection of the IMMs in run 0 (mode probability, turn rate)"
                 + (" and the learned IMMs' parameters" if learned else "")
                 + (f"; looks {k0}-{k1 - 1} of {n}" if (k0, k1) != (0, n) else ""), fontsize=10, y=1.0, pad=5)
    h0, l0 = a0.get_legend_handles_labels()
    h1, l1 = a1.get_legend_handles_labels()
    _bottom_legend(fig, h0 + h1, l0 + l1, ncol=5, y_in=0.05)
    return fig


def training_curve_figure(stages, returns=None):
    """Selection-suite ratios (position RMSE / imm2) over env steps, one or more training stages in order.

    Args:
        stages: list of ``(label, selection_history, selected_timesteps_or_None)``; the stages are drawn end to
            end (a fine-tuning stage starts from the previous stage's selected checkpoint, marked on its curve).
            The first line of a label names the stage inside the axes; the rest goes under the figure.
        returns: optional ``(steps, mean_episode_return)`` of the (last) stage's TensorBoard log.
    Returns the figure.
    """
    ncols = 2 if returns is not None else 1
    multi = len(stages) > 1
    fig, axs = _figure(7.0 * ncols + 3.4, 4.9 if multi else 4.4, 1, ncols, right_in=3.0, top_in=0.75,
                       bottom_in=1.25 if multi else 0.6, wspace_in=0.9)
    axs = axs[0]
    a2 = axs[-1]
    offset, colors, bounds = 0, {}, []
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
        bounds.append((offset, offset + steps.max(), label))
        if chosen is not None:
            a2.axvline((offset + chosen) / 1e6, color="tab:red", ls=":", lw=1.2,
                       label=("selected checkpoint" + (" of each stage\n(the next stage starts from it)"
                                                        if multi else "")) if i == 0 else None)
        offset += steps.max()
    a2.axhline(1.0, color="k", lw=0.8, ls="--")
    if multi:
        lo, hi = a2.get_ylim()
        a2.set_ylim(lo, hi + 0.12 * (hi - lo))               # headroom for the stage names, inside the axes
        for j, (s0, s1, label) in enumerate(bounds):
            if j:
                a2.axvline(s0 / 1e6, color="0.5", lw=0.8)
            a2.text(0.5 * (s0 + s1) / 1e6, 0.985, label.split("\n")[0].split(":")[0], ha="center", va="top",
                    transform=a2.get_xaxis_transform(), fontsize=8, color="0.25", clip_on=True)
        fig.text(0.01, 0.12 / fig.get_figheight(), "\n".join(" ".join(lab.split("\n")) for _, _, lab in bounds),
                 fontsize=8, color="0.25", va="bottom", ha="left")
    a2.set_xlabel("env steps (millions" + (", stages end to end)" if multi else ")"))
    a2.set_ylabel("position RMSE / imm2 (ratio)")
    a2.set_title("selection suite (training-range seeds)" + ("" if multi else f": {stages[0][0]}"), fontsize=10,
                 y=1.0, pad=5)
    a2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0, frameon=False)
    if returns is not None:
        axs[0].plot(np.asarray(returns[0]) / 1e6, returns[1], lw=1)
        axs[0].set_xlabel("env steps (millions)")
        axs[0].set_ylabel("mean episode return (reward units)")
        axs[0].set_title(f"training episodes: {stages[-1][0]}", fontsize=10, y=1.0, pad=5)
    return fig


FIGURE_KINDS = {"errors": error_figure, "trajectory": trajectory_figure, "q": q_figure, "features": features_figure,
                "maneuver": maneuver_figure}
"""The figures of a suite, by the file name's suffix."""


def suite_figures(suite, batch, runs, out_dir, scenario=None, kinds=tuple(FIGURE_KINDS)):
    """Write the suite's PNGs (see the module docstring) into ``out_dir``; returns their paths.

    Args:
        scenario: run 0's truth model (:func:`agents.evaluation.suites.run_scenario`), for the exact path and
            maneuver times; None: the looks' samples.
        kinds: which of :data:`FIGURE_KINDS` to draw."""
    out_dir = Path(out_dir)
    files = []
    for kind in kinds:
        fig = FIGURE_KINDS[kind](suite, batch, runs, scenario=scenario)
        if fig is not None:
            files.append(_save(fig, out_dir / f"{suite}_{kind}.png"))
    return files


def _save(fig, path):
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
