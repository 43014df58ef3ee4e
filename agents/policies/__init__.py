"""Learned policies as things that act: the bundled policy and the env it was trained in (:mod:`.bundle`), and
loading a saved policy as a ``choose_q(obs) -> q`` function for the evaluation (:mod:`.loading`)."""
