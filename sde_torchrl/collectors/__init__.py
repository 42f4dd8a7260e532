"""Collecting whole episodes (the fast paths and ``env.rollout``) and the paper's episode queue."""
