"""Train policies with state-dependent exploration: ``python train.py +experiment=minimize``.

Hydra composes ``conf/config.yaml`` with the groups ``env``, ``actor``, ``explorer``,
``estimator``, ``logger`` and an optional ``+experiment``; each job writes ``metrics.csv``,
``summary.json`` and ``checkpoint.pt`` into its run directory.
"""

from __future__ import annotations

import logging

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from sde_torchrl.build import build_trainer, register_resolvers
from sde_torchrl.trainer import write_json_atomic

log = logging.getLogger("train")
register_resolvers()


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    """Builds the job from ``cfg``, trains it and labels the summary with the chosen groups."""
    hydra_cfg = HydraConfig.get()
    out_dir = hydra_cfg.runtime.output_dir
    trainer = build_trainer(cfg, out_dir)
    summary = trainer.train(out_dir)
    choices = hydra_cfg.runtime.choices
    labels = {group: choices.get(group) for group in ("env", "actor", "explorer", "estimator")}
    write_json_atomic(f"{out_dir}/summary.json", {**labels, "seed": cfg.seed, **summary})
    log.info("final return per run: %s", [round(r, 3) for r in summary["final_return"]])


if __name__ == "__main__":
    main()
