"""The README headline's derived numbers (agents.reports.report)."""

import math

from agents.reports.report import headline, headroom_share


def _res(**rmse):
    return {"runs": 30, "trackers": {t: {"pos_rmse_m": v, "track_loss_rate": 0.0} for t, v in rmse.items()}}


def test_headroom_share_is_the_captured_fraction():
    assert math.isclose(headroom_share(_res(policy=90.0, imm2=100.0, hindsight_q=60.0)), 0.25)
    assert math.isclose(headroom_share(_res(policy=110.0, imm2=100.0, hindsight_q=60.0)), -0.25)
    assert headroom_share(_res(policy=90.0, imm2=100.0)) is None                  # no ceiling on this suite
    assert headroom_share(_res(policy=90.0, imm2=100.0, hindsight_q=100.0)) is None   # no headroom
    assert headroom_share(_res(policy=float("nan"), imm2=100.0, hindsight_q=60.0)) is None


def test_headline_lists_only_present_trackers_and_the_share():
    text = headline({"random": _res(policy=90.0, imm2=100.0, hindsight_q=60.0)}, has_policy=True)
    head = text.splitlines()[0]
    assert "imm_cv_ct" not in head and "hindsight_q" in head and "headroom" in head
    assert text.splitlines()[2].rstrip().endswith("| 25% |")
