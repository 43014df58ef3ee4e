"""Speed of RadarTrack-v0's opt-in variants beside CartPole-v1 and the default env, measured in one run with
:mod:`benchmarks.bench_env`'s loops (random actions drawn beforehand, resets included; vector envs: row-steps/s,
autoresets included). The variants: ``tracker="imm_cv_ct"`` (the IMM's parameters as the action) and the default
env with the detector features (``features=DEFAULT_FEATURES + DETECTOR_FEATURES``: two IMMs beside the chain).

Run by hand from the repository root: ``python benchmarks/bench_env_imm.py [--seconds 3] [--num-envs 1 64 256]
[--variants imm_cv_ct detectors]``. Prints steps/s and the ratio to CartPole of the same kind (single to single,
vector to CartPole's vector env at the same N) and to the default env, and the load average at the start and the
end (the machine is shared: compare runs made under the same load).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_env as B  # noqa: E402
from radar_env.envs.observation import DEFAULT_FEATURES, DETECTOR_FEATURES  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--num-envs", type=int, nargs="+", default=[1, 64, 256])
    ap.add_argument("--action-type", default="continuous", choices=["continuous", "discrete"])
    ap.add_argument("--variants", nargs="+", default=["imm_cv_ct", "detectors"], choices=["imm_cv_ct", "detectors"])
    args = ap.parse_args(argv)
    variants = {"imm_cv_ct": dict(tracker="imm_cv_ct", action_type=args.action_type),
                "detectors": dict(features=DEFAULT_FEATURES + DETECTOR_FEATURES, action_type=args.action_type)}
    variants = {k: variants[k] for k in args.variants}
    print(f"load average at start: {os.getloadavg()}")
    cp = B.bench_single("CartPole-v1", args.seconds)
    cv = B.bench_single("RadarTrack-v0", args.seconds, action_type=args.action_type)
    line = (f"single env steps/s: CartPole {cp.steps_per_s:,.0f}; RadarTrack cv {cv.steps_per_s:,.0f} "
            f"({cv.steps_per_s / cp.steps_per_s:.3f}x CartPole)")
    for name, kw in variants.items():
        r = B.bench_single("RadarTrack-v0", args.seconds, **kw)
        line += (f"; {name} {r.steps_per_s:,.0f} ({r.steps_per_s / cp.steps_per_s:.3f}x CartPole, "
                 f"{r.steps_per_s / cv.steps_per_s:.2f}x cv)")
    print(line)
    for n in args.num_envs:
        cpv = B.bench_cartpole_vector(n, args.seconds)
        cvv = B.bench_vector(n, args.seconds, action_type=args.action_type)
        line = (f"vector env N={n} row-steps/s: CartPole {cpv.steps_per_s:,.0f}; RadarTrack cv "
                f"{cvv.steps_per_s:,.0f} ({cvv.steps_per_s / cpv.steps_per_s:.3f}x)")
        for name, kw in variants.items():
            r = B.bench_vector(n, args.seconds, **kw)
            line += (f"; {name} {r.steps_per_s:,.0f} ({r.steps_per_s / cpv.steps_per_s:.3f}x CartPole, "
                     f"{r.steps_per_s / cvv.steps_per_s:.2f}x cv)")
        print(line)
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
