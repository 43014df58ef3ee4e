"""Classical trackers from the papers, as reference policies and comparison trackers."""

from radar_env._moved import install as _install

_install({"baselines.imm_cv_ct": "baselines.imm_cv_ct_runner"})   # old name of the IMM CV/CT runner, warned
