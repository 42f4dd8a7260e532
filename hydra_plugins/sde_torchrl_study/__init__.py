"""The study's config tree (``analysis/conf/``) on Hydra's search path, in a clone of the repository.

Hydra finds this package by scanning the ``hydra_plugins`` namespace: it is seen when the clone's
root is on ``sys.path`` (``python train.py``, ``python -m analysis...`` or pytest from the root), never
from an installed wheel, which ships only the library's tree (``sde_torchrl/conf/``).
"""
