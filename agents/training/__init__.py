"""Training learned policies: ``radar-track train`` (:mod:`.train`: stable-baselines3 on the native vector env
through :mod:`.sb3_vec`, selection callbacks in :mod:`.callbacks`) and ``radar-track sweep`` (:mod:`.sweep`, Ray
Tune). Hyperparameter files in ``hyperparams/``, sweep configs in ``sweeps/``."""
