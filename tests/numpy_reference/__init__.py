"""The numpy chain of main before the compiled kernels (commit 0345032: filters.py, features.py, tracking.py,
verbatim apart from these imports), kept as the independent reference that tests/test_kernels.py compares the
kernels, the Tracker's features and the bundled policy's choices against. Not imported by the library."""
