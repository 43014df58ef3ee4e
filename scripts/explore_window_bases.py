"""A window correction over the classical bank ``imm_ct_bank`` (which holds long turns) against one over
``policy_bp_prior`` (the bundled correction's base, its last 12 q among the inputs): does a base that holds the turn
leave the correction less to do, or more? (issue 38; docs/training.md, "Closing the gap to rbpf"). An experiment,
not a tracker.

    python scripts/explore_window_bases.py EPISODES EPOCHS SEED [broad] [OUT.json]
    python scripts/explore_window_bases.py 1000 10 0          # the run in training.md (about 6 min)

The same training for both bases (no mirror, standardised inputs, suites weighted by the base's mean squared error,
Adam lr 2e-3 cosine-decayed, batches of 4,096 looks, tanh layers 128-128, inputs of 24 looks with fits through the
last 6-24), on ``EPISODES`` each of ``random`` and ``random_radars`` from training seeds ``SEED + i`` (with
``broad``, as many of each with the broad laws, :func:`agents.training.window.broad_config`, from ``SEED +
300,000 + i``). Validation, training-range seeds only: ``random`` and ``random_radars`` at 900,000 + i and the same
generators with the broad laws at 940,000 + i, 100 flights each, beside ``imm_cv_ct``, ``imm_ct_bank`` and ``rbpf``.
"""
import json, math, sys, time
from pathlib import Path
import numpy as np

from agents.evaluation.metrics import region_masks
from agents.evaluation.suites import draw_suite
from agents.policies.learned import load_learned
from agents.policies.window_correction import window_features
from agents.training.selection import SELECTION_SEED_BASE, pooled_rmse
from agents.training.window import broad_config
from baselines.registry import run_tracker
from radar_env.sim.episode import stack_episodes

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _window_fit import ClassicalBase, fit_regression  # noqa: E402

args = sys.argv[1:]
WITH_BROAD = "broad" in args
args = [a for a in args if a != "broad"]
if len(args) not in (3, 4):
    sys.exit("usage: python scripts/explore_window_bases.py EPISODES EPOCHS SEED [broad] [OUT.json]")
N_EP, EPOCHS, SEED = int(args[0]), int(args[1]), int(args[2])
K, SCALE, FITS = 24, 300.0, (6, 8, 12, 16, 24)



ARMS = {"bp_prior": (load_learned("policy_bp_prior"), 12),
        "imm_ct_bank": (ClassicalBase("imm_ct_bank"), 0)}


def looks(base, q_looks, eps):
    b = stack_episodes(eps)
    run = base.run(eps)
    F, ca, sa = window_features(b.t_s, b.z_m, b.R_m2, b.detected, run.x, run.P, K, SCALE, FITS, run.q_m_s2, q_looks)
    dx, dy = b.truth[..., 0] - run.x[..., 0], b.truth[..., 1] - run.x[..., 1]
    Y = np.stack([dx * ca + dy * sa, -dx * sa + dy * ca], -1) / SCALE
    used = region_masks(b, run.start_index)["used"] & np.isfinite(F).all(-1) & np.isfinite(Y).all(-1)
    lost = int((region_masks(b, run.start_index)["used"] & ~np.isfinite(Y).all(-1)).sum())
    return dict(F=F[used], Y=Y[used], lost=lost)


t0 = time.time()
laws = broad_config()
train_sets = [("random", None, SEED), ("random_radars", None, SEED)]
if WITH_BROAD:
    train_sets += [("random", laws, SEED + 300_000), ("random_radars", laws, SEED + 300_000)]
val_sets = {"random": ("random", None, SELECTION_SEED_BASE),
            "random_radars": ("random_radars", None, SELECTION_SEED_BASE),
            "broad_random": ("random", laws, SELECTION_SEED_BASE + 40_000),
            "broad_random_radars": ("random_radars", laws, SELECTION_SEED_BASE + 40_000)}
val_eps = {k: draw_suite(g, 100, seed=s, random_config=c) for k, (g, c, s) in val_sets.items()}
res = {"episodes": N_EP, "epochs": EPOCHS, "seed": SEED, "broad_in_training": WITH_BROAD, "arms": {}}
for arm, (base, q_looks) in ARMS.items():
    train = []
    for g, c, s in train_sets:
        parts = [looks(base, q_looks, draw_suite(g, min(500, N_EP - c0), seed=s + c0, random_config=c))
                 for c0 in range(0, N_EP, 500)]
        train.append({k: np.concatenate([p[k] for p in parts]) for k in ("F", "Y")})
    val = {k: looks(base, q_looks, e) for k, e in val_eps.items()}
    base_rmse = {k: math.sqrt(((v["Y"] ** 2).sum(-1) * SCALE ** 2).mean()) for k, v in val.items()}
    print(arm, "base", {k: round(v, 1) for k, v in base_rmse.items()}, "lost", {k: v["lost"] for k, v in val.items()},
          f"({time.time() - t0:.0f} s)", flush=True)
    hist = fit_regression([(t["F"], t["Y"]) for t in train], {k: (v["F"], v["Y"]) for k, v in val.items()},
                          EPOCHS, SEED, SCALE, arm, t0)
    res["arms"][arm] = {"base": base_rmse, "history": hist}
ref = {}
for k, e in val_eps.items():
    b = stack_episodes(e)
    for t in ("imm_cv_ct", "imm_ct_bank", "rbpf"):
        ref.setdefault(k, {})[t] = pooled_rmse(b, run_tracker(t, e))
    print(k, ref[k], flush=True)
res["ref"] = ref
for arm, a in res["arms"].items():
    last = a["history"][-1]
    print(arm, {k: (round(last[k], 1), round(last[k] / ref[k]["rbpf"], 3)) for k in val_eps})
if len(args) == 4:
    json.dump(res, open(args[3], "w"), indent=1)
