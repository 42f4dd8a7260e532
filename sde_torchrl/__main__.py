"""``python -m sde_torchrl +experiment=minimize``: the training command (:func:`sde_torchrl.cli.cli`),
the same as ``sde-train`` and a clone's ``train.py``."""

import sys

from sde_torchrl.cli import cli

if __name__ == "__main__":
    sys.exit(cli())
