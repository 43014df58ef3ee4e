"""Build a window-correction ensemble folder (kind ``window_correction``, version 2) from window training runs that
share their base: each member is a run's ``best/`` network with its input standardisation unfolded from the first
layer (the run's ``checkpoints/last.npz`` keeps the standardisation the run trained with), so that the network reads
``(F - mean) / sd`` as in training and can run in float32 (agents/policies/window_correction.py).

    python scripts/make_window_ensemble.py OUT RUN [RUN ...] [--precision float32] [--base-precision float32]

Unfolding is exact algebra for any standardisation; the run's own matters for float32, whose first layer then sums
terms of order one instead of thousands that cancel. Every member is checked before anything is written: its
unfolded network on standardised inputs gives the folded network's outputs to 1e-9 (relative, float64) and, in
``--precision``, to 1e-4 of the output's unit (3 cm at ``scale_m`` 300; the eleventh recipe's networks: 2.4e-5) on
4,096 inputs drawn around its training mean; and every run has the first run's configuration (base, window, fits,
q looks, architecture, scales). ``OUT/ensemble.json`` records the members' sources (path and sha256 of each
``policy.npz``); ``covariance.json``, ``training.json`` and the rest stay in the runs (the bundle keeps them under
``seeds/`` and writes its own by hand). The new ``policy.json`` has no ``covariance_scale``: an existing
``OUT/calibration.json`` is removed, and ``scripts/calibrate_window_covariance.py`` fits the scale again.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from agents.policies.learned import install_checked, staging_beside  # noqa: E402
from agents.policies.recurrent import layer_weights  # noqa: E402
from agents.training.window import unfold_standardisation  # noqa: E402
from agents.policies.window_correction import (PRECISIONS, network_forward, network_shapes,  # noqa: E402
                                               save_window_ensemble)

SAME = ("base", "window_looks", "scale_m", "architecture", "fit_looks", "q_looks", "scale_m_s")


def member(run, precision="float64"):
    """``(weights, mean, sd, config, source)`` of a run folder's ``best/`` network, unfolded and checked (in float64
    and in ``precision``). Its folder passes the checked loader first and its checkpoint's standardisation is
    checked: a damaged or foreign file stops in one line."""
    run = Path(run)
    try:
        return _member(run, precision)
    except ValueError as e:
        msg = str(e).splitlines()[0]
        raise SystemExit(f"error: {msg if str(run) in msg else f'{run}: {msg}'}"[:500]) from None


def _member(run, precision):
    from agents.policies import checks
    from agents.policies.layout import CORRECTION_KINDS
    from agents.policies.learned import load_learned
    npz, ckpt = run / "best" / "policy.npz", run / "checkpoints" / "last.npz"
    for f in (npz, ckpt):
        if not f.is_file():
            raise ValueError(f"no {f.relative_to(run)} (a window training run's folder is needed)")
    load_learned(npz.parent, kinds=CORRECTION_KINDS)          # every file and field of best/, its base included
    config = checks.read_json_object(npz.parent / "policy.json")
    if config.get("version") != 1 or isinstance(config.get("version"), bool):
        raise ValueError(f"{npz.parent / 'policy.json'}: version {config.get('version')!r}, need a single "
                         "correction (version 1)")
    weights = checks.read_npz(npz)
    w = {k: weights[k] for k in network_shapes(config["architecture"])}
    last = checks.read_npz(ckpt)
    if "mean" not in last or "sd" not in last:
        raise ValueError(f"{ckpt}: no standardisation (the run trained without standardise_inputs)")
    mean, sd = np.asarray(last["mean"], np.float64), np.asarray(last["sd"], np.float64)
    n_in = int(config["architecture"]["input_size"])
    if mean.shape != (n_in,) or sd.shape != (n_in,):
        raise ValueError(f"{ckpt}: mean and sd must have the network's {n_in} inputs, got shapes {mean.shape} and "
                         f"{sd.shape}")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(sd)) and np.all(sd > 0)):
        raise ValueError(f"{ckpt}: mean and sd must be finite and sd > 0 (a damaged checkpoint)")
    u = unfold_standardisation(w, mean, sd)
    F = mean + sd * np.random.default_rng(0).standard_normal((4096, mean.size))
    n = len(config["architecture"]["layers"])
    cov = bool(config["architecture"].get("covariance"))
    a = network_forward(layer_weights(w), n, F, cov)
    b = network_forward(layer_weights(u), n, F, cov, mean=mean, sd=sd)
    dt = np.dtype(precision).type
    c = network_forward(layer_weights(u, dt), n, F, cov, dt, mean, sd)
    for x, y, z in zip(*((v if cov else (v,)) for v in (a, b, c))):
        err = np.abs(x - y).max() / max(np.abs(x).max(), 1e-300)
        if not err <= 1e-9:
            raise ValueError(f"the unfolded network differs from best/'s by {err:.2e} (relative)")
        err = np.abs(x - z).max()
        if not err <= 1e-4:
            raise ValueError(f"in {precision} the network differs from best/'s by {err:.2e} (output units; at most "
                             "1e-4)")
    return u, mean, sd, config, {"run": str(run), "policy_npz_sha256": hashlib.sha256(npz.read_bytes()).hexdigest()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", help="the ensemble's folder (created)")
    ap.add_argument("runs", nargs="+", help="window training runs' folders (best/ and checkpoints/last.npz)")
    ap.add_argument("--precision", default="float32", choices=PRECISIONS, help="the networks' forward")
    ap.add_argument("--base-precision", default="float32", choices=PRECISIONS,
                    help="a recurrent q-policy base's GRU")
    args = ap.parse_args(argv)
    runs = [Path(r).resolve() for r in args.runs]
    if len(set(runs)) < len(runs):
        raise SystemExit(f"error: a run is given twice: {args.runs}")
    if not args.out.strip() or (Path(args.out).exists() and not Path(args.out).is_dir()):
        raise SystemExit(f"error: OUT: {args.out!r} must name a folder (created if missing), not a file or nothing")
    members = [member(r, args.precision) for r in runs]
    out_dir = Path(args.out).resolve()
    bases = [_base(m[3]["base"], r, out_dir) for m, r in zip(members, runs)]
    first = members[0][3]
    for m, b in zip(members[1:], bases[1:]):
        diff = [k for k in SAME if k != "base" and m[3].get(k) != first.get(k)] + (["base"] if b != bases[0] else [])
        if diff:
            raise SystemExit(f"error: {m[4]['run']}: {diff} differ from {members[0][4]['run']}'s")
    config = {k: first[k] for k in SAME if k in first}
    config.update(base=bases[0], precision=args.precision, base_precision=args.base_precision)
    env = json.loads((runs[0] / "best" / "env_config.json").read_text())      # checked by the loader (member)
    # built beside OUT and loaded before anything in OUT changes, so that a refusal leaves OUT as it was
    with staging_beside(out_dir) as tmp:
        save_window_ensemble(tmp, [m[:3] for m in members], config, env)
        try:
            install_checked(tmp, out_dir, ("policy.npz", "policy.json", "env_config.json"))
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
    stale = out_dir / "calibration.json"        # a covariance scale fitted for the networks OUT held before
    if stale.is_file():
        stale.unlink()
        print(f"removed {stale}: the new policy.json has no covariance_scale; fit it again with "
              "scripts/calibrate_window_covariance.py")
    (out_dir / "ensemble.json").write_text(json.dumps(
        {"members": [m[4] for m in members],
         "command": " ".join(["scripts/make_window_ensemble.py", *(argv if argv is not None else sys.argv[1:])])},
        indent=1))
    print(f"wrote {out_dir / 'policy.npz'} ({len(members)} members, precision {args.precision}, base "
          f"{args.base_precision})")


def _base(base, run, out_dir):
    """A run's ``base`` field as OUT's: a bundled name as it is, a folder (relative to the run's ``best/``, as the
    trainer writes it) relative to OUT."""
    from agents.policies.layout import BUNDLED_LEARNED
    if base in BUNDLED_LEARNED:
        return base
    return os.path.relpath((Path(run) / "best" / base).resolve(), out_dir)

if __name__ == "__main__":
    main()
