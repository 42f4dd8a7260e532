"""The study's experiments (``analysis/conf/experiment/``: every ``*_sweep`` and ``minimize_guessed``,
on Hydra's search path in a clone) compose and validate like the library's (``tests/test_config.py``,
``tests/test_job_config.py``), and the Table 1 sweeps train with the closed-form scores."""

from __future__ import annotations

import json

import pytest
from _helpers import REPO, compose_config
from omegaconf import OmegaConf

from sde_torchrl.config.schemas.train import validate

#: The study's experiments (analysis/conf/experiment/).
EXPERIMENTS = sorted(path.stem for path in (REPO / "analysis" / "conf" / "experiment").glob("*.yaml"))


@pytest.mark.parametrize("experiment", ["minimize_guessed", "noise_sweep", "episode_length_sweep"])
def test_experiments_validate(experiment):
    validate(compose_config(f"+experiment={experiment}"))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_the_resolved_config_is_what_hydra_resolves(experiment):
    """As for the library's experiments: ``job_config.json`` and the summary's config, from the
    typed object, are Hydra's resolved config key for key, in the same order."""
    cfg = compose_config(f"+experiment={experiment}", "max_memory_gb=1000")
    resolved = validate(cfg).resolved()
    expected = OmegaConf.to_container(cfg, resolve=True)
    assert json.dumps(resolved) == json.dumps(expected)


@pytest.mark.parametrize("experiment", ["noise_sweep", "episode_length_sweep"])
def test_the_table1_sweeps_use_the_closed_form_scores(experiment, tmp_path):
    from sde_torchrl.config.build import build_trainer

    trainer = build_trainer(compose_config(f"+experiment={experiment}", "runs=2", "logger=none"), str(tmp_path))
    assert trainer.estimator.closed_form
    trainer.close()
