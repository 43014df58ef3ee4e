"""Fit the covariance scale of a window-correction ensemble folder on fresh training flights.

    python scripts/calibrate_window_covariance.py FOLDER --seed S [--episodes JSON] [--first-leg-min-s 0] [--write]

An ensemble (``policy.json`` version 2) reports the mean of its members' covariance heads plus the spread of their
moves; each head was fitted by Gaussian likelihood to its own run's looks, and their mean is more cautious than each
(the bundled ``policy_window``: ANEES about 0.8 on its training mix against 0.98-1.01 for each head). The scale
``c = mean NEES / 4`` over every look the correction moves on the given training flights is the maximum-likelihood
factor of that fixed covariance (:func:`agents.training.window.covariance_scale_fit`); ``c`` times it has ANEES 1
there. The estimates do not change (the covariance has no feedback). Choose ``--seed`` so that no training run, rule
or check used the flights (the script refuses only the held-out evaluation's seeds, 10,000,000 and above; the
selection suites draw 900,000 + i and 920,000 + i, the broad suites' flights come from ``--seed`` + 300,000); the
default mix is the bundled ensemble's fine-tuning mix (2,000 / 2,000 / 500 / 500 flights) at 0.4 of its size: for an
ensemble of runs trained on another mix (e.g. ``window.toml``'s defaults, no broad flights) pass ``--episodes`` with
that mix's suites (the scale is fitted where the networks were trained). ``--write`` sets ``policy.json``'s
``covariance_scale`` and writes ``calibration.json`` beside it (the seed, the flights, each suite's ANEES before,
the command; the new ``policy.json`` is loaded from a copy first, so a refusal leaves the folder as it was); without
it the fit is printed only. Rebuilding the folder with ``scripts/make_window_ensemble.py`` drops the scale (and the
stale ``calibration.json``): fit it again. A version-1 correction has no scale field: make it an ensemble of one
(``scripts/make_window_ensemble.py``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from agents.evaluation.suites import EVAL_SEED_BASE  # noqa: E402
from agents.training.window import (BROAD_SCENARIOS, BROAD_SEED_OFFSET, WINDOW_SCENARIOS,  # noqa: E402
                                    covariance_scale_fit)

DEFAULT_EPISODES = {"random": 800, "random_radars": 800, "random_broad": 200, "random_radars_broad": 200}
MAX_EPISODES = 20_000


def check_episodes(text):
    """``--episodes``' JSON object ``{suite: flights}``, checked (suites of the window trainer's generators)."""
    try:
        ep = json.loads(text)
    except json.JSONDecodeError as e:
        raise SystemExit(f"error: --episodes must be a JSON object {{suite: flights}}: {e}") from None
    if not isinstance(ep, dict) or not ep:
        raise SystemExit(f"error: --episodes must be a non-empty JSON object {{suite: flights}}, got {text!r}")
    for name, n in ep.items():
        if name not in WINDOW_SCENARIOS:
            raise SystemExit(f"error: --episodes: suite {name!r} is not one of {list(WINDOW_SCENARIOS)}")
        if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_EPISODES:
            raise SystemExit(f"error: --episodes: {name}'s flights must be an integer in [1, {MAX_EPISODES}], "
                             f"got {n!r}")
    return ep


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", help="a window-correction ensemble folder (policy.json version 2, covariance heads)")
    ap.add_argument("--seed", type=int, required=True,
                    help="first seed of the flights (training range; broad suites at seed + 300,000)")
    ap.add_argument("--episodes", default=json.dumps(DEFAULT_EPISODES),
                    help="JSON {suite: flights}: the members' own training mix (default, the bundled ensemble's: "
                         "%(default)s)")
    ap.add_argument("--first-leg-min-s", type=float, default=0.0,
                    help="the random suites' shortest first leg (s; default 0, the window recipe's)")
    ap.add_argument("--write", action="store_true", help="write covariance_scale and calibration.json")
    args = ap.parse_args(argv)
    episodes = check_episodes(args.episodes)
    last = max(args.seed + (BROAD_SEED_OFFSET if name in BROAD_SCENARIOS else 0) + n - 1
               for name, n in episodes.items())
    if args.seed < 0 or last >= EVAL_SEED_BASE:
        raise SystemExit(f"error: --seed: the flights' seeds {args.seed}..{last} must lie in [0, {EVAL_SEED_BASE:,}) "
                         "(the held-out evaluation's seeds start there)")
    if not 0.0 <= args.first_leg_min_s <= 600.0:
        raise SystemExit(f"error: --first-leg-min-s must be in [0, 600] s, got {args.first_leg_min_s}")
    folder = Path(args.folder)
    meta_file = folder / "policy.json"
    from agents.policies.learned import install_checked, load_learned, staging_beside
    from agents.policies.window_correction import ENSEMBLE_VERSION, FORMAT, ensemble_fields
    from agents.policies.checks import read_json_object
    try:
        meta = read_json_object(meta_file, "a window-correction ensemble's config (a JSON object)")
        if meta.get("format") != FORMAT or meta.get("version") != ENSEMBLE_VERSION:
            raise ValueError(f"{meta_file}: not a window-correction ensemble (format {FORMAT!r}, version "
                             f"{ENSEMBLE_VERSION}); a single correction becomes one with "
                             "scripts/make_window_ensemble.py")
        correction = load_learned(str(folder)).policy
    except (OSError, ValueError) as e:
        raise SystemExit(f"error: {e}"[:500]) from None
    hp = {"scenarios": list(episodes), "episodes": episodes, "first_leg_min_s": args.first_leg_min_s}
    try:
        fit = covariance_scale_fit(correction, hp, args.seed)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    for name, s in fit["suites"].items():
        print(f"{name:22s} {s['flights']:6d} flights {s['looks']:9,d} looks  ANEES (scale 1) {s['anees']:.4f}")
    print(f"covariance_scale {fit['covariance_scale']:.6f} over {fit['looks']:,} looks "
          f"({fit['invalid_looks']} without a positive-definite covariance)")
    if not args.write:
        return fit
    meta["covariance_scale"] = fit["covariance_scale"]
    try:
        ensemble_fields(meta)           # in range, before anything is written
    except ValueError as e:
        raise SystemExit(f"error: {meta_file}: {e}; nothing written") from None
    npz = folder / "policy.npz"
    record = {"covariance_scale": fit["covariance_scale"], "seed": args.seed, "episodes": episodes,
              "first_leg_min_s": args.first_leg_min_s, "broad_seed_offset": BROAD_SEED_OFFSET,
              "looks": fit["looks"], "invalid_looks": fit["invalid_looks"], "suites": fit["suites"],
              "policy_npz_sha256": hashlib.sha256(npz.read_bytes()).hexdigest(),
              "command": " ".join(["scripts/calibrate_window_covariance.py",
                                   *(argv if argv is not None else sys.argv[1:])])}
    texts = {"calibration.json": json.dumps(record, indent=1, allow_nan=False) + "\n",
             "policy.json": json.dumps(meta, indent=1, allow_nan=False)}
    # the new policy.json loaded from a copy beside the folder before anything in the folder changes; then each file
    # replaced whole, the record first
    with staging_beside(folder) as tmp:
        for f in ("policy.npz", "env_config.json"):
            shutil.copyfile(folder / f, Path(tmp) / f)
        for name, text in texts.items():
            (Path(tmp) / name).write_text(text)
        try:
            install_checked(tmp, folder, tuple(texts))
        except ValueError as e:
            raise SystemExit(f"error: {e}; nothing written"[:500]) from None
    print(f"wrote {meta_file} (covariance_scale) and {folder / 'calibration.json'}")
    return fit


if __name__ == "__main__":
    main()
