"""The window correction's analysis scripts run end to end on a few training-range flights (their tables are in
agents/bundled/window/CHOICE.md and docs/training.md; these only guard against the APIs they use drifting)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(*args):
    p = subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout


def test_window_seed_intervals_prints_each_pair_with_an_interval():
    out = _run("scripts/window_seed_intervals.py", "--runs", "4")
    rows = re.findall(r"window_s(\d+) / window_s(\d+): ([0-9.]+) \[([0-9.]+), ([0-9.]+)\]", out)
    assert len(rows) == 6                                       # three seeds: three pairs, at 2 and at 4 flights
    for _, _, r, lo, hi in rows:
        assert float(lo) <= float(r) <= float(hi)


@pytest.mark.parametrize("bad, message", [(["--runs", "3"], "--runs must be an even number"),
                                          (["--folders", "agents/bundled/window"], "at least two")])
def test_window_seed_intervals_refuses_in_one_line(bad, message):
    p = subprocess.run([sys.executable, "scripts/window_seed_intervals.py", *bad], cwd=REPO, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode != 0 and message in p.stderr and len(p.stderr.strip().splitlines()) == 1


def test_window_gap_by_region_prints_the_regions_and_their_shares():
    out = _run("scripts/window_gap_by_region.py", "--runs", "3")
    for suite in ("random", "random_radars"):
        assert f"{suite}, 3 runs from seed 960000" in out
    shares = [float(m) for m in re.findall(r"^\| used \|.* \| ([-0-9.]+) \|$", out, re.M)]
    assert shares == [1.0, 1.0]                                 # the whole gap is the sum of its regions' shares
    assert "scan period" in out


def test_window_fresh_check_prints_s4_and_the_broad_score_against_the_reference():
    out = _run("scripts/window_fresh_check.py", "agents/bundled/window", "agents/bundled/window/seeds/window_s200000",
               "--runs", "3")
    rows = re.findall(r"^\| (\S+) \| ([0-9.]+) \| ([0-9.]+) \[([0-9.]+), ([0-9.]+)\] \| ([0-9.]+) \| ([0-9.]+) \| "
                      r"([0-9.]+) \[([0-9.]+), ([0-9.]+)\] \|$", out, re.M)
    assert [r[0] for r in rows] == ["window", "window_s200000"]
    assert rows[0][2] == rows[0][7] == "1.0000"                 # the reference against itself
    for r in rows:
        assert float(r[3]) <= float(r[2]) <= float(r[4]) and float(r[8]) <= float(r[7]) <= float(r[9])


def test_window_fresh_check_refuses_in_one_line():
    p = subprocess.run([sys.executable, "scripts/window_fresh_check.py", "agents/bundled/window"], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "a reference and at least one candidate" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
