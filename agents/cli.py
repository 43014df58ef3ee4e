"""The ``radar-track`` command: ``radar-track evaluate ...`` (the main job) and ``radar-track tune``."""

from __future__ import annotations

import sys

USAGE = """usage: radar-track <command> [options]

commands:
  evaluate   compare learned policies and classical trackers on identical measurement streams
  tune       re-tune the classical baselines (constant-q KF, 2-mode IMM, CV/CT IMM) on training seeds
  train      train a q-choosing policy on RadarTrack-v0 (random scenarios, training seeds): PPO, DQN, SAC
             (--method ppo --algo ...), or a GRU end to end through the filter (--method backprop)
  sweep      seed and hyperparameter sweeps of 'train' on Ray Tune, local or on a cluster (needs '.[scale]')

'radar-track <command> --help' shows the options of a command."""


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "evaluate":
        from agents.evaluation.evaluate import main as evaluate_main
        evaluate_main(rest)
        return 0
    if cmd == "tune":
        from baselines.tuning import main as tune_main
        tune_main(rest)
        return 0
    if cmd == "train":
        from agents.training.train import main as train_main
        train_main(rest)
        return 0
    if cmd == "sweep":
        from agents.training.sweep import main as sweep_main
        sweep_main(rest)
        return 0
    print(f"radar-track: unknown command {cmd!r}\n\n{USAGE}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
