"""Does a window correction over a range-rate base gain from the window's radial velocities? (issue 38 and the
range-rate trackers; docs/training.md, "On the range-rate filter"). An experiment, not a tracker.

    python scripts/explore_rdot_window.py BASE EPISODES EPOCHS SEED [OUT.json]
    python scripts/explore_rdot_window.py policy_imm_bp_rdot 2000 20 0      # the run in training.md (about 17 min)

Control: the window recipe's inputs (:func:`agents.policies.window_correction.window_features`: 24 looks, fits
through the last 6-24, no q) over ``BASE`` (a bundled learned tracker's name, or a classical tracker's). Treatment:
the same plus, per slot, the measured radial velocity's residual from the base's straight line through its
estimate ((m/s) / 30, clipped to +-30) and the line of sight along / across the base velocity (0 when the slot has
no plot). The same flights and training for both (no mirror, standardised inputs, suites weighted by the base's
mean squared error, Adam lr 2e-3 cosine-decayed, batches of 4,096 looks, tanh layers 128-128, the same seed).
Training flights: ``EPISODES`` each of ``random`` and ``random_radars`` from training seeds ``SEED + i``;
validation: 100 of each from the selection suites' seeds (900,000 + i), beside ``imm_ct_bank_rdot`` and
``rbpf_rdot`` on the same flights. Nothing held out is drawn.
"""
import json, math, sys, time
from pathlib import Path
import numpy as np

from agents.evaluation.metrics import region_masks
from agents.evaluation.suites import draw_suite
from agents.policies.learned import load_learned
from agents.policies.window_correction import window_features
from agents.training.selection import SELECTION_SEED_BASE, pooled_rmse
from baselines.registry import run_tracker
from radar_env.sim.episode import stack_episodes

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _window_fit import ClassicalBase, fit_regression  # noqa: E402

if len(sys.argv) not in (5, 6):
    sys.exit("usage: python scripts/explore_rdot_window.py BASE EPISODES EPOCHS SEED [OUT.json]")
BASE, N_EP, EPOCHS, SEED = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
K, SCALE, FITS, SV = 24, 300.0, (6, 8, 12, 16, 24), 30.0



base = load_learned(BASE) if BASE.startswith("policy") else ClassicalBase(BASE)


def rdot_features(b, run, ca, sa):
    """(B, L, 3K): per slot j the radial-velocity residual from the base's straight line through its estimate at
    look k, and the line of sight along / across the base velocity at the slot's predicted position."""
    B, L = b.t_s.shape
    out = np.zeros((B, L, 3 * K))
    x = run.x
    for j in range(K):
        kk = np.arange(L) - j
        ok = kk >= 0
        kc = np.maximum(kk, 0)
        det = b.detected[:, kc] & ok[None, :]
        tau = b.t_s[:, kc] - b.t_s
        px = x[..., 0] + tau * x[..., 2]
        py = x[..., 1] + tau * x[..., 3]
        dx, dy = px - b.site_xy_m[:, kc, 0], py - b.site_xy_m[:, kc, 1]
        rr = np.hypot(dx, dy)
        ux, uy = dx / rr, dy / rr
        pred = ux * x[..., 2] + uy * x[..., 3]
        res = np.clip((b.radial_velocity_m_s[:, kc] - pred) / SV, -30, 30)
        ua, uc = ux * ca + uy * sa, -ux * sa + uy * ca
        with np.errstate(invalid="ignore"):
            out[..., 3 * j] = np.where(det, res, 0.0)
            out[..., 3 * j + 1] = np.where(det, ua, 0.0)
            out[..., 3 * j + 2] = np.where(det, uc, 0.0)
    return out


def looks(eps):
    b = stack_episodes(eps)
    run = base.run(eps)
    F, ca, sa = window_features(b.t_s, b.z_m, b.R_m2, b.detected, run.x, run.P, K, SCALE, FITS, run.q_m_s2, 0)
    Fr = rdot_features(b, run, ca, sa)
    dx, dy = b.truth[..., 0] - run.x[..., 0], b.truth[..., 1] - run.x[..., 1]
    Y = np.stack([dx * ca + dy * sa, -dx * sa + dy * ca], -1) / SCALE
    used = (region_masks(b, run.start_index)["used"] & np.isfinite(F).all(-1) & np.isfinite(Y).all(-1)
            & np.isfinite(Fr).all(-1))
    return dict(F=F[used], Fr=Fr[used], Y=Y[used], ca=ca[used], sa=sa[used], b=b, run=run, used=used)


t0 = time.time()
train = {}
for suite in ("random", "random_radars"):
    parts = [looks(draw_suite(suite, min(500, N_EP - c), seed=SEED + c)) for c in range(0, N_EP, 500)]
    train[suite] = {k: np.concatenate([p[k] for p in parts]) for k in ("F", "Fr", "Y")}
    print(suite, "training looks", len(train[suite]["Y"]), f"({time.time() - t0:.0f} s)", flush=True)
val_eps = {s: draw_suite(s, 100, seed=SELECTION_SEED_BASE) for s in ("random", "random_radars")}
val = {s: looks(e) for s, e in val_eps.items()}
ref = {}
for s, v in val.items():
    e = (v["Y"] ** 2).sum(-1) * SCALE ** 2
    ref[s] = {"base": math.sqrt(e.mean())}
    for t in ("imm_ct_bank_rdot", "rbpf_rdot"):
        ref[s][t] = pooled_rmse(v["b"], run_tracker(t, val_eps[s]))
    print(s, "validation", ref[s], f"({time.time() - t0:.0f} s)", flush=True)


def fit(with_rdot):
    inputs = (lambda v: np.concatenate([v["F"], v["Fr"]], 1)) if with_rdot else (lambda v: v["F"])
    return fit_regression([(inputs(train[s]), train[s]["Y"]) for s in train],
                          {s: (inputs(v), v["Y"]) for s, v in val.items()}, EPOCHS, SEED, SCALE,
                          "rdot" if with_rdot else "ctrl", t0)


res = {"base": BASE, "episodes": N_EP, "epochs": EPOCHS, "seed": SEED, "ref": ref,
       "control": fit(False), "treatment": fit(True)}
for arm in ("control", "treatment"):
    last = res[arm][-1]
    print(arm, {s: (round(last[s], 1), round(last[s] / ref[s]["rbpf_rdot"], 3),
                    round(last[s] / ref[s]["imm_ct_bank_rdot"], 3)) for s in val})
if len(sys.argv) > 5:
    json.dump(res, open(sys.argv[5], "w"), indent=1)
