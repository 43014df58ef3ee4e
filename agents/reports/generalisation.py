"""Does the learned policy generalise? The held-out families and the spread of a recipe over its training seeds:
``python -m agents.reports.generalisation``.

Writes ``docs/generalisation.json`` and the README blocks ``families`` (per held-out family: the bundled policy,
the bundled backprop policy ``policy_bp`` when there is one, ``imm2``, the strongest classical tracker,
``hindsight_q`` and ``clairvoyant``), ``seed-spread`` (every trained seed of the recipes in :data:`RECIPES` on every
suite, held-out seeds; and the other realisations of an ensemble bundle's recipe, :data:`REALISATION_DIRS`) and
``targets`` (the targets set for the bundled policies, reached or not, with the
numbers: :func:`targets` for the PPO policy, :func:`bp_targets` for ``policy_bp`` and its recipe's seeds). Every
number is computed here; nothing is typed in.

Seeds: every suite is drawn with the evaluation seeds ``EVAL_SEED_BASE + i`` (held out). The families
(:data:`agents.evaluation.suites.HELDOUT_FAMILY_SUITES`) were never used for training, tuning or choosing a policy. The
*strongest classical tracker* of a suite is the one of :data:`CLASSICAL` with the lowest pooled position RMSE
there (chosen on the same runs it is compared on, which favours it).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from baselines.registry import run_tracker
from radar_env.sim.episode import stack_episodes

from agents.evaluation.evaluate import DEFAULT_RUNS
from agents.evaluation.metrics import jsonable
from agents.evaluation.runner import run_policy
from agents.policies.bundle import (BUNDLED_BP_POLICY, BUNDLED_BP_PRIOR, BUNDLED_IMM_PPO, BUNDLED_LEARNED_IMM,
                                    BUNDLED_LEARNED_IMM_PRIOR, BUNDLED_POLICIES, BUNDLED_POLICY, BUNDLED_WINDOW)
from agents.policies.loading import load_policy
from agents.policies.learned_imm import is_learned_imm_checkpoint
from agents.policies.recurrent import is_recurrent_checkpoint
from agents.policies.window_correction import is_window_correction
from agents.evaluation.metrics import FEW_RUNS, comparable_rmse, evaluate_run, ratio_ci
from agents.reports.report import headroom_share
from agents.evaluation.suites import DEFAULT_SUITES, EVAL_SEED_BASE, HELDOUT_FAMILY_SUITES, draw_suite

__all__ = ["CLASSICAL", "RECIPES", "FAMILY_RUNS", "main", "families_table", "spread_table", "targets_table",
           "track_start_table", "NAMED_SUITES", "bp_targets", "imm_targets", "LONG_TURN_SUITES", "evaluate_suite",
           "BP_RECIPE", "IMM_RECIPE"]

CLASSICAL = ("imm2", "imm2_grid", "imm_cv_ct", "imm_ct_bank", "rbpf", "imm2_bizup", "imm3_ct", "kf_tuned", "cmin")
"""The classical field the *strongest classical tracker* is taken from (tuned IMMs, the particle filter over the
random flights' regimes, Bizup's IMM, the tuned KF, Bizup's c_min rule)."""
BOUNDS = ("hindsight_q", "clairvoyant")
FAMILY_RUNS = 60
"""Runs per family for the family table (``hindsight_q`` costs about a CPU-second per episode); ``adsb_heldout``
flies each of its 12 flights once."""
NAMED_SUITES = ("bizup2002", "adrian_flower", "kim_lee_accel", "seed002_course_changes", "seed002_two_radars")
RECIPE_DIR = BUNDLED_POLICY.parent / "recipe"
"""Every trained seed of this round's recipes: ``<recipe>_s<seed>/policy.zip`` with its ``env_config.json``."""
BP_RECIPE_DIR = BUNDLED_BP_POLICY.parent / "seeds"
"""Every trained seed of the backprop recipe: ``<recipe>_s<seed>/policy.npz`` with its ``policy.json`` and
``env_config.json``."""
BP_RECIPE = "bp_gru"
IMM_RECIPE_DIR = BUNDLED_LEARNED_IMM.parent / "seeds"
"""Every trained seed of the learned IMM's recipe: ``imm_bp_s<seed>/policy.npz`` with its ``policy.json`` and
``env_config.json``."""
IMM_RECIPE = "imm_bp"
IMM_PPO_RECIPE_DIR = BUNDLED_IMM_PPO.parent / "seeds"
"""Every trained seed of the PPO learned IMM's recipe: ``imm_ppo_s<seed>/policy.zip`` with its ``env_config.json``
(``tracker="imm_cv_ct"``) and numpy export."""
IMM_PPO_RECIPE = "imm_ppo"
IMM_PRIOR_RECIPE_DIR = BUNDLED_LEARNED_IMM_PRIOR.parent / "seeds"
"""Every trained seed of the learned IMM's recipe on the random suites' own flights: ``imm_bp_prior_s<seed>/``."""
IMM_PRIOR_RECIPE = "imm_bp_prior"
BP_PRIOR_RECIPE_DIR = BUNDLED_BP_PRIOR.parent / "seeds"
"""Every trained seed of the wider q-policy's recipe on the random suites' own flights: ``bp_prior_s<seed>/``."""
BP_PRIOR_RECIPE = "bp_prior"
WINDOW_RECIPE_DIR = BUNDLED_WINDOW.parent / "seeds"
"""Every trained seed of the window correction's recipe over policy_bp_prior: ``window_s<seed>/``."""
WINDOW_RECIPE = "window"
REALISATION_DIRS = {"policy_window": BUNDLED_WINDOW.parent / "realisations"}
"""Bundled ensemble -> the folder of other realisations of its whole recipe (``<name>/policy.npz``: an ensemble like
the bundle, its networks trained from their own seeds in every stage; README.md there). The bundle is one more."""
LONG_TURN_SUITES = ("slow_orbits", "bizup2002", "adrian_flower")
"""Long constant-rate turns: the suites the backprop policy's per-suite target leaves out (a CV filter's q cannot
follow a long turn as a turn model can)."""
RECIPES = {"broad_fs4": "B: as broad, with frame_stack 4 (the last four observations; zero weights for the older "
                        "three at the start)",
           "broad": "A: fine-tune of the previous bundle (3 M steps, lr 1e-4 -> 0) on the broad flight distribution "
                    "(maneuvers from the first look, 0.3-9 g, 10-540 deg turns, speed-only maneuvers)",
           "broad_nees": "C: as broad, with reward_nees_weight 0.1 (a reward term against an overconfident "
                         "covariance)",
           BP_RECIPE: "backprop: a GRU choosing the CV filter's q, trained end to end by backpropagation through the "
                      "filter (agents/training/hyperparams/backprop.toml; radar-track train --method backprop)",
           IMM_RECIPE: "learned IMM: imm_cv_ct whose per-look mode-switch probabilities and noises a GRU sets, "
                       "trained end to end by backpropagation (agents/training/hyperparams/backprop_imm_cv_ct.toml; "
                       "radar-track train --method backprop --tracker imm_cv_ct)",
           IMM_PRIOR_RECIPE: "learned IMM on the random suites' own flights: the learned IMM's recipe with the "
                             "random and random_radars suites' flight laws (RandomScenarioConfig's defaults, 70 % random "
                             "radars) instead of the broad ones (agents/bundled/learned_imm_prior/CHOICE.md)",
           BP_PRIOR_RECIPE: "backprop on the random suites' own flights: policy_bp's recipe with a GRU of 128 and a "
                            "tanh layer of 64, lr 5e-3, 3,000 steps, on the random and random_radars suites' flight "
                            "laws (agents/bundled/backprop_prior/CHOICE.md)",
           WINDOW_RECIPE: "a window correction of policy_bp_prior: an MLP (tanh 128, 128) over the last 24 plots in "
                          "the base track's frame and least-squares quadratics through the last 6-24 of them and the "
                          "base's q at its last 12 looks, moving its reported position, trained by regression on 4,000 "
                          "flights of each random suite, their first leg drawn as every leg (inputs standardised, "
                          "suites weighted alike, 160 epochs in float32 with the flights drawn afresh every 10, "
                          "selected also on flights whose start is unknown; agents/training/hyperparams/window.toml; "
                          "radar-track train --method window; agents/bundled/window/CHOICE.md)",
           IMM_PPO_RECIPE: "learned IMM by PPO: RadarTrack-v0 with tracker='imm_cv_ct' (the IMM's per-look "
                           "parameters as a continuous action), ppo.toml, 1.2 M steps"}
"""This round's recipes (issue 20), each trained with seeds 700000, 710000 and 720000; the bundle is the seed the
rule chose (agents/bundled/policy/choice.json)."""


def _runs(suite, family_runs):
    if suite in HELDOUT_FAMILY_SUITES:
        return DEFAULT_RUNS[suite] if suite.startswith("adsb") else family_runs
    return DEFAULT_RUNS.get(suite, 50)


def _ratio(batch, a, b):
    r, ci = ratio_ci(batch, a, b)
    return [r, list(ci)]


def _score(batch, policy_run, classical_runs, strongest):
    m = evaluate_run(batch, policy_run)
    return {"pos_rmse_m": m["pos_rmse_m"], "pos_rmse_m_ci95": m["pos_rmse_m_ci95"],
            "track_loss_rate": m["track_loss_rate"], "failed_runs": m["failed_runs"], "anees": m["anees"],
            "anees_few_valid_looks": m.get("anees_few_valid_looks", False),
            "ratio_vs_imm2": _ratio(batch, policy_run, classical_runs["imm2"]),
            "ratio_vs_imm_cv_ct": _ratio(batch, policy_run, classical_runs["imm_cv_ct"]),
            "ratio_vs_strongest": _ratio(batch, policy_run, classical_runs[strongest])}


def evaluate_suite(suite, episodes, policies, bounds=()):
    """Classical field, ``bounds`` and every policy of ``policies`` (``{name: load_policy(...)}``'s ``(choose_q,
    cfg)``: a q-policy or a learned IMM) on one suite.
    Returns the suite's JSON-able result."""
    batch = stack_episodes(episodes)
    runs = {t: run_tracker(t, episodes) for t in CLASSICAL + tuple(bounds)}
    metrics = {t: evaluate_run(batch, r) for t, r in runs.items()}
    ok = {t: m for t, m in metrics.items() if t in CLASSICAL and np.isfinite(m["pos_rmse_m"])}
    whole = {t: m for t, m in ok.items() if comparable_rmse(m)}        # pooled over the same (all) runs
    strongest = min(whole or ok, key=lambda t: (whole or ok)[t]["pos_rmse_m"])
    res = {"runs": len(episodes), "few_runs": len(episodes) < FEW_RUNS,
           "looks_per_run_mean": float(batch.n_looks.mean()), "strongest_classical": strongest,
           "trackers": {t: {k: metrics[t].get(k, False) for k in ("pos_rmse_m", "pos_rmse_m_ci95", "track_loss_rate",
                                                                "failed_runs", "anees", "anees_few_valid_looks")}
                        for t in runs},
           "ratio_vs_imm2": {t: _ratio(batch, r, runs["imm2"]) for t, r in runs.items()},
           "policies": {}}
    for name, (choose_q, cfg) in policies.items():
        res["policies"][name] = _score(batch, run_policy(name, episodes, choose_q, cfg), runs, strongest)
    if "hindsight_q" in runs and "policy" in res["policies"]:
        fake = {"trackers": {"policy": res["policies"]["policy"], **metrics}}
        res["headroom_share"] = headroom_share(fake)
    return res


TRACK_START_SUITES = ("start_maneuver", "random")
TRACK_START_TRACKERS = ("imm2", "imm_cv_ct", "kf_tuned")
TRACK_START_WARMUPS = (12, 1)
"""The track-start study: Bizup's 12 warm-up looks at 0.03 g against the earliest start the env allows (one
warm-up look, then the tracker acts), scored on the looks both use (after the later start)."""


def track_start_study(seed, runs):
    """Per suite and tracker: pooled RMSE with 1 warm-up look / with 12, paired 95 % interval, on the looks after
    the 12-look start (the same looks for both)."""
    from radar_env.filters.tracking import TrackStart
    out = {}
    for suite in TRACK_START_SUITES:
        eps = draw_suite(suite, runs, seed=seed)
        batch = stack_episodes(eps)
        res = {"runs": len(eps)}
        for t in TRACK_START_TRACKERS:
            a, b = (run_tracker(t, eps, TrackStart(warmup_scans=w)) for w in TRACK_START_WARMUPS[::-1])
            res[t] = _ratio(batch, a, b)
        out[suite] = res
    return out


def track_start_table(data):
    lines = ["| suite (runs) | " + " | ".join(f"{t}: 1 warm-up look / 12" for t in TRACK_START_TRACKERS) + " |",
             "|---" * (1 + len(TRACK_START_TRACKERS)) + "|"]
    for suite, res in data["track_start"].items():
        lines.append(f"| {suite} ({res['runs']}) | " + " | ".join(_fmt_ratio(res[t]) for t in TRACK_START_TRACKERS)
                     + " |")
    return "\n".join(lines)


def recipe_policies(recipe_dir=RECIPE_DIR):
    """``{name: path}`` of every recipe seed shipped in ``recipe_dir`` (sorted): SB3 zips and recurrent policies
    (``policy.npz`` with ``policy.json``; the ``policy.npz`` beside an SB3 zip is that zip's numpy export)."""
    found = [*Path(recipe_dir).glob("*/policy.zip"),
             *(p for p in Path(recipe_dir).glob("*/policy.npz")
               if (is_recurrent_checkpoint(p) or is_learned_imm_checkpoint(p) or is_window_correction(p))
               and not p.with_suffix(".zip").is_file())]
    return {p.parent.name: p for p in sorted(found)}


# ------------------------------------------------------------------------------------------------ tables
def _fmt_ratio(r, few=False):
    est, (lo, hi) = r
    if est is None or not np.isfinite(est):
        return "-"
    return f"{est:.2f} [{lo:.2f}, {hi:.2f}]" + (f" (n<{FEW_RUNS})" if few else "")


def _m0(v):
    """A pooled RMSE (m) for a table: "-" when undefined (None in the JSON, NaN live: the tracker failed every run)."""
    return "-" if v is None or not np.isfinite(v) else f"{v:.0f}"


def _mean_worst(v):
    """``mean / worst`` of seed ratios, "-" if any seed's ratio is undefined (a failed seed is not averaged in)."""
    if any(x is None or not np.isfinite(x) for x in v):
        return "-"
    return f"{np.mean(v):.3f} / {np.max(v):.3f}"


def _pct(h):
    return "-" if h is None else f"{round(100 * h) + 0:d} %"   # + 0: no "-0 %"


def families_table(data):
    """Markdown: one row per held-out family (bundled policy, ``policy_bp`` if evaluated, imm2, the strongest
    classical tracker, hindsight_q, clairvoyant; ratios to imm2 with paired 95 % intervals)."""
    bp = any("policy_bp" in r["policies"] for r in data["families"].values())
    lines = ["| family (runs) | policy m (/ imm2) | " + ("policy_bp m (/ imm2) | " if bp else "")
             + "imm2 m | strongest classical m (policy / it" + (", policy_bp / it" if bp else "")
             + ") | hindsight_q m (/ imm2) | clairvoyant m (/ imm2) | track loss policy / "
             + ("policy_bp / " if bp else "") + "imm2 | share of the imm2 -> hindsight_q headroom |",
             "|---" * (8 + bp) + "|"]
    for suite, res in data["families"].items():
        few = res["few_runs"]
        p, tr, s = res["policies"]["policy"], res["trackers"], res["strongest_classical"]
        b = res["policies"].get("policy_bp") if bp else None
        h = res.get("headroom_share")
        lines.append(
            f"| {suite} ({res['runs']}) | {_m0(p['pos_rmse_m'])} ({_fmt_ratio(p['ratio_vs_imm2'], few)}) | "
            + (f"{_m0(b['pos_rmse_m'])} ({_fmt_ratio(b['ratio_vs_imm2'], few)}) | " if bp else "")
            + f"{_m0(tr['imm2']['pos_rmse_m'])} | {s} {_m0(tr[s]['pos_rmse_m'])} "
            f"({_fmt_ratio(p['ratio_vs_strongest'], few)}" + (f", {_fmt_ratio(b['ratio_vs_strongest'], few)}" if bp
                                                               else "") + ")"
            f" | {_m0(tr['hindsight_q']['pos_rmse_m'])} ({_fmt_ratio(res['ratio_vs_imm2']['hindsight_q'], few)}) | "
            f"{_m0(tr['clairvoyant']['pos_rmse_m'])} ({_fmt_ratio(res['ratio_vs_imm2']['clairvoyant'], few)}) | "
            f"{100 * p['track_loss_rate']:.1f} % / " + (f"{100 * b['track_loss_rate']:.1f} % / " if bp else "")
            + f"{100 * tr['imm2']['track_loss_rate']:.1f} % | {_pct(h)} |")
    return "\n".join(lines)


def _seeds(data, recipe):
    return data["recipes"][recipe]["seeds"]


def spread_table(data):
    """Markdown: per suite, each recipe's mean and worst ratio to imm2 over its seeds, and to the strongest
    classical tracker; the bundles' own ratios (``policy``, and ``policy_bp``, ``policy_imm_bp`` if evaluated)
    beside them."""
    recipes = list(data["recipes"])
    extra = [b for b in ("policy_bp", "policy_imm_bp", "policy_imm_ppo") if any(b in r["policies"] for r in data["spread"].values())]
    head = "| suite (runs) | bundle / imm2 | " + "".join(f"{b} / imm2 | " for b in extra) + " | ".join(
        f"{r}: mean / worst over {len(_seeds(data, r))} seeds, / imm2 | {r}: mean / worst, / strongest"
        for r in recipes)
    lines = [head + " |", "|---" * (2 + len(extra) + 2 * len(recipes)) + "|"]
    for suite, res in data["spread"].items():
        cells = [f"{suite} ({res['runs']})", _fmt_ratio(res["policies"]["policy"]["ratio_vs_imm2"], res["few_runs"])]
        for b in extra:
            cells.append(_fmt_ratio(res["policies"][b]["ratio_vs_imm2"], res["few_runs"]))
        for r in recipes:
            for key in ("ratio_vs_imm2", "ratio_vs_strongest"):
                v = [res["policies"][s][key][0] for s in _seeds(data, r)]
                cells.append(_mean_worst(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _bound_ok(p):
    """The issue's per-suite bound: ratio to imm2 <= 1.0 with the interval's upper end <= 1.05, and not worse
    than the strongest classical tracker beyond its interval (its lower end <= 1)."""
    r, (lo, hi) = p["ratio_vs_imm2"]
    return bool(r <= 1.0 and hi <= 1.05 and p["ratio_vs_strongest"][1][0] <= 1.0 and not p.get("failed_runs"))


def targets(data):
    """Issue 20's targets for the bundled policy (held-out seeds), then issue 25's for ``policy_bp`` if it was
    evaluated (:func:`bp_targets`), each ``(target, reached, numbers)``."""
    sp = data["spread"]
    pol = {s: r["policies"]["policy"] for s, r in sp.items()}
    out = []
    r, ci = pol["random"]["ratio_vs_imm2"]
    out.append(("random <= 0.88 x imm2 (stretch 0.85)", r <= 0.88, f"{r:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"))
    r, ci = pol["random"]["ratio_vs_strongest"]
    out.append((f"random: 95 % interval of the ratio to the strongest classical ({sp['random']['strongest_classical']})"
                " below 1", ci[1] < 1.0, f"{r:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"))
    bounded = [s for s in sp if s in NAMED_SUITES or s in HELDOUT_FAMILY_SUITES]
    bad = [s for s in bounded if not _bound_ok(pol[s])]
    out.append(("every named scenario and held-out family: <= 1.0 x imm2, upper end <= 1.05, not worse than the "
                "strongest classical beyond its interval", not bad,
                "fails on " + ", ".join(f"{s} ({pol[s]['ratio_vs_imm2'][0]:.3f} [{pol[s]['ratio_vs_imm2'][1][0]:.3f},"
                                        f" {pol[s]['ratio_vs_imm2'][1][1]:.3f}] / imm2, "
                                        f"{pol[s]['ratio_vs_strongest'][0]:.3f} / {sp[s]['strongest_classical']})"
                                        for s in bad) if bad else f"all {len(bounded)} suites"))
    worse = [s for s in sp if pol[s]["track_loss_rate"] > sp[s]["trackers"]["imm2"]["track_loss_rate"]]
    out.append(("track-loss rate <= imm2's on every suite", not worse,
                "worse on " + ", ".join(f"{s} ({100 * pol[s]['track_loss_rate']:.1f} % vs "
                                        f"{100 * sp[s]['trackers']['imm2']['track_loss_rate']:.1f} %)" for s in worse)
                if worse else f"all {len(sp)} suites"))
    rec = data.get("bundle_recipe")
    for r in sorted(data["recipes"], key=lambda r: r != rec):   # the bundle's recipe first (a target), then others
        seeds = _seeds(data, r)
        named_ok = [s for s in seeds if all(sp[n]["policies"][s]["ratio_vs_imm2"][0] <= 1.0
                                            and sp[n]["policies"][s]["ratio_vs_imm2"][1][1] <= 1.05
                                            for n in NAMED_SUITES if n in sp)]
        what = "the bundle's recipe" if r == rec else "another recipe"
        out.append((f"at least 2 of 3 seeds of {what} ({r}) meet the named-scenario bound (<= 1.0 x imm2, upper "
                    "end <= 1.05, on each named scenario)", len(named_ok) >= 2 if r == rec else None,
                    f"{len(named_ok)} of {len(seeds)} ({', '.join(named_ok) or 'none'})"))
    shares = {s: r.get("headroom_share") for s, r in data["families"].items()}
    out.append(("share of the imm2 -> hindsight_q headroom captured (families)", None,
                ", ".join(f"{s} {_pct(v)}" for s, v in shares.items())))
    if "policy_bp" in sp["random"]["policies"]:
        seeds = data["recipes"][BP_RECIPE]["seeds"] if BP_RECIPE in data["recipes"] else []
        out += bp_targets(sp, "policy_bp", seeds)
    if "policy_imm_bp" in sp["random"]["policies"]:
        seeds = data["recipes"][IMM_RECIPE]["seeds"] if IMM_RECIPE in data["recipes"] else []
        out += imm_targets(sp, "policy_imm_bp", seeds, _train_minutes(IMM_RECIPE_DIR, seeds))
    if "policy_imm_ppo" in sp["random"]["policies"]:
        seeds = data["recipes"][IMM_PPO_RECIPE]["seeds"] if IMM_PPO_RECIPE in data["recipes"] else []
        out += imm_targets(sp, "policy_imm_ppo", seeds)
    if "policy_imm_bp_prior" in sp["random"]["policies"]:
        seeds = data["recipes"][IMM_PRIOR_RECIPE]["seeds"] if IMM_PRIOR_RECIPE in data["recipes"] else []
        out += imm_targets(sp, "policy_imm_bp_prior", seeds, _train_minutes(IMM_PRIOR_RECIPE_DIR, seeds))
    if "policy_bp_prior" in sp["random"]["policies"]:
        seeds = data["recipes"][BP_PRIOR_RECIPE]["seeds"] if BP_PRIOR_RECIPE in data["recipes"] else []
        out += bp_targets(sp, "policy_bp_prior", seeds)
    if "policy_window" in sp["random"]["policies"]:
        r = LEARNED_RECIPES["policy_window"]
        seeds = data["recipes"][r]["seeds"] if r in data["recipes"] else []
        out += bp_targets(sp, "policy_window", seeds, tested=WINDOW_TESTED)
    out += causal_targets(data)
    return out


LEARNED_RECIPES = {"policy_bp": BP_RECIPE, "policy_imm_bp": IMM_RECIPE, "policy_imm_ppo": IMM_PPO_RECIPE,
                   "policy_imm_bp_prior": IMM_PRIOR_RECIPE, "policy_bp_prior": BP_PRIOR_RECIPE,
                   "policy_window": WINDOW_RECIPE}
"""Bundled learned tracker -> the recipe whose seeds it was chosen from (the PPO q-policy ``policy`` has its own
recipes and targets)."""
RECIPE_DIRS = (RECIPE_DIR, BP_RECIPE_DIR, IMM_RECIPE_DIR, IMM_PPO_RECIPE_DIR, IMM_PRIOR_RECIPE_DIR, BP_PRIOR_RECIPE_DIR,
               WINDOW_RECIPE_DIR)
"""Every folder of shipped seeds (the PPO q-policy's recipes, then one per bundled learned tracker's recipe)."""


def shipped_realisations():
    """``{bundled tracker: {"<tracker>_<folder>": its policy.npz}}`` of every folder of :data:`REALISATION_DIRS`."""
    return {b: {f"{b}_{p.parent.name}": p for p in sorted(Path(d).glob("*/policy.npz"))}
            for b, d in REALISATION_DIRS.items()}


def shipped_seeds():
    """Every shipped seed of every recipe: ``{seed folder name: its weights file}`` (:func:`recipe_policies` of each
    of :data:`RECIPE_DIRS`)."""
    return {n: p for d in RECIPE_DIRS for n, p in recipe_policies(d).items()}


def causal_targets(data):
    """Issue 38's targets for the learned trackers (held-out seeds): the best one on ``random`` at most 0.88 x
    imm_cv_ct (stretch: within 2 % of ``rbpf``), on at least 2 of 3 training seeds of its recipe; and, for that
    tracker, every named scenario, family and adsb_heldout at most 1.0 x the strongest classical tracker (``rbpf``
    among them) with the interval's upper end at most 1.02, track loss at most imm_cv_ct's on every suite, ANEES on
    ``random`` within [0.7, 2]; each ``(target, reached, numbers)``."""
    spread = data["spread"]
    sp = spread["random"]
    learned = {n: sp["policies"][n]["ratio_vs_imm_cv_ct"] for n in LEARNED_RECIPES if n in sp["policies"]}
    if not learned or "rbpf" not in sp["trackers"]:
        return []
    best = min(learned, key=lambda n: learned[n][0])
    rbpf = sp["trackers"]["rbpf"]["pos_rmse_m"] / sp["trackers"]["imm_cv_ct"]["pos_rmse_m"]
    r = learned[best][0]
    others = ", ".join(f"{n} {learned[n][0]:.3f}" for n in sorted(learned, key=lambda n: learned[n][0]) if n != best)
    return [("best learned tracker on random <= 0.88 x imm_cv_ct", r <= 0.88,
             f"{best} {_f3(learned[best])} (then {others}); rbpf {rbpf:.3f}"),
            ("stretch: within 2 % of rbpf on random", r <= 1.02 * rbpf, f"{best} / rbpf {r / rbpf:.3f}"),
            _training_seeds_target(data, best)] + _causal_suite_targets(spread, best)


def _training_seeds_target(data, best):
    """The row "on at least 2 of 3 training seeds of its recipe" for the tracker ``best``. An ensemble bundle is
    counted over the realisations of its whole recipe (itself and :data:`REALISATION_DIRS`' folder, each trained
    from its own seeds): at least two, and at least two thirds of them, at most 0.88 x imm_cv_ct on ``random``
    (two of two: no third can make it fewer than two of three). Its recipe's networks alone are listed beside."""
    sp = data["spread"]["random"]["policies"]

    def listed(names):
        return ", ".join(f"{n} {sp[n]['ratio_vs_imm_cv_ct'][0]:.3f}" for n in names)
    seeds = data["recipes"].get(LEARNED_RECIPES[best], {}).get("seeds", [])
    good = [n for n in seeds if sp[n]["ratio_vs_imm_cv_ct"][0] <= 0.88]
    real = data.get("realisations", {}).get(best, [])
    if not real:
        return ("on at least 2 of 3 training seeds of its recipe", len(good) >= 2,
                f"{len(good)} of {len(seeds)}: {listed(seeds)}")
    whole = [best, *real]
    ok = [n for n in whole if sp[n]["ratio_vs_imm_cv_ct"][0] <= 0.88]
    return ("on at least 2 of 3 training seeds of its recipe", len(ok) >= max(2, -(-2 * len(whole) // 3)),
            f"the ensemble recipe, {len(ok)} of {len(whole)} realisations trained from their own seeds: "
            f"{best} (the bundle) {sp[best]['ratio_vs_imm_cv_ct'][0]:.3f}, {listed(real)}; the networks of the "
            f"bundle alone {len(good)} of {len(seeds)}: {listed(seeds)}")


def _causal_suite_targets(spread, best):
    """:func:`causal_targets`' rows for the tracker ``best`` on every suite."""
    bad = _imm_bad_suites(spread, best)
    n_bounded = sum(s in NAMED_SUITES or s in HELDOUT_FAMILY_SUITES for s in spread)
    worse = _imm_worse_loss(spread, best)
    p = spread["random"]["policies"][best]
    a = p["anees"] if not p.get("anees_few_valid_looks") else float("nan")     # too few valid looks: no ANEES
    return [(f"{best}: every named scenario, family and adsb_heldout <= 1.0 x the strongest classical (rbpf "
             "included), upper end <= 1.02", not bad,
             f"fails on {len(bad)} of {n_bounded}: " + ", ".join(
                 f"{s} {_f3(spread[s]['policies'][best]['ratio_vs_strongest'])} / {spread[s]['strongest_classical']}"
                 for s in bad) if bad else f"all {n_bounded} suites"),
            (f"{best}: track loss <= imm_cv_ct's on every suite", not worse,
             "worse on " + ", ".join(worse) if worse else f"all {len(spread)} suites"),
            (f"{best}: ANEES on random within [0.7, 2]", bool(0.7 <= a <= 2.0), f"{a:.2f}")]


def _train_minutes(recipe_dir, seeds):
    """``{seed: (wall minutes to the best checkpoint, to the end, 1-min load at the end)}`` from the shipped
    ``summary.json`` files."""
    out = {}
    for n in seeds:
        f = Path(recipe_dir) / n / "summary.json"
        if f.is_file():
            sm = json.loads(f.read_text())
            out[n] = ((sm.get("best_wall_s") or float("nan")) / 60, sm["wall_s"] / 60, sm.get("loadavg_1min_at_end"))
    return out


def _anees(m):
    """A tracker's ANEES, NaN (so that no target passes on it) when too few of its looks had a valid NEES."""
    return float("nan") if m.get("anees_few_valid_looks") else m["anees"]


def _imm_suite_ok(p):
    """The learned IMM's per-suite bound: at most 1.0 x the strongest classical tracker, upper end <= 1.02."""
    r, (lo, hi) = p["ratio_vs_strongest"]
    return bool(r <= 1.0 and hi <= 1.02 and not p.get("failed_runs"))


def _imm_vs_cv_ct(spread, name, suite, limit):
    return spread[suite]["policies"][name]["ratio_vs_imm_cv_ct"][0] <= limit


def _imm_bad_suites(spread, name):
    """The named scenarios, families and adsb_heldout where ``name`` misses the learned IMM's per-suite bound."""
    return [s for s in spread if (s in NAMED_SUITES or s in HELDOUT_FAMILY_SUITES)
            and not _imm_suite_ok(spread[s]["policies"][name])]


def _imm_all_ok(spread, name):
    return (_imm_vs_cv_ct(spread, name, "random", 0.90) and _imm_vs_cv_ct(spread, name, "bizup2002", 0.95)
            and not _imm_bad_suites(spread, name))


def _imm_worse_loss(spread, name):
    p = {s: r["policies"][name]["track_loss_rate"] for s, r in spread.items()}
    return [s for s in spread if p[s] > spread[s]["trackers"]["imm_cv_ct"]["track_loss_rate"]]


def imm_targets(spread, policy="policy_imm_bp", seeds=(), minutes=None):
    """The learned IMM's targets (``policy`` and its recipe's ``seeds``, held-out seeds) from a seed-spread dict:
    each ``(target, reached, numbers)``. ``minutes``: :func:`_train_minutes` of the seeds."""
    pol = {s: r["policies"][policy] for s, r in spread.items()}
    bounded = [s for s in spread if s in NAMED_SUITES or s in HELDOUT_FAMILY_SUITES]

    def vs_cv_ct(name, suite, limit):
        return _imm_vs_cv_ct(spread, name, suite, limit)

    def bad_suites(name):
        return _imm_bad_suites(spread, name)

    out = [(f"{policy}: random <= 0.90 x imm_cv_ct (stretch 0.85)", vs_cv_ct(policy, "random", 0.90),
            _f3(pol["random"]["ratio_vs_imm_cv_ct"])),
           (f"{policy}: bizup2002 <= 0.95 x imm_cv_ct", vs_cv_ct(policy, "bizup2002", 0.95),
            _f3(pol["bizup2002"]["ratio_vs_imm_cv_ct"]))]
    bad = bad_suites(policy)
    out.append((f"{policy}: every named scenario, family and adsb_heldout: <= 1.0 x the strongest classical, upper "
                "end <= 1.02", not bad,
                "fails on " + ", ".join(f"{s} ({_f3(pol[s]['ratio_vs_strongest'])} / "
                                        f"{spread[s]['strongest_classical']})" for s in bad)
                if bad else f"all {len(bounded)} suites"))
    if seeds:
        good = [n for n in seeds if _imm_all_ok(spread, n)]
        out.append((f"at least 2 of 3 seeds of {policy}'s recipe meet these three", len(good) >= 2,
                    f"{len(good)} of {len(seeds)} ({', '.join(good) or 'none'}); random / imm_cv_ct, bizup2002 / "
                    "imm_cv_ct: " + ", ".join(
                        f"{n} {spread['random']['policies'][n]['ratio_vs_imm_cv_ct'][0]:.3f}, "
                        f"{spread['bizup2002']['policies'][n]['ratio_vs_imm_cv_ct'][0]:.3f} "
                        f"({len(bad_suites(n))} suites fail the bound)" for n in seeds)))
    worse = _imm_worse_loss(spread, policy)
    out.append((f"{policy}: track-loss rate <= imm_cv_ct's on every suite", not worse,
                "worse on " + ", ".join(f"{s} ({100 * pol[s]['track_loss_rate']:.1f} % vs "
                                        f"{100 * spread[s]['trackers']['imm_cv_ct']['track_loss_rate']:.1f} %)"
                                        for s in worse) if worse else f"all {len(spread)} suites"))
    a, ref = _anees(pol["random"]), _anees(spread["random"]["trackers"]["imm_cv_ct"])
    out.append((f"{policy}: ANEES on random <= imm_cv_ct's", bool(a <= ref), f"{a:.2f} vs {ref:.2f}"))
    if minutes:
        out.append(("backprop training: a seed in at most 30 minutes on the idle 2-core machine",
                    None, "not timed idle: " + ", ".join(
                        f"{n} best at {b:.0f} min, end at {e:.0f} min (load {ld:.1f})" for n, (b, e, ld)
                        in minutes.items())))
        out.append(("at its initial weights it is imm_cv_ct; its torch forward equals the numba IMM (1e-9)", None,
                    "tested: tests/test_learned_imm.py, tests/test_torch_imm.py (a failure fails the test suite)"))
    return out


def imm_targets_readme(data):
    """The README's compact table of the learned IMMs' targets (held-out seeds): one row per target, one column per
    learned IMM with its recipe's seeds (the full rows are in :func:`targets_table`)."""
    sp = data["spread"]
    cols = [(p, r) for p, r in (("policy_imm_bp", IMM_RECIPE), ("policy_imm_ppo", IMM_PPO_RECIPE),
                                ("policy_imm_bp_prior", IMM_PRIOR_RECIPE))
            if p in sp["random"]["policies"]]
    if not cols:
        return "(no learned IMM was evaluated)"

    def cell(ok, text):
        return f"{'yes' if ok else '**no**'}: {text}"

    rows = {"random <= 0.90 x imm_cv_ct": [], "bizup2002 <= 0.95 x imm_cv_ct": [],
            "every named scenario, family and adsb_heldout: <= 1.0 x the strongest classical (upper end <= 1.02)": [],
            "at least 2 of 3 seeds meet the three above": [], "track loss <= imm_cv_ct's on every suite": [],
            "ANEES on random <= imm_cv_ct's": []}
    cells = list(rows.values())
    for p, rec in cols:
        for j, suite, lim in ((0, "random", 0.90), (1, "bizup2002", 0.95)):
            cells[j].append(cell(_imm_vs_cv_ct(sp, p, suite, lim), _f3(sp[suite]["policies"][p]["ratio_vs_imm_cv_ct"])))
        bad = _imm_bad_suites(sp, p)
        worst = max(bad, key=lambda s: sp[s]["policies"][p]["ratio_vs_strongest"][0], default=None)
        cells[2].append(cell(not bad, f"{len(bad)} suites fail, worst {worst} "
                             f"{sp[worst]['policies'][p]['ratio_vs_strongest'][0]:.3f}" if bad else "all suites"))
        seeds = data["recipes"].get(rec, {}).get("seeds", [])
        good = [n for n in seeds if _imm_all_ok(sp, n)]
        cells[3].append(cell(len(good) >= 2, f"{len(good)} of {len(seeds)}"))
        worse = _imm_worse_loss(sp, p)
        cells[4].append(cell(not worse, f"worse on {', '.join(worse)}" if worse else "all suites"))
        a, ref = _anees(sp["random"]["policies"][p]), _anees(sp["random"]["trackers"]["imm_cv_ct"])
        cells[5].append(cell(bool(a <= ref), f"{a:.2f} vs {ref:.2f}"))
    lines = ["| target (held-out seeds) | " + " | ".join(p for p, _ in cols) + " |",
             "|---|" + "---|" * len(cols)]
    lines += [f"| {name} | " + " | ".join(c) + " |" for name, c in rows.items()]
    return "\n".join(lines)


def _f3(r):
    est, (lo, hi) = r
    return f"{est:.3f} [{lo:.3f}, {hi:.3f}]"


def _bp_suite_ok(p):
    """Issue 25's per-suite bound: at most 1.0 x the strongest classical tracker, the interval's upper end <= 1.03."""
    r, (lo, hi) = p["ratio_vs_strongest"]
    return bool(r <= 1.0 and hi <= 1.03 and not p.get("failed_runs"))


BP_TESTED = ("the torch chain equals the numba chain to 1e-9; acting in the env equals the batched evaluation to 1e-9",
             "tested: tests/test_torch_chain.py, tests/test_backprop.py (a failure fails the test suite)")
"""The last row of :func:`bp_targets` for a q-policy trained by backpropagation: what its tests check."""
WINDOW_TESTED = ("the correction's compiled inputs equal the numpy reference; in the env (CorrectedEstimate) it equals "
                 "the batched evaluation to 1e-9", "tested: tests/test_window_correction.py (a failure fails the test "
                                                   "suite)")


def bp_targets(spread, policy="policy_bp", seeds=(), tested=BP_TESTED):
    """Issue 25's targets (the backprop policy ``policy`` and its recipe's ``seeds``, held-out seeds) from a
    seed-spread dict (``{suite: evaluate_suite(...)}``): each ``(target, reached, numbers)``; the last row says what
    the tracker's tests check (``tested``: ``(what, where)``)."""
    pol = {s: r["policies"][policy] for s, r in spread.items()}
    bounded = [s for s in spread if (s in NAMED_SUITES or s in HELDOUT_FAMILY_SUITES) and s not in LONG_TURN_SUITES]
    out = []

    def random_ok(name):
        return spread["random"]["policies"][name]["ratio_vs_imm_cv_ct"][0] <= 0.93

    def suites_ok(name):
        return [s for s in bounded if not _bp_suite_ok(spread[s]["policies"][name])]

    out.append((f"{policy}: random <= 0.93 x imm_cv_ct", random_ok(policy),
                _f3(pol["random"]["ratio_vs_imm_cv_ct"])))
    bad = suites_ok(policy)
    out.append((f"{policy}: every named scenario, family and adsb_heldout except the long turns "
                f"({', '.join(LONG_TURN_SUITES)}): <= 1.0 x the strongest classical, upper end <= 1.03", not bad,
                "fails on " + ", ".join(f"{s} ({_f3(pol[s]['ratio_vs_strongest'])} / "
                                        f"{spread[s]['strongest_classical']})" for s in bad)
                if bad else f"all {len(bounded)} suites"))
    out.append((f"{policy}: the long turns against the strongest classical (no target)", None,
                ", ".join(f"{s} {_f3(pol[s]['ratio_vs_strongest'])} / {spread[s]['strongest_classical']}"
                          for s in LONG_TURN_SUITES if s in spread)))
    if seeds:
        both = [n for n in seeds if random_ok(n) and not suites_ok(n)]
        out.append((f"at least 2 of 3 seeds of {policy}'s recipe meet both", len(both) >= 2,
                    f"{len(both)} of {len(seeds)} ({', '.join(both) or 'none'}); random / imm_cv_ct "
                    + ", ".join(f"{n} {spread['random']['policies'][n]['ratio_vs_imm_cv_ct'][0]:.3f} "
                                f"({len(suites_ok(n))} suites fail)" for n in seeds)))
    worse = [s for s in spread if pol[s]["track_loss_rate"] > spread[s]["trackers"]["imm2"]["track_loss_rate"]]
    out.append((f"{policy}: track-loss rate <= imm2's on every suite", not worse,
                "worse on " + ", ".join(f"{s} ({100 * pol[s]['track_loss_rate']:.1f} % vs "
                                        f"{100 * spread[s]['trackers']['imm2']['track_loss_rate']:.1f} %)"
                                        for s in worse) if worse else f"all {len(spread)} suites"))
    out.append((f"{policy}: ANEES of its reported covariance beside imm_cv_ct's (1 is consistent; no target)", None,
                ", ".join(f"{s} {pol[s]['anees']:.2f} / {spread[s]['trackers']['imm_cv_ct']['anees']:.2f}"
                          for s in spread)))
    out.append((tested[0], None, tested[1]))
    return out


def targets_table(data):
    lines = ["| target (bundled policy, held-out seeds) | reached | numbers |", "|---|---|---|"]
    for name, ok, nums in targets(data):
        lines.append(f"| {name} | {'-' if ok is None else ('yes' if ok else '**no**')} | {nums} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ main
def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m agents.reports.generalisation", description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", default="docs")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE)
    ap.add_argument("--family-runs", type=int, default=FAMILY_RUNS)
    ap.add_argument("--no-readme", dest="readme", action="store_false", help="do not update the generated blocks of docs/*.md")
    ap.add_argument("--add-recipe", metavar="RECIPE", choices=sorted(RECIPES),
                    help="add one recipe's seeds (and its bundle, policy_imm_bp for imm_bp, with the bundle's "
                         "other realisations) to the seed spread of the existing docs/generalisation.json (same "
                         "--seed; the classical field is recomputed on the same episodes, every other number is kept) "
                         "and rewrite the blocks (default: compute everything)")
    args = ap.parse_args(argv)
    from agents.reports.blocks import check_report_options
    check_report_options(args)
    t0 = time.time()
    docs = Path(args.docs)
    if args.add_recipe:
        return _add_recipe(args, docs, t0)
    bundle = {"policy": load_policy(BUNDLED_POLICY)}
    for name in LEARNED_RECIPES:
        if BUNDLED_POLICIES[name].is_file():
            bundle[name] = load_policy(BUNDLED_POLICIES[name])
    seeds = {n: load_policy(p) for n, p in shipped_seeds().items()}
    real = {b: names for b, names in shipped_realisations().items() if names and b in bundle}
    seeds.update({n: load_policy(p) for names in real.values() for n, p in names.items()})
    data = {"seed": args.seed, "classical": list(CLASSICAL), "recipes": {}, "families": {}, "spread": {},
            "realisations": {b: sorted(names) for b, names in real.items()}}
    for r, what in RECIPES.items():
        names = [n for n in seeds if n.rsplit("_s", 1)[0] == r]
        if names:
            data["recipes"][r] = {"description": what, "seeds": names}
    cfg_file = BUNDLED_POLICY.with_name("training.json")
    if cfg_file.is_file():
        data["bundle_recipe"] = json.loads(cfg_file.read_text()).get("recipe")
    for suite in HELDOUT_FAMILY_SUITES:
        eps = draw_suite(suite, _runs(suite, args.family_runs), seed=args.seed)
        data["families"][suite] = evaluate_suite(suite, eps, bundle, BOUNDS)
        print(f"{suite}: family table ({time.time() - t0:.0f} s)", flush=True)
    for suite in DEFAULT_SUITES + HELDOUT_FAMILY_SUITES:
        eps = draw_suite(suite, _runs(suite, 200), seed=args.seed)
        data["spread"][suite] = evaluate_suite(suite, eps, {**bundle, **seeds})
        print(f"{suite}: seed spread ({time.time() - t0:.0f} s)", flush=True)
    data["track_start"] = track_start_study(args.seed, 200)
    data["seconds"] = time.time() - t0
    _write(args, docs, data)


def _add_recipe(args, docs, t0):
    """``--add-recipe``: one recipe's seeds (and its bundle) into the seed spread of the existing JSON."""
    data = json.loads((docs / "generalisation.json").read_text())
    if data.get("seed") != args.seed:
        raise SystemExit(f"error: --add-recipe: docs/generalisation.json was computed with --seed "
                         f"{data.get('seed')}, not {args.seed}")
    r = args.add_recipe
    paths = {n: p for n, p in shipped_seeds().items() if n.rsplit("_s", 1)[0] == r}
    if not paths:
        raise SystemExit(f"error: --add-recipe: no seeds of {r!r} are shipped")
    pols = {n: load_policy(p) for n, p in paths.items()}
    bundled = {rec: (name, BUNDLED_POLICIES[name]) for name, rec in LEARNED_RECIPES.items()}   # its bundle again too
    if r in bundled and bundled[r][1].is_file():
        pols[bundled[r][0]] = load_policy(bundled[r][1])
        real = shipped_realisations().get(bundled[r][0], {})      # and the other realisations of its recipe
        pols.update({n: load_policy(p) for n, p in real.items()})
        if real:
            data.setdefault("realisations", {})[bundled[r][0]] = sorted(real)
    data["recipes"][r] = {"description": RECIPES[r], "seeds": sorted(paths)}
    for suite, old in data["spread"].items():
        eps = draw_suite(suite, old["runs"], seed=args.seed)
        new = evaluate_suite(suite, eps, pols)
        for t, m in new["trackers"].items():     # the same episodes: the classical field must come out the same
            if m["pos_rmse_m"] != old["trackers"][t]["pos_rmse_m"]:
                raise SystemExit(f"error: --add-recipe: {suite}/{t} now scores {m['pos_rmse_m']!r} m, the JSON "
                                 f"{old['trackers'][t]['pos_rmse_m']!r}: recompute everything (no --add-recipe)")
        old["policies"].update(new["policies"])
        print(f"{suite}: {r} seeds ({time.time() - t0:.0f} s)", flush=True)
    data.setdefault("added_recipes_seconds", {})[r] = time.time() - t0
    _write(args, docs, data)


def _write(args, docs, data):
    (docs / "generalisation.json").write_text(json.dumps(jsonable(data), indent=1, allow_nan=False))
    blocks = {"families": families_table(data), "seed-spread": spread_table(data), "targets": targets_table(data),
              "track-start": track_start_table(data), "imm-targets": imm_targets_readme(data)}
    if args.readme:
        from agents.reports.blocks import replace_block
        for name, text in blocks.items():
            replace_block(name, text)
    print("\n\n".join(blocks.values()))


if __name__ == "__main__":
    main()
