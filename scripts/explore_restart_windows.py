"""Whether a bank of restart windows helps in the minute after a maneuver (issue 38; docs/training.md, "Closing the
gap to rbpf"). An experiment, not a tracker: numpy with Python loops (about 30 s on 100 episodes).

    python scripts/explore_restart_windows.py [runs] [--rbpf]      # runs first; --rbpf adds the particle filter

On ``random`` episodes of TRAINING-range seeds (900_000 + i; never the held-out seeds), from the common track start,
on the same converted plots and R as every tracker: at every look, constant-velocity least-squares line fits over
the last j detected plots (j = 2..12, each plot weighted by its R), i.e. filters restarted j looks ago, which could
undo a maneuver's lag after the fact as a single filter cannot. It prints the pooled position RMSE / imm_cv_ct's and
by region (maneuver / after / straight) of imm_cv_ct, policy_bp, single windows, a hindsight choice per look among
policy_bp and the windows (an optimistic bound: it picks among noisy candidates knowing the truth), and a causal rule
(the longest window whose fit is consistent by a chi-square test at p; policy_bp when the longest is).
"""
import sys
import numpy as np
from scipy.stats import chi2
from agents.evaluation.suites import draw_suite
from agents.evaluation.metrics import region_masks
from baselines.imm_cv_ct_runner import common_start
from baselines.registry import run_tracker
from agents.evaluation.runner import run_one
from agents.policies.learned import load_learned

def main():
    N = int(sys.argv[1]) if len(sys.argv) > 1 else 100
    JMAX = 12
    eps = draw_suite("random", N, seed=900000)
    start = common_start(eps)
    b, k0 = start[0], start[1]
    B, K = b.t_s.shape
    used = region_masks(b, k0 + 1)
    runs = {"imm_cv_ct": run_tracker("imm_cv_ct", eps)}
    lt = load_learned("policy_bp")
    runs["policy_bp"] = run_one("policy_bp", eps, lt.policy, lt.env_config)
    if "--rbpf" in sys.argv:
        runs["rbpf"] = run_tracker("rbpf", eps)


    def rm(err, m):
        return np.sqrt(np.mean(err[m] ** 2))


    def report(name, X):
        e = np.hypot(*(X[..., :2] - b.truth[..., :2]).transpose(2, 0, 1))
        ref = np.hypot(*(runs["imm_cv_ct"].x[..., :2] - b.truth[..., :2]).transpose(2, 0, 1))
        print(f"{name:40s} {rm(e, used['used']) / rm(ref, used['used']):6.3f} " +
              " ".join(f"{rm(e, used[r]):6.1f}" for r in ("maneuver", "after", "straight")), flush=True)
        return e


    # window fits: for each look k, the last j detected plots up to k (j = 2..JMAX)
    Xw = np.full((JMAX + 1, B, K, 4), np.nan)
    C2 = np.full((JMAX + 1, B, K), np.nan)      # residual chi-square
    Ri = np.linalg.inv(np.where(b.detected[..., None, None], b.R_m2, np.eye(2)))
    for bi in range(B):
        det = np.flatnonzero(b.detected[bi, :b.n_looks[bi]])
        for k in range(k0[bi] + 1, b.n_looks[bi]):
            d = det[det <= k][::-1][:JMAX]     # most recent first
            if d.size < 2:
                continue
            tau = b.t_s[bi, d] - b.t_s[bi, k]
            A = np.zeros((4, 4)); y = np.zeros(4)
            z = b.z_m[bi, d]; W = Ri[bi, d]
            for j in range(d.size):
                H = np.hstack([np.eye(2), tau[j] * np.eye(2)])
                A += H.T @ W[j] @ H
                y += H.T @ W[j] @ z[j]
                if j >= 1:
                    try:
                        x = np.linalg.solve(A, y)
                    except np.linalg.LinAlgError:
                        continue
                    Xw[j + 1, bi, k] = x
                    r = z[:j + 1] - (x[None, :2] + tau[:j + 1, None] * x[None, 2:])
                    C2[j + 1, bi, k] = np.einsum("ni,nij,nj->", r, W[:j + 1], r)

    for name in runs:
        report(name, runs[name].x)
    for j in (3, 4, 6, 8, 12):
        report(f"window {j}", Xw[j])
    main = runs["policy_bp"].x
    # oracle: per look best of main and windows 3..JMAX
    cands = [main] + [Xw[j] for j in range(3, JMAX + 1)]
    errs = np.stack([np.hypot(*(c[..., :2] - b.truth[..., :2]).transpose(2, 0, 1)) for c in cands])
    errs = np.where(np.isfinite(errs), errs, np.inf)
    best = np.argmin(errs, 0)
    Xo = np.take_along_axis(np.stack(cands), best[None, ..., None], 0)[0]
    report("oracle best of main + windows", Xo)
    # causal rule: longest consistent window; if the full window is consistent, main
    for p in (0.01, 0.001, 1e-4):
        for jmin in (3, 4, 5):
            X = main.copy()
            L = np.zeros((B, K), int)
            for j in range(jmin, JMAX + 1):
                good = np.isfinite(C2[j]) & (C2[j] <= chi2.ppf(1 - p, 2 * j - 4))
                L = np.where(good, j, L)
            # does main agree? use window when the longest consistent window is < JMAX and > 0
            use = (L > 0) & (L < JMAX)
            for j in range(jmin, JMAX):
                m = use & (L == j)
                X[m] = Xw[j][m]
            report(f"rule p={p} jmin={jmin}", X)


if __name__ == "__main__":
    main()
