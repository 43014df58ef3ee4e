"""Learned policies for RadarTrack-v0 and the jobs around them, one sub-package per job:

* :mod:`agents.policies`: what acts (the bundled policy, loading a saved one);
* :mod:`agents.training`: ``radar-track train`` and ``radar-track sweep``;
* :mod:`agents.evaluation`: the main job, ``radar-track evaluate``;
* :mod:`agents.reports`: the generated documentation (results, generalisation, paper checks).

Layers look down only: policies < evaluation < training < reports < cli (tests/test_layering.py)."""
