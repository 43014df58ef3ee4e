"""radar-track-gym: simulation, shared filter math and the RadarTrack-v0 Gymnasium environment.

The sub-packages follow the chain, each importing only the ones before it: ``common`` (units, validation, numba
cache) -> ``sim`` (flights, radar, episodes, packed looks) -> ``filters`` (compiled chain: Kalman, IMM, feature
bank, preview; torch forward) -> ``envs`` (Gymnasium layer); ``applications`` and ``render`` sit beside them.

Importing the package registers ``RadarTrack-v0`` and its variants (:data:`ENV_VARIANTS`; idempotent); ``gym.make("radar_env:RadarTrack-v0")`` works
without importing it first. Only the Gymnasium layer (``radar_env.envs.env``, ``single_env``, ``vector_env``) needs
gymnasium: without it the package still imports, registers nothing, and the simulation, filter, tracking and
feature modules (and the env's configuration and batched core) work. The old flat module paths
(``radar_env.episode``, ...) still import for one release, with a DeprecationWarning (``radar_env._moved``).
"""

__version__ = "0.1.0"

import copy as _copy


def _register():
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:   # no Gymnasium: nothing to register with; the modules below the env layer need none
        return
    for env_id, kwargs in ENV_VARIANTS.items():
        if env_id not in registry:
            register(id=env_id, entry_point="radar_env.envs.env:RadarTrackEnv",
                     vector_entry_point="radar_env.envs.env:RadarTrackVectorEnv", kwargs=_copy.deepcopy(kwargs))


from .envs.variants import ENV_VARIANTS  # noqa: E402 - the ids and their arguments (radar_env/envs/variants.py)

_register()

from ._moved import MOVED as _MOVED, install as _install  # noqa: E402

_install(_MOVED)
