"""radar-track-gym: simulation, shared filter math and the RadarTrack-v0 Gymnasium environment.

Importing the package registers ``RadarTrack-v0`` (idempotent); ``gym.make("radar_env:RadarTrack-v0")`` works
without importing it first.
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"


def _register():
    if "RadarTrack-v0" not in registry:
        register(
            id="RadarTrack-v0",
            entry_point="radar_env.env:RadarTrackEnv",
            vector_entry_point="radar_env.env:RadarTrackVectorEnv",
        )


_register()
