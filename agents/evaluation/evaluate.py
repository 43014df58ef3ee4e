"""The main job: compare learned policies and classical trackers on identical measurement streams.

``radar-track evaluate`` (or ``python -m agents.evaluation.evaluate``) draws each suite's episodes once (held-out evaluation
seeds, see :mod:`agents.evaluation.suites`), runs every tracker on the same episodes, batched over runs, and prints a table,
writes plots (PNG) and optionally a JSON file with every metric (:mod:`agents.evaluation.metrics`).

Defaults: the bundled learned policies if they exist (``agents/bundled/``: ``policy``, PPO, ``policy_bp``, a q-policy
trained by backpropagation, ``policy_imm_bp`` and ``policy_imm_ppo``, the learned IMM trained by backpropagation and
by PPO), the tuned 2-mode IMM (``imm2``), the tuned CV / CT-EKF IMM (``imm_cv_ct``), the particle filter over the
random flights' regimes (``rbpf``: the strongest classical tracker on its own prior), Bizup's IMM, the tuned constant-q
KF, the c_min tracker and the clairvoyant bound, on the default suite (random scenarios and the papers' named
scenarios).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from baselines.registry import BOUND_TRACKERS, DESIGN_ENVELOPES, POLICY_TRACKERS, RANGE_RATE_TRACKERS, tracker_names
from baselines.user_trackers import import_tracker_module
from radar_env.sim.catalog import FAMILIES, SCENARIO_NAMES
from radar_env.sim.radar import atc_radar
from radar_env.sim.episode import stack_episodes

from agents.policies.bundle import BUNDLED_POLICIES, BUNDLED_POLICY  # noqa: F401 (BUNDLED_POLICY: part of this API)
from agents.policies.learned import BUNDLED_LEARNED, learned_label, load_learned, read_kind, resolve_learned
from agents.policies.loading import load_policy
from agents.evaluation.downstream import intercept_metrics, warning_metrics
from radar_env.common.files import (check_output_dir, check_output_file, file_type, move_replacing, same_file,
                                     write_text_replacing)
from agents.evaluation.metrics import (FEW_RUNS, MIN_VALID_NEES_SHARE, common_runs, comparable_rmse, evaluate_run,
                                       failed_runs, jsonable, ratio_ci, score_run)
from agents.evaluation.options import DEFAULT_TRACKERS, OLD_OPTION_KINDS, OLD_OPTIONS, build_parser, check_numbers
from agents.evaluation.scores import REFERENCE_RMSE_M, normalised_score
from agents.evaluation.progress import Progress
from agents.evaluation.runner import run_one
from baselines.seeds import EVAL_SEED_BASE
from agents.evaluation.suites import (DEFAULT_RADAR_RANGE_M, DEFAULT_SUITES, EXTRA_SUITES, draw_suite, run_scenario,
                                      suite_key, trajectory_suite_names)

__all__ = ["evaluate", "main", "format_table", "write_plots", "DEFAULT_TRACKERS", "DEFAULT_RUNS", "default_runs"]

DEFAULT_RUNS = {"random": 200, "random_radars": 100, "adrian_flower": 10, "adsb_calibration": 24, "adsb_dev": 12,
                "adsb_heldout": 12, "encounters": 100, **{f: 200 for f in FAMILIES}}
"""Runs per suite when ``--runs`` is not given (the flower has 1561 looks per run, random radars up to ~1500;
the ADS-B suites fly each of their flights once; the held-out families 200); others: 50 (``adsb:<flight>``: 10)."""


def default_runs(suite, trajectory=False):
    """Runs of ``suite`` when ``--runs`` is not given: :data:`DEFAULT_RUNS`, else 10 for ``adsb:<flight>`` and 50 for
    any other suite or a ``--trajectory`` file (``trajectory=True``)."""
    if trajectory:
        return 50
    return DEFAULT_RUNS.get(suite, 10 if suite.startswith("adsb:") else 50)


# ------------------------------------------------------------------------------------------------ evaluation
def evaluate(suites, trackers, policy_path=None, reference="imm2", progress=True, workers=1, address=None, seed=None,
             common_over=None, loaded_policy=None, policy_paths=None, loaded_policies=None, learned=None,
             allow_pickle=False):
    """Run ``trackers`` on every suite.

    Args:
        suites: list of ``(name, episodes)``.
        trackers: tracker names (``TRACKER_NAMES``); ``policy`` needs ``policy_path``; the other learned trackers
            (``policy_bp``, ``policy_imm_bp``, ``policy_imm_ppo``) run ``policy_paths[name]`` (default: the bundled
            ones, :data:`agents.policies.bundle.BUNDLED_POLICIES`). Each file may be an SB3 zip, a recurrent ``.npz``
            or a learned IMM (:func:`agents.policies.loading.load_policy`).
        reference: tracker the ratio column is taken against (if present).
        workers, address, seed: ``workers > 1`` runs the trackers on Ray (:func:`agents.evaluation.parallel.run_suites_ray`,
            same numbers as the serial run); ``seed``: the base seed the suites were drawn with (lets the tasks draw
            the named suites themselves).
        common_over: tracker names whose lost or failed runs are left out of every tracker's common-run metrics
            (:func:`agents.evaluation.metrics.common_runs`); default: all ``trackers`` except, per suite, those that failed
            every run (named in ``common_excluded_failed_everywhere``).
        loaded_policy, loaded_policies: ``load_policy(policy_path)``'s result (``{name: load_policy(
            policy_paths[name])}``) if the caller has it already (not loaded again).
        learned: ``{tracker name: LearnedTracker}`` (:func:`agents.policies.learned.load_learned`): learned
            trackers by any name, each run as its kind says; a name here takes precedence over the file arguments.
        allow_pickle: let a policy file given by path be unpickled (an SB3 zip without a current numpy export);
            refused in one line otherwise.
    Returns:
        ``(results, runs)``: ``results[suite]["trackers"][tracker]`` = metrics dict, ``results[suite]
        ["ratio_vs_" + reference][tracker]`` = ``[ratio, [lo, hi]]`` over the runs neither failed (their number in
        ``"ratio_vs_" + reference + "_runs"``), ``..._common`` the same over the suite's ``common_runs``;
        ``runs[suite]`` = ``(batch, {name: TrackRun})``.
    """
    paths = {t: (policy_paths or {}).get(t) for t in POLICY_TRACKERS}
    paths["policy"] = policy_path
    for t in POLICY_TRACKERS:
        if t != "policy" and paths[t] is None and BUNDLED_POLICIES[t].is_file():
            paths[t] = BUNDLED_POLICIES[t]
    given = {t: (loaded_policies or {}).get(t) for t in POLICY_TRACKERS}
    given["policy"] = loaded_policy
    policies = {}                           # tracker -> (choose_q, env config)
    learned = dict(learned or {})
    for t, lt in learned.items():
        if t in trackers:
            policies[t], paths[t] = (lt.policy, lt.env_config), lt.file
    for t in POLICY_TRACKERS:
        if t in trackers and t not in learned:
            if paths[t] is None and given[t] is None:
                raise ValueError(f"tracker {t!r} needs a policy file (--{t.replace('_', '-')} PATH); none bundled")
            policies[t] = given[t] if given[t] is not None else load_policy(paths[t], allow_pickle=allow_pickle)
    range_rate = set(RANGE_RATE_TRACKERS) | {t for t, (_, cfg) in policies.items()
                                             if getattr(cfg, "radial_velocity", False)}
    default_common = common_over is None
    common_over = list(trackers if common_over is None else common_over)
    bad = [t for t in common_over if t not in trackers]
    if bad:
        raise ValueError(f"common_over names {bad}, which are not among the trackers {list(trackers)}")
    # one item per (suite, tracker), weighted by the suite's looks: a tracker's cost grows with them
    jobs = [(s, t) for s, eps in suites for t in trackers]
    looks = {s: sum(e.n_looks for e in eps) for s, eps in suites}
    bar = Progress("evaluate", [(f"{s}: {t}", looks[s], t) for s, t in jobs], enabled=progress)
    results, runs = {}, {}
    ray_runs = None
    if workers > 1 or address:
        from agents.evaluation.parallel import run_suites_ray
        finished = iter(range(len(jobs)))       # Ray runs them all at once: each tick is one more finished

        def tick(msg):
            i = next(finished)
            bar.done(i)                          # its time: since the previous one finished (the throughput)
            if i + 1 < len(jobs):
                bar.start(i + 1)
        bar.start(0)
        ray_runs = run_suites_ray(suites, trackers, {t: paths[t] for t in policies}, workers, address, seed, tick,
                                  allow_pickle=allow_pickle)
    for suite, episodes in suites:
        batch = stack_episodes(episodes)
        suite_runs = {} if ray_runs is None else ray_runs[suite]
        for t in trackers if ray_runs is None else ():
            bar.start(jobs.index((suite, t)))
            suite_runs[t] = run_one(t, episodes, *policies.get(t, (None, None)))
            bar.done()
        scores = {t: score_run(batch, r) for t, r in suite_runs.items()}     # errors, failed, lost: once per run
        # by default a tracker that failed every run does not empty the common set for all the others
        dropped = [t for t in common_over if default_common and scores[t].failed.all()]
        cover = [t for t in common_over if t not in dropped]
        common = common_runs(batch, [suite_runs[t] for t in cover], scores=[scores[t] for t in cover])
        n_common = int(common.sum())
        res = {"runs": len(episodes), "looks_per_run_mean": float(batch.n_looks.mean()),
               "few_runs": len(episodes) < FEW_RUNS, "common_runs": n_common, "few_common_runs": n_common < FEW_RUNS,
               "common_trackers": cover, "common_excluded_failed_everywhere": dropped, "trackers": {}}
        for t, r in suite_runs.items():
            m = evaluate_run(batch, r, common=common, score=scores[t])
            if r.error is not None:
                m["error"] = r.error
            m.update(_downstream(suite, episodes, batch, r, scores[t].failed))
            if suite in REFERENCE_RMSE_M and comparable_rmse(m):     # 0 = kf_tuned, 100 = rbpf (pooled, every run)
                m["score"] = normalised_score(suite, float(m["pos_rmse_m"]))
            _note_undefined(m)
            res["trackers"][t] = m
        res["bounds_beaten"] = bounds_beaten(res["trackers"], range_rate)
        if reference in suite_runs:
            ref = suite_runs[reference]
            ref_ok = ~scores[reference].failed
            pair = {t: (scores[t], scores[reference]) for t in suite_runs}
            res[f"ratio_vs_{reference}"] = {
                t: list(_pair(ratio_ci(batch, r, ref, scores=pair[t]))) for t, r in suite_runs.items()}
            res[f"ratio_vs_{reference}_runs"] = {
                t: int((ref_ok & ~scores[t].failed).sum()) for t in suite_runs}
            res[f"ratio_vs_{reference}_common"] = {
                t: list(_pair(ratio_ci(batch, r, ref, runs=common, scores=pair[t]))) for t, r in suite_runs.items()}
        results[suite] = res
        runs[suite] = (batch, suite_runs)
    bar.close()
    return results, runs


def bounds_beaten(trackers, range_rate=RANGE_RATE_TRACKERS):
    """``{bound: {"pos_rmse_m": .., "beaten_by": name, "beaten_by_pos_rmse_m": ..}}`` for each bound tracker
    (:data:`baselines.registry.BOUND_TRACKERS`) whose pooled position RMSE is above that of the best real tracker
    of the suite (``trackers``: name -> metrics): such a "bound" bounds nothing there, and the tables say so. The
    bounds filter the position plots only, so the trackers in ``range_rate`` (which also update on the radial
    velocity: a measurement the bounds do not use) are not compared with them. Only trackers that failed no run
    are compared (a pooled RMSE over fewer runs is not comparable)."""
    real = {t: m["pos_rmse_m"] for t, m in trackers.items()
            if t not in BOUND_TRACKERS and t not in range_rate and comparable_rmse(m)}
    if not real:
        return {}
    best = min(real, key=real.get)
    return {t: {"pos_rmse_m": m["pos_rmse_m"], "beaten_by": best, "beaten_by_pos_rmse_m": real[best]}
            for t, m in trackers.items() if t in BOUND_TRACKERS and comparable_rmse(m) and m["pos_rmse_m"] > real[best]}


def _downstream(suite, episodes, batch, run, failed=None):
    """Conflict warnings (``encounters``) or intercepts (other suites) over the runs the tracker did not fail (an
    encounter pair goes with either of its runs; ``failed``: its failed runs if known); ``downstream_runs`` counts
    them."""
    fn = warning_metrics if suite == "encounters" else intercept_metrics
    keep = ~(failed_runs(batch, run) if failed is None else failed)
    if suite == "encounters":
        keep = np.repeat(keep.reshape(-1, 2).all(axis=1), 2)
    if keep.all() or not keep.any():          # nothing to leave out, or nothing left (the values are then NaN)
        return {**fn(batch, run), "downstream_runs": int(keep.sum())}
    rows = np.flatnonzero(keep)
    sub = stack_episodes([episodes[i] for i in rows])
    return {**fn(sub, _take_rows(run, rows, sub.valid.shape[1])), "downstream_runs": int(rows.size)}


def _take_rows(run, rows, K):
    """The TrackRun of the episodes ``rows`` only, padded to ``K`` looks like a batch of just those episodes."""
    return dataclasses.replace(
        run, x=run.x[rows, :K], P=run.P[rows, :K], start_index=run.start_index[rows], q_m_s2=run.q_m_s2[rows, :K],
        declared=None if run.declared is None else run.declared[rows, :K],
        extra={k: v[rows, :K] for k, v in run.extra.items()})


def _note_undefined(m):
    """Give every non-finite value of a metrics dict a reason in ``m["undefined"]`` (the JSON writes it as null)."""
    und = m.setdefault("undefined", {})
    for k, v in m.items():
        if k != "undefined" and k not in und and not _finite(v):
            und[k] = f"not finite ({v!r}; {m.get('failed_runs', 0)} failed runs)"


def _finite(v):
    if isinstance(v, (list, tuple)):
        return all(_finite(x) for x in v)
    if isinstance(v, (float, np.floating)):
        return bool(np.isfinite(v))
    return True


def _pair(rc):
    est, (lo, hi) = rc
    return est, [lo, hi]


# ------------------------------------------------------------------------------------------------ output
TABLE_WIDTH = 120
"""The printed table's width budget (characters) with the default trackers and runs: the compact table
(:func:`format_table`) fits it; ``--wide`` prints every column."""


def format_table(results, reference="imm2", wide=False):
    """Plain-text table: one block per suite, one row per tracker.

    ``pos RMSE`` is pooled over the runs the tracker did not fail (lost runs included); ``score`` is its normalised
    score (0 = ``kf_tuned``, 100 = ``rbpf``, :mod:`agents.evaluation.scores`) where the suite has reference RMSEs; ``common`` over the suite's
    common runs (no compared tracker lost or failed them); the ratio columns are paired over the runs neither
    tracker failed (``all``) and over the common runs. ``(n<20)`` marks an interval from fewer than 20 runs; ``*``
    beside an ANEES one taken from under 90 % of the looks (:func:`table_notes` says how many, and names a bound
    tracker that some real tracker beat).

    By default the compact table (within :data:`TABLE_WIDTH` characters for the default trackers, a legend under
    it): position RMSE with its interval, score, RMSE in maneuvers / after them / on straight legs, ANEES, lost,
    failed and the ratio to ``reference`` over all runs. ``wide=True``: every column (also the velocity RMSE, the
    peak error, the share of looks in the 95 % NEES bound, the common runs' RMSE and ratio). The JSON has every
    metric either way."""
    if not wide:
        return _format_compact(results, reference)
    lines = []
    head = ("tracker", "pos RMSE m [95% CI]", "score", "maneuver", "after", "straight", "vel m/s", "peak m", "ANEES",
            "in95", "lost", "failed", "common RMSE m [95% CI]", f"/{reference} all [95% CI]",
            f"/{reference} common [95% CI]")
    widths = (20, 30, 6, 9, 8, 9, 8, 8, 6, 5, 5, 6, 30, 28, 28)
    for suite, res in results.items():
        n_common = res.get("common_runs")
        lines.append(_suite_header(suite, res))
        lines.append(" ".join(f"{h:{'<' if i == 0 else '>'}{w}s}" for i, (h, w) in enumerate(zip(head, widths))))
        ratios = res.get(f"ratio_vs_{reference}", {})
        ratio_runs = res.get(f"ratio_vs_{reference}_runs", {})
        ratios_c = res.get(f"ratio_vs_{reference}_common", {})
        for t, m in res["trackers"].items():
            rr, rc = ratios.get(t), ratios_c.get(t)
            cells = (
                t,
                _f_ci(m["pos_rmse_m"], m["pos_rmse_m_ci95"], m.get("runs_scored", res["runs"]), 1),
                _f(m.get("score"), 6, 0), _f(m["pos_rmse_m_maneuver"], 9), _f(m["pos_rmse_m_after"], 8), _f(m["pos_rmse_m_straight"], 9),
                _f(m["vel_rmse_m_s"], 8, 2), _f(m["peak_pos_err_m"], 8, 0), _anees_cell(m, 6),
                _f(m["nees_in_95"], 5, 2), _f(m["track_loss_rate"], 5, 2), str(m.get("failed_runs", "-")),
                _f_ci(m["pos_rmse_m_common"], m["pos_rmse_m_common_ci95"], m["common_runs"], 1)
                if "pos_rmse_m_common" in m else "-",
                _f_ci(rr[0], rr[1], ratio_runs.get(t, res["runs"]), 3) if rr else "",
                _f_ci(rc[0], rc[1], n_common, 3) if rc else "")
            lines.append(" ".join(f"{c:{'<' if i == 0 else '>'}{w}s}" for i, (c, w) in enumerate(zip(cells, widths))))
        lines += [f"  {n}" for n in table_notes(res)]
    return "\n".join(lines)


def _suite_header(suite, res, compact=False):
    """A suite's title line; ``compact``: the few-runs warning on a second line (the compact table's width)."""
    n_common = res.get("common_runs")
    few = (f"(n<{FEW_RUNS}): fewer than {FEW_RUNS} runs, the intervals are no evidence"
           if res["runs"] < FEW_RUNS else "")
    head = (f"\n== {suite}: {res['runs']} runs, {res['looks_per_run_mean']:.0f} looks/run"
            + ("" if n_common is None else f"; {n_common} common runs (no tracker lost or failed them)"))
    if compact:
        return head + " ==" + (f"\n   {few}" if few else "")
    return head + (f"; {few}" if few else "") + " =="


def compact_legend(reference="imm2", few_runs=False):
    """The lines printed under the compact table, naming its columns (``few_runs``: and the ``(n<20)`` mark)."""
    return ["columns: RMSE = position RMSE (m) over the runs not failed [95% CI]; score: 0 = kf_tuned, 100 = rbpf;",
            "man / aft / str = position RMSE (m) in maneuvers / up to 60 s after one / on straight legs;",
            "ANEES: 1 = a consistent covariance; lost: share of runs lost; fail: runs failed;",
            f"/{reference}: RMSE / {reference}'s RMSE, paired over the runs neither failed [95% CI]"
            + (f"; (n<{FEW_RUNS}): from fewer than {FEW_RUNS} runs." if few_runs else "."),
            "--wide: every column (velocity RMSE, peak error, NEES in 95 %, the common runs' RMSE and ratio); "
            "--json: every metric."]


def _format_compact(results, reference):
    """:func:`format_table`'s default: the columns that fit :data:`TABLE_WIDTH`, and a legend."""
    lines = []
    names = [t for res in results.values() for t in res["trackers"]]
    tw = max([7] + [len(t) for t in names])
    head = ("tracker", "RMSE m [95% CI]", "score", "man", "aft", "str", "ANEES", "lost", "fail",
            f"/{reference} [95% CI]")
    widths = (tw, 26, 5, 6, 6, 6, 6, 4, 4, 26)
    for suite, res in results.items():
        lines.append(_suite_header(suite, res, compact=True))
        lines.append(" ".join(f"{h:{'<' if i == 0 else '>'}{w}s}" for i, (h, w) in enumerate(zip(head, widths))))
        ratios = res.get(f"ratio_vs_{reference}", {})
        ratio_runs = res.get(f"ratio_vs_{reference}_runs", {})
        for t, m in res["trackers"].items():
            rr = ratios.get(t)
            cells = (
                t,
                _f_ci(m["pos_rmse_m"], m["pos_rmse_m_ci95"], m.get("runs_scored", res["runs"]), 1),
                _f(m.get("score"), 5, 0), _f(m["pos_rmse_m_maneuver"], 6), _f(m["pos_rmse_m_after"], 6),
                _f(m["pos_rmse_m_straight"], 6), _anees_cell(m, 6), _f(m["track_loss_rate"], 4, 2),
                str(m.get("failed_runs", "-")),
                _f_ci(rr[0], rr[1], ratio_runs.get(t, res["runs"]), 3) if rr else "")
            lines.append(" ".join(f"{c:{'<' if i == 0 else '>'}{w}s}" for i, (c, w) in enumerate(zip(cells, widths))))
        lines += [f"  {n}" for n in table_notes(res)]
    if results:
        lines += ["", *compact_legend(reference, few_runs=any(f"(n<{FEW_RUNS})" in line for line in lines))]
    return "\n".join(lines)


def table_notes(suite_result):
    """Notes printed under a suite's table: a tracker that raised (its error), and the design envelope of each
    tracker used outside the conditions its paper assumed (:data:`baselines.registry.DESIGN_ENVELOPES`)."""
    notes = []
    beaten = suite_result.get("bounds_beaten", {})
    for t, m in suite_result["trackers"].items():
        if m.get("error"):
            notes.append(f"{t}: failed on every run: {m['error']}")
        if t in beaten:
            b = beaten[t]
            notes.append(f"{t}: NOT A BOUND on this suite: a bound (it sees the truth), yet its position RMSE "
                         f"{b['pos_rmse_m']:.1f} m is above {b['beaten_by']}'s {b['beaten_by_pos_rmse_m']:.1f} m")
        if m.get("anees_few_valid_looks") and m.get("nees_valid_looks") is not None:
            n_all = m["nees_valid_looks"] + m["nees_invalid_looks"]
            notes.append(f"{t}: ANEES from only {m['nees_valid_looks']} of {n_all} scored looks (under "
                         f"{MIN_VALID_NEES_SHARE:.0%}): the others' covariance is not positive definite")
        if t in DESIGN_ENVELOPES:
            notes.append(f"{t}: design envelope: {DESIGN_ENVELOPES[t]}")
    return notes


def _anees_cell(m, w):
    """The ANEES column: ``*`` beside a value taken from under MIN_VALID_NEES_SHARE of the looks (see the notes)."""
    if m.get("anees_few_valid_looks") and m.get("anees") is not None and np.isfinite(m["anees"]):
        return f"{m['anees']:.2f}*".rjust(w)
    return _f(m["anees"], w, 2)


def _f(v, w, nd=1):
    """``v`` with ``nd`` decimals right-aligned in ``w`` characters, '-' if None or not finite."""
    return f"{v:{w}.{nd}f}" if v is not None and np.isfinite(v) else f"{'-':>{w}s}"


def _f_ci(est, ci, n, nd):
    """``est [lo,hi]`` and ``(n<20)`` if the interval comes from fewer than ``FEW_RUNS`` runs; '-' if undefined."""
    if est is None or not np.isfinite(est):
        return "-"
    lo, hi = ci
    txt = f"{est:.{nd}f} [{_f(lo, 0, nd).strip()},{_f(hi, 0, nd).strip()}]"
    return txt + (f" (n<{FEW_RUNS})" if n is not None and n < FEW_RUNS else "")


_FIGURES = {}
"""The figures' inputs for the forked drawing processes (:func:`_draw_figure`): set before the fork, read-only."""


def _draw_figure(item):
    """Draw one ``(suite, kind)`` figure into the temporary folder; returns the files (a forked worker's job)."""
    from agents.evaluation import plots
    suite, kind = item
    batch, suite_runs = _FIGURES["runs"][suite]
    safe = re.sub(r"[/\\]", "_", suite) if suite not in (".", "..") else "_"
    return [str(f) for f in plots.suite_figures(safe, batch, suite_runs, Path(_FIGURES["tmp"]),
                                               scenario=_FIGURES["scenarios"].get(suite), kinds=(kind,))]


def figure_processes(n_items):
    """How many processes draw the figures: one per usable core, at most 4 and at most one per figure; 1 where
    forking is not the way processes start (macOS, Windows) or with one core."""
    if sys.platform != "linux":
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, 4, n_items))


def write_plots(runs, out_dir, scenarios=None, progress=False, inputs=(), processes=None):
    """PNG figures per suite (:mod:`agents.evaluation.plots`); returns the list of files written.

    Args:
        scenarios: ``{suite: run 0's truth model}`` (:func:`agents.evaluation.suites.run_scenario`) for the exact
            paths and maneuver times; a suite without one is drawn from its looks.
        progress: a bar over the figures on stderr.
        inputs: the run's input files: one of them is never replaced (a warning instead).
        processes: how many forked processes draw them (default :func:`figure_processes`: one per core, at most
            4; the figures are the same files either way). Measured on the main job's 35 figures on the 2-core
            machine (load 1.5): 11.5 s in one process, 5.9 s in two.

    The figures are drawn in a temporary folder inside ``out_dir`` and renamed into it
    (:func:`radar_env.common.files.move_replacing`) by this process, in the figures' order: a link in ``out_dir``
    is replaced, never followed, and a suite name cannot lead outside ``out_dir``."""
    import matplotlib
    matplotlib.use("Agg")
    from agents.evaluation import plots
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    items = [(s, k) for s in runs for k in plots.FIGURE_KINDS]
    n_proc = figure_processes(len(items)) if processes is None else max(1, int(processes))
    bar = Progress("figures", [(f"{s}: {k}", 1, k) for s, k in items], enabled=progress)
    files = []
    with tempfile.TemporaryDirectory(dir=out_dir, prefix=".plots-") as tmp:
        _FIGURES.update(runs=runs, scenarios=scenarios or {}, tmp=tmp)
        try:
            if n_proc > 1:
                import multiprocessing as mp
                pool = mp.get_context("fork").Pool(n_proc)
                drawn = pool.imap(_draw_figure, items)       # in the figures' order
            else:
                pool, drawn = None, iter(map(_draw_figure, items))
            try:
                for i in range(len(items)):
                    bar.start(i)
                    made = next(drawn)          # waits for figure i (the bar's clock runs meanwhile)
                    for f in made:
                        dest = out_dir / Path(f).name
                        if any(same_file(dest, inp) for inp in inputs if inp is not None):
                            print(f"warning: --out: not writing {dest}: it is an input of this run", file=sys.stderr)
                            continue
                        move_replacing(f, dest)
                        files.append(dest)
                    bar.done()
            finally:
                if pool is not None:
                    pool.close()
                    pool.join()
        finally:
            _FIGURES.clear()
    bar.close()
    return files


def _say(args, msg):
    """A status line on stderr (not with --quiet): what the command does next, before a slow step."""
    if not args.quiet:
        print(msg, file=sys.stderr, flush=True)


def _list_names():
    """``--list``: every suite and built-in tracker name."""
    print("suites:\n  " + "\n  ".join(list(SCENARIO_NAMES) + list(EXTRA_SUITES) + ["adsb:<flight>",
                                                                               "<file>.csv (--trajectory)"]))
    print("trackers:\n  " + "\n  ".join(tracker_names()))
    print(f"defaults: --scenario {','.join(DEFAULT_SUITES)} --trackers {','.join(DEFAULT_TRACKERS)}")


# ------------------------------------------------------------------------------------------------ CLI
def _km_pair(option, text):
    """``"A,B"`` -> two finite floats (km); a one-line error naming ``option`` otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 2 or not all(np.isfinite(vals)):
        raise SystemExit(f"error: {option}: expected two finite numbers in km separated by a comma, got {text!r}")
    return vals


def _check_outputs(args, inputs=()):
    """Fail before the evaluation runs if an output cannot be written (``--out`` for plots, ``--json``), or if
    ``--json`` is a symbolic link or one of the run's ``inputs`` (it would be overwritten)."""
    for option, value in (("--out", None if args.no_plots else args.out), ("--json", args.json)):
        if value is not None and not str(value).strip():
            raise SystemExit(f"error: {option}: an empty path; give a {'folder' if option == '--out' else 'file'} "
                             "name")
    if not args.no_plots:
        out = Path(args.out)
        try:
            check_output_dir("--out", out)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
        if out.exists() and not out.is_dir():
            raise SystemExit(f"error: --out: {args.out!r} exists and is not a directory")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SystemExit(f"error: --out: cannot create directory {args.out!r} ({e.strerror or e})") from None
        if not os.access(out, os.W_OK | os.X_OK):
            raise SystemExit(f"error: --out: directory {args.out!r} is not writable")
    if args.json:
        js = Path(args.json)
        folder = js.parent
        if file_type(js) not in (None, "file", "directory", "symbolic link"):
            raise SystemExit(f"error: --json: {args.json!r} exists and is a {file_type(js)}; only a new path or a "
                             "regular file is replaced")
        if js.is_dir():
            raise SystemExit(f"error: --json: {args.json!r} is a directory; give a file name")
        if not folder.is_dir():
            raise SystemExit(f"error: --json: folder {str(folder)!r} of {args.json!r} does not exist (or is not a "
                             "directory)")
        if not os.access(folder, os.W_OK | os.X_OK) or (js.exists() and not os.access(js, os.W_OK)):
            raise SystemExit(f"error: --json: {args.json!r} is not writable")
        try:
            check_output_file("--json", js, inputs)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None


BYTES_PER_LOOK = 1000
"""Driver memory per look of a suite without trackers (the episodes, their padded batch, the chain's look rows)."""
BYTES_PER_LOOK_TRACKER = 500
"""Memory per look and tracker (its TrackRun: estimate, covariance, q, extras; the scoring's temporaries)."""
SECONDS_PER_LOOK_TRACKER = {"hindsight_q": 5e-3, "hindsight_q_turn": 1e-2, "konle": 2e-4, "policy": 1e-4}
"""Rough wall time per look and tracker, scoring included, on a shared 2-core machine (others:
``SECONDS_PER_LOOK_DEFAULT``; measured: 5 trackers on 2000 random runs, 3.5e5 padded looks, 105 s and 1.1 GiB), for
the up-front estimate of a long evaluation."""
SECONDS_PER_LOOK_DEFAULT = 6e-5


def _available_memory_bytes():
    """MemAvailable from /proc/meminfo, else the physical memory."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def estimate_cost(plan, trackers, seed=EVAL_SEED_BASE):
    """``(bytes, seconds, looks)``: the driver memory and the rough wall time of evaluating ``trackers`` on the
    suites of ``plan`` (``(option, name, source, runs, draw_suite kwargs)``), from the looks per run of a pilot
    draw of at most 4 runs per suite (:data:`BYTES_PER_LOOK`, :data:`BYTES_PER_LOOK_TRACKER`,
    :data:`SECONDS_PER_LOOK_TRACKER`)."""
    looks = 0.0
    for option, name, source, runs, kw in plan:
        try:
            pilot = draw_suite(source, min(int(runs), 4), seed=seed, **kw)
        except ValueError as e:
            raise SystemExit(f"error: {option}: {e}") from None
        per_run = len(pilot) / min(int(runs), 4)                 # encounters: two episodes per run
        looks += runs * per_run * max(e.n_looks for e in pilot)   # padded to the longest run
    mem = looks * (BYTES_PER_LOOK + BYTES_PER_LOOK_TRACKER * len(trackers))
    sec = looks * sum(SECONDS_PER_LOOK_TRACKER.get(t, SECONDS_PER_LOOK_DEFAULT) for t in trackers)
    return mem, sec, looks


def _check_cost(plan, trackers, seed):
    """Refuse a plan whose memory estimate exceeds the available memory (one line, naming --runs); print the
    estimate to stderr when it is large (over 2 GB or 10 minutes)."""
    mem, sec, looks = estimate_cost(plan, trackers, seed)
    avail = _available_memory_bytes()
    what = (f"{sum(p[3] for p in plan)} runs over {len(plan)} suite(s), about {looks:.3g} looks x "
            f"{len(trackers)} trackers")
    if avail is not None and mem > avail:
        raise SystemExit(f"error: --runs: {what} need about {mem / 2**30:.3g} GiB of memory, more than the "
                         f"{avail / 2**30:.3g} GiB available (and about {sec / 3600:.3g} h); lower --runs or split "
                         "the suites")
    if mem > 2 * 2**30 or sec > 600:
        print(f"estimate: {what}: about {mem / 2**30:.2g} GiB of memory and {sec / 60:.3g} min (rough, 2-core "
              "machine)", file=sys.stderr)


def _input_files(args, policies=()):
    """The files this run reads (outputs must not replace them): trajectory CSVs, ADS-B flight files given by path,
    tracker-module files, and ``policies``: the learned trackers' files (:meth:`LearnedTracker.input_files`)."""
    files = list(args.trajectory or []) + [m for m in args.tracker_module or [] if m.endswith(".py")]
    files += [n[len("adsb:"):] for n in args.scenario or [] if n.startswith("adsb:")]
    files += [str(p) for p in policies]
    return [f for f in files if Path(f).is_file()]


def _learned_sources(args):
    """``{tracker name: (option, name or path, kinds)}`` of the learned trackers this run may load: each
    ``--learned`` (its label: :func:`agents.policies.learned.learned_label`), each old per-tracker option (a
    deprecated alias, with the kinds it accepts, :data:`agents.evaluation.options.OLD_OPTION_KINDS`), and the
    bundled ones present that neither names (``kinds`` ``None``: any). ``SystemExit`` (one line) for a path that
    does not exist or a tracker given twice."""
    sources = {}
    for t, opt in OLD_OPTIONS.items():
        given = getattr(args, t)
        if given is None:
            continue
        print(f"note: {opt} is deprecated and will be removed in the next release; use --learned "
              f"{Path(given).parent}", file=sys.stderr)
        if not Path(given).is_file():
            raise SystemExit(f"error: {opt}: file {given!r} does not exist (or is not a file)")
        try:    # the kind, now (JSON only): the file is refused even where --trackers does not run it
            kind, where = read_kind(Path(given).parent, given)
        except ValueError:
            kind = None         # not a learned tracker folder: the loader says why, when the tracker is loaded
        if kind is not None and kind not in OLD_OPTION_KINDS[t]:
            raise SystemExit(f"error: {opt}: {where}: kind {kind!r}, but {opt} takes "
                             f"{' or '.join(OLD_OPTION_KINDS[t])}; use --learned {Path(given).parent}")
        sources[t] = (opt, given, OLD_OPTION_KINDS[t])
    for spec in args.learned or []:
        try:
            folder, _, bundled = resolve_learned(spec)
        except ValueError as e:
            raise SystemExit(f"error: --learned: {e}") from None
        label = learned_label(folder, bundled)
        if label in sources:
            raise SystemExit(f"error: --learned: {spec!r} is the tracker {label!r}, already given by "
                             f"{sources[label][0]} {sources[label][1]!r}")
        sources[label] = ("--learned", spec, None)
    for t in BUNDLED_LEARNED:
        if t not in sources and BUNDLED_POLICIES[t].is_file():
            sources[t] = ("the bundled folder", t, None)
    return sources


def main(argv=None, prog="radar-track evaluate"):
    """The ``radar-track evaluate`` command. Every user error (options, files, outputs) stops with a one-line
    ``error: --option: ...`` (``SystemExit``) before any evaluation runs. Returns the results dict."""
    args = build_parser(prog).parse_args(argv)
    if args.list:
        _list_names()
        return {}
    # a CSV path given to --scenario is a trajectory suite (named by its stem, seeded by its content)
    csv_scenarios = [n for n in (args.scenario or []) if n.endswith(".csv") and not n.startswith("adsb:")]
    if csv_scenarios:
        args.scenario = [n for n in args.scenario if n not in csv_scenarios]
        args.trajectory = list(args.trajectory or []) + csv_scenarios
    check_numbers(args)
    sources = _learned_sources(args)    # learned tracker name -> (option, name or path, kinds it may have)
    for spec in args.tracker_module or []:
        try:
            import_tracker_module(spec)
        except ValueError as e:
            raise SystemExit(f"error: --tracker-module: {e}") from None
    if args.tracker_module and (args.workers > 1 or args.address):
        raise SystemExit("error: --tracker-module: user trackers are registered in this process only and cannot run "
                         f"on Ray workers; use --workers 1 without --address (got --workers {args.workers})")
    known = tracker_names()
    user_learned = [n for n, (opt, _, _) in sources.items() if opt == "--learned" and n not in POLICY_TRACKERS]
    for n in user_learned:
        if n in known:      # a folder named like a built-in tracker would be reported as that tracker
            raise SystemExit(f"error: --learned: {sources[n][1]}: its label {n!r} (the folder's name) is a built-in "
                             "tracker's name; rename the folder")
    # --learned adds to the list: named in --trackers or not, a tracker asked for by --learned runs
    asked = [n for n, (opt, _, _) in sources.items() if opt == "--learned"]
    if args.trackers is not None:
        trackers = [t.strip() for t in args.trackers.split(",") if t.strip()]
        if not trackers:
            raise SystemExit(f"error: --trackers: no tracker named in {args.trackers!r}; give comma-separated names "
                             f"from {list(known)}")
        bad = [t for t in trackers if t not in known and t not in user_learned]
        if bad:
            raise SystemExit(f"error: --trackers: unknown tracker(s) {bad}; valid: {list(known)}"
                             + ("" if args.tracker_module else " (user trackers need --tracker-module)"))
        for t in POLICY_TRACKERS:
            if t in trackers and t not in sources:
                raise SystemExit(f"error: tracker {t!r} needs --learned PATH (no bundled policy found)")
        if len(set(trackers)) != len(trackers):
            raise SystemExit(f"error: --trackers: a tracker is named twice in {args.trackers!r}")
        trackers += [n for n in asked if n not in trackers]
    else:
        trackers = [t for t in DEFAULT_TRACKERS if t not in POLICY_TRACKERS or t in sources]
        n = sum(t in POLICY_TRACKERS for t in trackers)
        # then every other learned tracker --learned asks for (bundled ones not in the default list, such as
        # policy_bp_prior, and the user's folders), in the order given
        trackers[n:n] = [t for t in asked if t not in trackers]
    learned = {}
    for t in trackers:      # load once, now: a file that is not a usable tracker of its kind is a user error
        if t in sources:
            option, spec, kinds = sources[t]
            _say(args, f"loading the learned tracker {spec} ({t}) ...")
            try:
                learned[t] = load_learned(spec, name=t, kinds=kinds, allow_pickle=args.allow_pickle)
            except ValueError as e:
                raise SystemExit(f"error: {option}: {e}") from None
    policy_files = {t: (sources[t][1] if sources[t][0] in OLD_OPTIONS.values() else str(learned[t].file))
                    if t in learned else None for t in POLICY_TRACKERS}      # as the JSON's meta named them
    policy = policy_files["policy"]
    radar, radar_range_m = None, None
    if args.radar_site is not None or args.radar_range_km is not None:
        if not args.trajectory:
            opt = "--radar-site" if args.radar_site is not None else "--radar-range-km"
            raise SystemExit(f"error: {opt} applies to --trajectory suites only; no --trajectory given")
        if args.radar_site is not None and args.radar_range_km is not None:
            raise SystemExit("error: --radar-site (a fixed site) and --radar-range-km (the placement rule's range) "
                             "exclude each other; give one")
    if args.radar_site is not None:
        x_km, y_km = _km_pair("--radar-site", args.radar_site)
        radar = atc_radar(position_m=(x_km * 1e3, y_km * 1e3))
    if args.radar_range_km is not None:
        lo_km, hi_km = _km_pair("--radar-range-km", args.radar_range_km)
        if not 0.0 < lo_km < hi_km:
            raise SystemExit(f"error: --radar-range-km: expected 0 < LO < HI (km), got {args.radar_range_km!r}")
        radar_range_m = (lo_km * 1e3, hi_km * 1e3)
    inputs = _input_files(args, [f for lt in learned.values() for f in lt.input_files()])
    _check_outputs(args, inputs)
    names = list(args.scenario or ([] if args.trajectory else DEFAULT_SUITES))
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SystemExit(f"error: --scenario: {dup} given more than once")
    suites = []
    files = list(args.trajectory or [])
    for f in files:
        if Path(f).exists() and not Path(f).is_file():
            raise SystemExit(f"error: --trajectory: {f!r} is a {file_type(Path(f))}, not a trajectory file (.csv)")
    try:
        file_names = trajectory_suite_names(files, taken=names)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    plan = [("--scenario", n, n, args.runs or default_runs(n), {}) for n in names]
    plan += [("--trajectory", n, f, args.runs or default_runs(n, trajectory=True),
              {"radar": radar, "radar_range_m": radar_range_m}) for n, f in zip(file_names, files)]
    _check_cost(plan, trackers, args.seed)
    _say(args, f"drawing the episodes: {sum(p[3] for p in plan)} runs of {len(plan)} suite(s) ...")
    for option, n, source, runs, kw in plan:
        try:
            suites.append((n, draw_suite(source, runs, seed=args.seed, **kw)))
        except ValueError as e:
            raise SystemExit(f"error: {option}: {e}") from None
    t0 = time.time()
    try:
        results, runs = evaluate(suites, trackers, progress=not args.quiet, workers=args.workers,
                                 address=args.address, seed=args.seed, learned=learned,
                                 allow_pickle=args.allow_pickle)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    print(format_table(results, wide=args.wide))
    print(f"\n({time.time() - t0:.0f} s; seeds {args.seed}+i per suite; every tracker saw the same plots)")
    if args.json:
        meta = {"seed": args.seed, "trackers": trackers, "tracker_modules": list(args.tracker_module or []),
                "policy": policy, **{t: policy_files[t] for t in POLICY_TRACKERS if t != "policy"},
                "learned": {t: {"kind": lt.kind, "folder": str(lt.folder)} for t, lt in learned.items()},
                "suites": [s for s, _ in suites],
                "trajectories": {n: {"file": f, "key": suite_key(f)} for n, f in
                                 zip(file_names, args.trajectory or [])},
                "radar_site_km": None if radar is None else [x_km, y_km],
                "radar_range_km": (None if radar is not None or not files else
                                   [v / 1e3 for v in (radar_range_m or DEFAULT_RADAR_RANGE_M)]),
                "command": " ".join(["radar-track", "evaluate", *(sys.argv[2:] if argv is None else argv)])}
        try:        # written beside it and renamed: a failed write leaves no partial file
            write_text_replacing(args.json, json.dumps(jsonable({"meta": meta, "suites": results}), indent=1,
                                                       allow_nan=False))
        except (OSError, ValueError) as e:
            raise SystemExit(f"error: --json: could not write {args.json} ({getattr(e, 'strerror', None) or e}); "
                             "the table above is the run's result") from None
        print(f"metrics: {args.json}")
    if not args.no_plots:
        scenarios = {n: run_scenario(n, args.seed) for n in names}
        scenarios.update({n: run_scenario(f, args.seed) for n, f in zip(file_names, files)})
        try:
            written = write_plots(runs, args.out, scenarios, progress=not args.quiet, inputs=inputs)
        except (OSError, ValueError) as e:
            where = getattr(e, "filename", None)
            raise SystemExit(f"error: --out: could not write the figures in {args.out}/ "
                             f"({getattr(e, 'strerror', None) or e}{': ' + str(where) if where else ''}); the "
                             "figures written before it are complete") from None
        print(f"plots: {len(written)} files in {args.out}/")
    return results


if __name__ == "__main__":
    main(prog="python -m agents.evaluation.evaluate")
