"""Radar-scope rendering: frame shape, RecordVideo, errors."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import RecordVideo

import radar_env  # noqa: F401
from radar_env.render import FRAME_SHAPE


def test_rgb_array_frame_has_declared_shape_and_changes():
    env = gym.make("RadarTrack-v0", render_mode="rgb_array", scenario="seed002_course_changes")
    env.reset(seed=1)
    f0 = env.render()
    for _ in range(5):
        env.step(6)
    f1 = env.render()
    assert f0.shape == f1.shape == FRAME_SHAPE and f1.dtype == np.uint8
    assert np.any(f0 != f1)                     # the scope moves with the track
    assert len(np.unique(f1.reshape(-1, 3), axis=0)) > 10


def test_record_video_writes_a_file(tmp_path):
    pytest.importorskip("moviepy")
    out = tmp_path / "videos"                    # not created yet: RecordVideo warns when overwriting a folder
    env = RecordVideo(gym.make("RadarTrack-v0", render_mode="rgb_array", scenario="kim_lee_accel"), str(out),
                      episode_trigger=lambda e: True, disable_logger=True)
    env.reset(seed=0)
    for _ in range(8):
        env.step(6)
    env.close()
    files = list(out.glob("*.mp4"))
    assert files and files[0].stat().st_size > 1000


@pytest.mark.filterwarnings("ignore:.*not in the possible render_modes")
def test_render_mode_validation():
    with pytest.raises(ValueError, match="render_mode"):
        gym.make("RadarTrack-v0", render_mode="ascii")
    with pytest.raises(ValueError, match="does not render"):
        gym.make_vec("RadarTrack-v0", num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array")
