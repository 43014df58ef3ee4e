"""radar-track-gym: simulation, shared filter math and the RadarTrack-v0 Gymnasium environment.

Importing the package registers ``RadarTrack-v0`` (idempotent); ``gym.make("radar_env:RadarTrack-v0")`` works
without importing it first. Only the Gymnasium layer (``radar_env.env``, ``single_env``, ``vector_env``) needs
gymnasium: without it the package still imports, registers nothing, and the simulation, filter, tracking and
feature modules (and the env's configuration and batched core) work.
"""

__version__ = "0.1.0"


def _register():
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:   # no Gymnasium: nothing to register with; the modules below the env layer need none
        return
    if "RadarTrack-v0" not in registry:
        register(
            id="RadarTrack-v0",
            entry_point="radar_env.env:RadarTrackEnv",
            vector_entry_point="radar_env.env:RadarTrackVectorEnv",
        )


_register()
