"""Shared utilities below every layer: units, argument validation, the kernels' array type, the numba cache check.
Imports only the standard library and numpy; nothing from radar_env's other sub-packages."""
