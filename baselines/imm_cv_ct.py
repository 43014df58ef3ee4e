"""Old name of :mod:`baselines.imm_cv_ct_runner` (the IMM CV/CT episode runner; the model is
:mod:`radar_env.filters.imm_cv_ct`), kept for one release: the same module object, one DeprecationWarning. A file,
not an entry of radar_env's alias finder: registering one from ``baselines/__init__.py`` would import radar_env
(and gymnasium) with every ``import baselines``."""

import sys

from radar_env._moved import warn_moved

from baselines import imm_cv_ct_runner as _runner

warn_moved(__name__, _runner.__name__, skip=(__file__,))
sys.modules[__name__] = _runner      # the import returns the runner itself
