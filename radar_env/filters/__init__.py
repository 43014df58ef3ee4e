"""Filters: the compiled chain kernels (Kalman, IMM, feature bank, preview), tracker, IMM CV/CT, particle filter, torch.
May import radar_env.common and .sim; never envs or gymnasium; torch only in torch_chain, torch_imm, compiled_chain."""

from .._moved import forward_attributes

__getattr__ = forward_attributes(__name__, "radar_env.filters.kalman")   # old radar_env/filters.py names, warned
