"""The ``radar-track`` command: ``radar-track evaluate ...`` (the main job), ``train``, ``tune`` and ``sweep``.

Nothing slow is imported before a command's options are parsed: ``--help`` and option errors answer at once, and
``evaluate``, ``train`` and ``tune`` say what they do (one line on stderr) before they import the trackers, numba's
kernels, torch or Ray."""

from __future__ import annotations

import contextlib
import sys

USAGE = """usage: radar-track <command> [options]

commands:
  evaluate   compare learned policies and classical trackers on identical measurement streams
  tune       re-tune the classical baselines (constant-q KF, 2-mode IMM, CV/CT IMM) on training seeds
  train      train a q-choosing policy on RadarTrack-v0 (random scenarios, training seeds): PPO, DQN, SAC
             (--method ppo --algo ...), or a GRU end to end through the filter (--method backprop)
  sweep      seed and hyperparameter sweeps of 'train' on Ray Tune, local or on a cluster (needs '.[scale]')

'radar-track <command> --help' shows the options of a command."""


@contextlib.contextmanager
def _interrupt_in_one_line(cmd):
    """Ctrl-C in ``evaluate`` or ``tune``: one line instead of a traceback (exit status 1, as every one-line
    error). Nothing is left half-written: each output file is written beside its target and renamed onto it
    whole, and the tuned values and the evaluation's JSON are written only at the end (``train`` and ``sweep``
    handle Ctrl-C themselves: they checkpoint and print the resume command)."""
    try:
        yield
    except KeyboardInterrupt:
        raise SystemExit(f"radar-track {cmd}: interrupted (Ctrl-C); every file it wrote before is complete, "
                         "nothing else was written") from None


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "evaluate":
        from agents.evaluation.options import build_parser, check_numbers, first_line
        args = build_parser().parse_args(rest)          # --help and option errors: here, before the trackers load
        check_numbers(args)
        if not args.quiet:
            print(first_line(args), file=sys.stderr, flush=True)
        with _interrupt_in_one_line(cmd):
            from agents.evaluation.evaluate import main as evaluate_main
            evaluate_main(rest)
        return 0
    if cmd == "tune":
        from baselines.tuning_options import build_parser, check_options, first_line
        args = build_parser().parse_args(rest)
        check_options(args)
        print(first_line(args), file=sys.stderr, flush=True)
        with _interrupt_in_one_line(cmd):
            from baselines.tuning import main as tune_main
            tune_main(rest)
        return 0
    if cmd == "train":       # agents.training.train imports torch and the env only when it trains
        from agents.training.train import main as train_main
        train_main(rest)
        return 0
    if cmd == "sweep":       # as train: Ray only when the sweep runs
        from agents.training.sweep import main as sweep_main
        sweep_main(rest)
        return 0
    print(f"radar-track: unknown command {cmd!r}\n\n{USAGE}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
