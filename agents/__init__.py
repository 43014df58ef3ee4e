"""Training and evaluation of learned q-policies."""
