"""Learned policies as things that act: one loader for every learned tracker folder, by the kind its ``policy.json``
names (:mod:`.learned`: :func:`~agents.policies.learned.load_learned`, the bundled names), and behind it the per-kind
loaders: a saved SB3 model or recurrent policy as a ``choose_q(obs) -> q`` function (:mod:`.loading`,
:mod:`.recurrent`, :mod:`.numpy_policy`), a learned IMM (:mod:`.learned_imm`), and the env a policy was trained in
(:mod:`.bundle`)."""
