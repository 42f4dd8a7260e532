"""Schemas declare themselves: a new estimator's or env's schema is found by its name alone
(no table lists it), and what the layers below the config need of an env is declared or refused."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from _helpers import build, compose_config
from hydra.core.config_store import ConfigStore

from sde_torchrl.config.schemas.envs import EnvConf, MinimizeEnvConf
from sde_torchrl.config.schemas.estimators import EstimatorConf
from sde_torchrl.config.schemas.frozen import SCHEMAS
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.resources import estimate_memory


@pytest.fixture
def declared():
    """Names this test declares, taken out of the schemas and Hydra's store afterwards."""
    names: list[str] = []
    yield names
    stored = ConfigStore.instance().repo.get("schema", {})
    for name in names:
        SCHEMAS.pop(name, None)
        group, option = name.split("/")
        stored.get(group, {}).pop(f"{option}.yaml", None)


def _option_yaml(folder, group: str, option: str) -> str:
    """Writes ``<group>/<option>.yaml`` into ``folder`` as the option's YAML file holds it (its
    schema, first in its defaults list); returns the override that adds ``folder`` to Hydra's
    search path."""
    (folder / group).mkdir(exist_ok=True)
    (folder / group / f"{option}.yaml").write_text(f"defaults:\n  - /schema/{group}/{option}@_here_\n  - _self_\n")
    return f"hydra.searchpath=[file://{folder}]"


def test_a_new_estimator_schema_composes_and_trains_without_a_table(declared, tmp_path):
    @dataclass
    class HalvedConf(EstimatorConf, schema="estimator/declared_halved"):
        baseline_from_batch = True
        _target_: str = "sde_torchrl.objectives.estimators.ReinforceEstimator"

    declared.append("estimator/declared_halved")
    search = _option_yaml(tmp_path, "estimator", "declared_halved")
    conf = validate(compose_config(search, "+experiment=minimize", "estimator=declared_halved",
                                   "estimator.max_grad_norm=5"))
    assert type(conf.estimator) is HalvedConf and conf.estimator.option == "declared_halved"
    with pytest.raises(Exception, match="at least 2 with estimator=declared_halved"):  # its trait is read
        validate(compose_config(search, "+experiment=minimize", "estimator=declared_halved", "episodes_per_update=1"))
    trainer = build(search, "estimator=declared_halved", "updates=2", "runs=2")
    assert type(trainer.estimator).__name__ == "ReinforceEstimator"


def test_a_new_env_schema_composes_builds_and_is_estimated_by_its_sizes(declared, tmp_path):
    @dataclass
    class WideConf(MinimizeEnvConf, schema="env/declared_wide"):
        steps_per_second = 5

        def sizes(self) -> tuple[int, int]:
            return self.dim, self.dim

    declared.append("env/declared_wide")
    search = _option_yaml(tmp_path, "env", "declared_wide")
    conf = validate(compose_config(search, "+experiment=minimize", "env=declared_wide", "env.dim=3"))
    assert type(conf.env) is WideConf
    same = validate(compose_config("+experiment=minimize", "env.dim=3"))
    assert estimate_memory(conf) == estimate_memory(same)
    trainer = build(search, "env=declared_wide", "env.dim=3", "updates=1")
    assert trainer.env.action_spec.shape[-1] == 3


def test_an_env_schema_without_sizes_is_refused_when_defined():
    with pytest.raises(TypeError, match=r"NoSizesConf \(schema env/declared_nosizes\) declares no sizes: an env "
                                        r"schema defines sizes\(\)"):
        @dataclass
        class NoSizesConf(EnvConf, schema="env/declared_nosizes"):
            _target_: str = "sde_torchrl.envs.make_minimize_env"
            episode_length: int = 5

    assert "env/declared_nosizes" not in SCHEMAS
