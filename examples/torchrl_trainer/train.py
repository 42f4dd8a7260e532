"""TorchRL's PPO trainer with an SDE policy: ``python examples/torchrl_trainer/train.py``.

Composes ``config.yaml`` beside this file (TorchRL's PPO trainer config with the policy changed to
``sde``) after registering the ``sde`` option in TorchRL's config store, builds TorchRL's
``PPOTrainer`` from it and trains. Hydra overrides work as usual, e.g.
``collector.total_frames=20000 trainer.total_frames=20000 models.policy_model.init_param=-1``.

The SDE policy's settings are checked before anything is built: a refused one (a non-finite
``init_param``, bound, ...) is reported in one line, ``error: <key>=<value>: <what is allowed>``,
with exit code 2, as ``train.py`` reports a config error.
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from sde_torchrl.config.torchrl_trainer import check_sde_models, register_torchrl_configs
from sde_torchrl.utils.checks import ArgumentError

#: The exit code of a refused setting (``train.py``'s for a config error).
EXIT_CONFIG = 2

register_torchrl_configs()


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        check_sde_models(cfg)
    except ArgumentError as error:
        sys.stderr.write(f"error: {error}\n")
        raise SystemExit(EXIT_CONFIG) from None
    trainer = hydra.utils.instantiate(cfg.trainer)
    try:
        trainer.train()
    finally:
        trainer.collector.shutdown()


if __name__ == "__main__":
    main()
