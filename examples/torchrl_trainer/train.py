"""TorchRL's PPO trainer with an SDE policy: ``python examples/torchrl_trainer/train.py``.

Composes ``config.yaml`` beside this file (TorchRL's PPO trainer config with the policy changed to
``sde``) after registering the ``sde`` option in TorchRL's config store, builds TorchRL's
``PPOTrainer`` from it and trains. Hydra overrides work as usual, e.g.
``collector.total_frames=20000 trainer.total_frames=20000 models.policy_model.init_param=-1``.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from sde_torchrl.config.torchrl_trainer import register_torchrl_configs

register_torchrl_configs()


@hydra.main(config_path=".", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    trainer = hydra.utils.instantiate(cfg.trainer)
    try:
        trainer.train()
    finally:
        trainer.collector.shutdown()


if __name__ == "__main__":
    main()
