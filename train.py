"""Train policies with state-dependent exploration: ``python train.py +experiment=minimize``.

The repository's script for the training command, :func:`sde_torchrl.cli.cli` (installed as
``sde-train``, and ``python -m sde_torchrl``): Hydra composes the package's config tree
(``conf/``) with the overrides given; see :mod:`sde_torchrl.cli.main` for its exit codes.
"""

import sys

from sde_torchrl.cli import cli

if __name__ == "__main__":
    sys.exit(cli())
