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

from sde_torchrl.build import register_resolvers, run_job

log = logging.getLogger("train")
register_resolvers()


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    """Builds the job from ``cfg``, trains it and labels the summary with the chosen groups."""
    hydra_cfg = HydraConfig.get()
    summary = run_job(cfg, hydra_cfg.runtime.output_dir, dict(hydra_cfg.runtime.choices))
    log.info("final return per run: %s", [round(r, 3) for r in summary["final_return"]])


if __name__ == "__main__":
    main()
