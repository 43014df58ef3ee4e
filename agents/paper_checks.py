"""Reproduce the papers' reported numbers with our implementation, side by side (``python -m agents.paper_checks``).

Writes ``docs/paper_checks.md`` (or ``--out``). Every number in it is computed here; the papers' values are quoted
from the seeds for comparison. Checks:

1. Bizup (seed 000) section 3.2: c_min from a uniform-motion KF (q = 0.03 g) on ``bizup2002`` with Bizup's radar
   (bearing noise 0.1 deg), 20 runs: false-alarm rate of c_min > 0.5 g per update on straight legs and the delay
   in scans until each turn is declared. Paper: 9 false alarms in 20 x 73 updates (0.006 per update); the first
   turn detected immediately, the second within two scans.
2. Adrian (seed 003): turn-rate error (estimate - truth) standard deviation and maximum over the flower for
   algorithm 1 (n = 4, on plots) and algorithm 2 (n = 4, filtered headings of his CT-KF with q = 0.1 g);
   paper: 0.579 / 4.599 deg/s and 0.586 / 3.356 deg/s. Also his position-noise reduction of the CT-KF with
   algorithm 2 vs the linear KF (1 - RMS estimate error / RMS plot error): paper 20.5 % vs 10.2 %.
3. Kim & Lee (seed 004): RMS position error of the conventional and the adaptive alpha-beta tracker on
   ``kim_lee_accel`` (the paper shows curves, no table; we report our numbers and the NPE).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from baselines import trackers as T
from radar_env.env import EnvConfig
from radar_env.episode import stack_episodes
from radar_env.units import G0_M_S2

from .metrics import evaluate_run, region_masks
from .suites import EVAL_SEED_BASE, draw_suite

__all__ = ["bizup_cmin_check", "adrian_check", "kim_lee_check", "main"]


def bizup_cmin_check(runs=20, seed=EVAL_SEED_BASE, threshold_g=0.5):
    eps = draw_suite("bizup2002", runs, seed)
    batch = stack_episodes(eps)
    run = T.run_q_policy(eps, lambda o: np.full(o.shape[0], 0.03 * G0_M_S2), "kf_0.03g")
    c = run.extra["c_min_g"]
    masks = region_masks(batch, run.start_index)
    used, man = masks["used"], masks["maneuver"]
    declared = (c > threshold_g) & used
    not_man = used & ~man
    fa_straight = declared[masks["straight"]].mean()
    fa_not_man = declared[not_man].mean()
    delays = [[], []]
    for b in range(runs):
        m = man[b]
        onsets = np.flatnonzero(m & ~np.r_[False, m[:-1]])
        for j, k0 in enumerate(onsets[:2]):
            hits = np.flatnonzero(declared[b, k0:])
            delays[j].append(int(hits[0]) if hits.size else np.nan)
    return {
        "runs": runs, "updates_per_run": int(used[0].sum()),
        "false_alarms_straight": int(declared[masks["straight"]].sum()),
        "straight_updates": int(masks["straight"].sum()), "fa_rate_straight": float(fa_straight),
        "false_alarms_not_maneuvering": int(declared[not_man].sum()), "fa_rate_not_maneuvering": float(fa_not_man),
        "delay_turn1_scans": delays[0], "delay_turn2_scans": delays[1],
    }


def adrian_check(runs=5, seed=EVAL_SEED_BASE):
    eps = draw_suite("adrian_flower", runs, seed)
    batch = stack_episodes(eps)
    truth_w = np.degrees(batch.truth_turn_rate_rad_s)
    out = {"runs": runs}
    lin = T.run_q_policy(eps, lambda o: np.full(o.shape[0], 0.1 * G0_M_S2), "linear_kf_0.1g")
    used = region_masks(batch, lin.start_index)["used"]
    det = used & batch.detected
    ez = np.hypot(*(batch.z_m - batch.truth[..., :2]).transpose(2, 0, 1))
    rms_plot = float(np.sqrt(np.mean(ez[det] ** 2)))

    def reduction(run):
        e = np.hypot(*(run.x[..., :2] - batch.truth[..., :2]).transpose(2, 0, 1))
        return float(1.0 - np.sqrt(np.mean(e[used] ** 2)) / rms_plot)

    w1 = lin.extra["turn_rate_alg1_deg_s"]   # algorithm 1 works on plots: independent of the filter
    err1 = (w1 - truth_w)[used & np.isfinite(w1)]
    a2 = T.run_turn_rate_kf(eps, 2, q_m_s2=0.1 * G0_M_S2)
    w2 = a2.extra["turn_rate_deg_s"]
    err2 = (w2 - truth_w)[used & np.isfinite(w2)]
    a1 = T.run_turn_rate_kf(eps, 1, q_m_s2=0.1 * G0_M_S2)
    out.update({
        "alg1_std_deg_s": float(np.std(err1)), "alg1_max_deg_s": float(np.max(np.abs(err1))),
        "alg2_std_deg_s": float(np.std(err2)), "alg2_max_deg_s": float(np.max(np.abs(err2))),
        "reduction_linear_kf": reduction(lin), "reduction_ct_kf_alg2": reduction(a2),
        "reduction_ct_kf_alg1": reduction(a1), "rms_plot_error_m": rms_plot,
    })
    return out


def kim_lee_check(runs=100, seed=EVAL_SEED_BASE):
    eps = draw_suite("kim_lee_accel", runs, seed)
    batch = stack_episodes(eps)
    cfg = EnvConfig()
    res = {}
    for name, adaptive in (("conventional", False), ("adaptive", True)):
        run = T.run_alpha_beta_tracker(eps, adaptive, cfg=cfg)
        m = evaluate_run(batch, run, n_boot=200)
        res[name] = {"pos_rmse_m": m["pos_rmse_m"], "pos_rmse_m_maneuver": m["pos_rmse_m_maneuver"],
                     "npe": m["npe"]}
    return {"runs": runs, **res}


def _md(b, a, k, seconds):
    d1 = np.array(b["delay_turn1_scans"], dtype=float)
    d2 = np.array(b["delay_turn2_scans"], dtype=float)
    lines = [
        "# Paper checks (generated by `python -m agents.paper_checks`)",
        "",
        f"Computed in {seconds:.0f} s on evaluation seeds. Papers' numbers quoted from the seeds.",
        "",
        "## Bizup: c_min > 0.5 g as a maneuver detector (bizup2002, Bizup's radar, bearing noise 0.1 deg)",
        "",
        "| quantity | paper | ours |",
        "|---|---|---|",
        f"| runs x updates per run | 20 x 73 | {b['runs']} x {b['updates_per_run']} |",
        f"| false-alarm rate per update, straight legs (>60 s after a turn) | 0.006 | {b['fa_rate_straight']:.4f} "
        f"({b['false_alarms_straight']} in {b['straight_updates']}) |",
        f"| false-alarm rate per update, all non-turning updates | - | {b['fa_rate_not_maneuvering']:.4f} "
        f"({b['false_alarms_not_maneuvering']}) |",
        f"| delay to declare turn 1 (scans), mean / max | 0 ('immediately') | {np.nanmean(d1):.2f} / "
        f"{np.nanmax(d1):.0f} |",
        f"| delay to declare turn 2 (scans), mean / max | <= 2 | {np.nanmean(d2):.2f} / {np.nanmax(d2):.0f} |",
        "",
        "Delays are counted in scans from the first look at which the truth is turning. Both turns of "
        "`bizup2002` start exactly at a look time (290 s, 610 s), when that plot does not yet show the turn, so a "
        "delay of 1 scan means the turn was declared on the first plot that could show it ('immediately').",
        "",
        "## Adrian: turn-rate estimation on the 12-leaf flower (n = 4, CT-KF q = 0.1 g)",
        "",
        "| quantity | paper | ours |",
        "|---|---|---|",
        f"| algorithm 1 error std / max (deg/s) | 0.579 / 4.599 | {a['alg1_std_deg_s']:.3f} / {a['alg1_max_deg_s']:.3f} |",
        f"| algorithm 2 error std / max (deg/s) | 0.586 / 3.356 | {a['alg2_std_deg_s']:.3f} / {a['alg2_max_deg_s']:.3f} |",
        f"| position-noise reduction, CT-KF with algorithm 2 | 20.5 % | {100 * a['reduction_ct_kf_alg2']:.1f} % |",
        f"| position-noise reduction, linear KF (q = 0.1 g) | 10.2 % | {100 * a['reduction_linear_kf']:.1f} % |",
        f"| position-noise reduction, CT-KF with algorithm 1 | - | {100 * a['reduction_ct_kf_alg1']:.1f} % |",
        "",
        f"({a['runs']} runs of 1561 looks; errors over every look after the track start, turns and legs. Not "
        "reproduced: our algorithm-1/2 error stdev is higher and our linear KF at 0.1 g lags the 3 deg/s turns "
        "(0.55 g) so badly that it is worse than the plots; the paper does not say over which looks its figures "
        "are taken, nor that its truth carries random acceleration noise, which ours does not.)",
        "",
        "## Kim & Lee: alpha-beta trackers on the +5 g / -5 g scenario",
        "",
        "| tracker | position RMSE (m) | during the accelerations (m) | NPE |",
        "|---|---|---|---|",
        *(f"| {n} | {k[n]['pos_rmse_m']:.1f} | {k[n]['pos_rmse_m_maneuver']:.1f} | {k[n]['npe']:.3f} |"
          for n in ("conventional", "adaptive")),
        "",
        f"({k['runs']} runs; conventional gains from the tuned constant q. The paper shows these as curves only.)",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m agents.paper_checks", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/paper_checks.md")
    ap.add_argument("--no-readme", dest="readme", action="store_false", help="do not update README.md")
    args = ap.parse_args(argv)
    t0 = time.time()
    b, a, k = bizup_cmin_check(), adrian_check(), kim_lee_check()
    text = _md(b, a, k, time.time() - t0)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text)
    if args.readme:
        from .readme_blocks import replace_block
        replace_block("paper-checks", text.split("\n", 2)[2].replace("## ", "#### "))
    print(text)


if __name__ == "__main__":
    main()
