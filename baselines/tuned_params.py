"""Where the tuned baseline parameters live: ``baselines/tuned.json``, written by ``python -m baselines.tuning``."""

from __future__ import annotations

import json
from pathlib import Path

TUNED_PATH = Path(__file__).with_name("tuned.json")


def tuned_parameters():
    """The tuned parameters (dict) from ``baselines/tuned.json``; ``ValueError`` if the file is missing."""
    if not TUNED_PATH.is_file():
        raise ValueError(f"{TUNED_PATH} is missing; run `python -m baselines.tuning` to create it")
    return json.loads(TUNED_PATH.read_text())
