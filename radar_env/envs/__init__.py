"""The Gymnasium layer: config, the batched core and its step kernel, observation, IMM env, single and vector envs.
May import common, sim, filters and render; only env, single_env and vector_env import gymnasium."""
