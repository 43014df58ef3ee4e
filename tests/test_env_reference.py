"""docs/env_reference.md is what ``python -m radar_env.envs.reference`` renders from the code (so the page and the
env cannot drift), and what the renderer states by hand (argument list, numeric ranges) matches the validation."""

import re
from dataclasses import fields

import pytest

from radar_env.envs.config import EnvConfig
from radar_env.envs.reference import ARGUMENTS, NUMERIC_RANGES, PAGE, main, render

IMM_ONLY = {"imm_action_levels": {"tracker": "imm_cv_ct", "action_type": "discrete"},
            "feature_q_g": {"tracker": "imm_cv_ct"}}


def test_committed_page_equals_the_rendered_one():
    assert PAGE.read_text() == render(), ("docs/env_reference.md differs from the code; regenerate it: "
                                          "python -m radar_env.envs.reference")
    assert main(["--check"]) == 0


def test_check_fails_on_a_stale_page(tmp_path, monkeypatch):
    import radar_env.envs.reference as ref
    stale = tmp_path / "env_reference.md"
    stale.write_text(PAGE.read_text().replace("| 0 | `nu_along` | sigma", "| 0 | `nu_along` | m"))
    monkeypatch.setattr(ref, "PAGE", stale)
    assert main(["--check"]) == 1


def test_every_argument_is_documented():
    assert list(ARGUMENTS) == [f.name for f in fields(EnvConfig)]
    page = PAGE.read_text()
    for name in ARGUMENTS:
        assert f"| `{name}` |" in page


def test_the_observation_table_has_every_feature_and_the_ids_spaces():
    import gymnasium as gym

    import radar_env
    from radar_env.envs.observation import FEATURE_SPECS
    page = PAGE.read_text()
    rows = re.findall(r"^\| (\d+) \| `(\w+)` \| ([^|]+) \|", page, flags=re.M)
    feats = [(int(i), n, u.strip()) for i, n, u in rows if n in FEATURE_SPECS]
    assert feats == [(i, n, s.unit) for i, (n, s) in enumerate(FEATURE_SPECS.items())]
    for env_id in radar_env.ENV_VARIANTS:
        env = gym.make(env_id, disable_env_checker=True)
        assert f"| `{env_id}` | `{env.action_space}` | `Box(({env.observation_space.shape[0]},))` |" in page


@pytest.mark.parametrize("name", sorted(NUMERIC_RANGES))
def test_stated_numeric_ranges_are_the_validated_ones(name):
    lo, hi, integer = NUMERIC_RANGES[name]
    extra = IMM_ONLY.get(name, {})
    for v in (lo, hi):                                      # the ends are accepted
        EnvConfig.from_kwargs(**extra, **{name: int(v) if integer else v})
    below = lo - 2 if integer else (lo - max(abs(lo) * 1e-3, 1e-12))
    above = hi + 2 if integer else hi * (1 + 1e-3)
    for v in (below, above):                                # just outside is refused, naming the argument and range
        with pytest.raises(ValueError) as e:
            EnvConfig.from_kwargs(**extra, **{name: v})
        msg = str(e.value)
        assert name in msg and "\n" not in msg
        assert f"[{lo}, {hi}]" in msg, msg            # check_number prints the interval's ends with str()
