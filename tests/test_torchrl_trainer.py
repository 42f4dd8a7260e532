"""SDE in TorchRL's own trainers: ``model@models.policy_model: sde`` in TorchRL's PPO trainer config.

- TorchRL's ``PPOTrainer``, built by Hydra from ``examples/torchrl_trainer/config.yaml`` (TorchRL's
  PPO trainer config with the policy line changed), trains the SDE policy: its noise is held for an
  episode and redrawn at the next, and training moves the policy's parameters.
- That config differs from TorchRL's in the two lines it marks, and with ``tanh_normal`` back it
  builds TorchRL's own policy.
- Both config stores live in one process: this repository's ``conf/`` composes and builds a job
  while TorchRL's trainer configs are registered, and TorchRL's config composes after it.
- ``make_sde_model`` refuses what it cannot honour, naming the fix; the example refuses a
  non-finite setting of the SDE policy before anything is built, in one line naming its key.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from _helpers import REPO, own_stderr_lines
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from tensordict import TensorDict
from tensordict.nn import ProbabilisticTensorDictSequential
from torchrl.modules import MLP

from sde_torchrl import SDEActor
from sde_torchrl.config.torchrl_trainer import make_sde_model, register_torchrl_configs

EXAMPLE = REPO / "examples" / "torchrl_trainer"
#: TorchRL's PPO run made tiny: 4 batches of 64 frames from one collector worker, 20-step episodes.
TINY = ("collector.total_frames=256", "trainer.total_frames=256", "collector.frames_per_batch=64",
        "collector.num_workers=1", "replay_buffer.storage.max_size=64", "replay_buffer.batch_size=32",
        "trainer.num_epochs=2", "trainer.progress_bar=false", "transform1.max_steps=20")
#: The example's lines that differ from TorchRL's, and TorchRL's (the second is not in TorchRL's).
SDE_LINES = {"  - model@models.policy_model: sde  # SDE: tanh_normal in TorchRL's\n":
             "  - model@models.policy_model: tanh_normal\n",
             "  auto_register_policy_transforms: true  # SDE: not in TorchRL's\n": ""}
#: sha256 of pytorch/rl's sota-implementations/ppo_trainer/config/config.yaml at commit 0b2a031.
TORCHRL_PPO_CONFIG_SHA256 = "4461adda7a96f2567d5ab9922c2f8f6a990c6c1095001cc7704bcd1b46f7d502"


def example_config(*overrides: str, config_dir: Path = EXAMPLE):
    register_torchrl_configs()
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        return compose("config", overrides=list(overrides))


@pytest.mark.e2e  # a training job with a collector worker process, about 15 s
def test_torchrl_ppo_trainer_trains_the_sde_policy_of_the_example_config(tmp_path):
    cfg = example_config(*TINY, f"logger.log_dir={tmp_path}")
    torch.manual_seed(0)
    trainer = instantiate(cfg.trainer)
    policy = trainer.loss_module.actor_network
    assert isinstance(policy, SDEActor)
    before = {name: value.detach().clone() for name, value in policy.named_parameters()}
    batches = []
    trainer.register_op("batch_process", lambda batch: batches.append(batch.clone()))
    try:
        trainer.train()
    finally:
        trainer.collector.shutdown()

    assert len(batches) == 4
    for batch in batches:
        batch = batch.reshape(-1)
        noise, episode = batch["sde_noise"], batch["collector", "traj_ids"]
        same_episode = episode[1:] == episode[:-1]
        assert same_episode.any() and (~same_episode).any(), "every batch holds steps of two episodes or more"
        held = (noise[1:] == noise[:-1]).flatten(1).all(-1)
        assert held[same_episode].all(), "the noise matrix changed within an episode"
        assert not held[~same_episode].any(), "the noise matrix was not redrawn at an episode's start"
        assert (batch["step_count"][1:][~same_episode] == 0).all()
    moved = [name for name, value in policy.named_parameters() if not torch.equal(value, before[name])]
    assert "module.0.module.1.sigma_param" in moved and any("module.0.module.0" in name for name in moved), moved


def test_the_example_config_is_torchrl_s_but_for_its_two_sde_lines(tmp_path):
    text = (EXAMPLE / "config.yaml").read_text()
    torchrl_s = text[text.index("# PPO Trainer Configuration"):]  # without our header
    for ours, theirs in SDE_LINES.items():
        assert torchrl_s.count(ours) == 1, ours
        torchrl_s = torchrl_s.replace(ours, theirs)
    assert hashlib.sha256(torchrl_s.encode()).hexdigest() == TORCHRL_PPO_CONFIG_SHA256

    (tmp_path / "config.yaml").write_text(torchrl_s)  # TorchRL's own config composes, with its own policy
    cfg = example_config(config_dir=tmp_path)
    assert type(instantiate(cfg.models.policy_model)) is ProbabilisticTensorDictSequential  # TanhNormal's


def test_our_conf_and_torchrls_configs_compose_in_one_process(tmp_path):
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.compose import compose as compose_ours
    from sde_torchrl.config.schemas.train import validate

    register_torchrl_configs()  # TorchRL's env/gym, optimizer/adam, logger/csv, ... are in the store
    ours = compose_ours(["algorithm=ppo", "env=gym", "algorithm.n_steps=8", "algorithm.batch_size=4", "updates=1",
                         "eval_episodes=1", "env.episode_length=10", "logger=csv"])
    assert (ours.env._target_, ours.optimizer._target_) == ("sde_torchrl.envs.gym.make_gym_env", "torch.optim.Adam")
    trainer = build_onpolicy_trainer(validate(ours), out_dir=str(tmp_path))
    assert torch.isfinite(trainer.update(0)["return_mean"]).all()

    theirs = example_config(*TINY)  # TorchRL's entries are back in the store
    assert theirs.training_env.create_env_fn.base_env._target_.startswith("torchrl.")
    assert isinstance(instantiate(theirs.models.policy_model), SDEActor)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"network": MLP(in_features=3, out_features=3, num_cells=[4])}, "out_features=3 with extract_normal_params"),
    ({"network": MLP(in_features=3, out_features=2, num_cells=[4]), "exploration_type": "DETERMINISTIC"},
     "exploration_type='DETERMINISTIC'"),
    ({"network": MLP(in_features=3, out_features=2, num_cells=[4]), "in_keys": ["observation", "goal"]},
     "feature_key="),
    ({"network": torch.nn.Sequential(torch.nn.Linear(3, 2))}, "give action_dim="),
    ({"network": torch.nn.LazyLinear(2)}, "give feature_dim="),
])
def test_make_sde_model_names_what_it_cannot_build(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        make_sde_model(**kwargs)


def test_make_sde_model_follows_tanh_normal_s_bounds_and_mean_bound():
    network = MLP(in_features=3, out_features=2, num_cells=[4])
    policy = make_sde_model(network, low=[-2.0], high=[2.0], tanh_loc=True, init_param=-1.0)
    assert policy.sde.feature_dim == 3 and torch.allclose(policy.sde.sigma_param, torch.tensor(-1.0))
    with torch.no_grad():
        network[-1].bias.fill_(100.0)
    td = policy(TensorDict({"observation": torch.ones(3), "sde_noise": torch.zeros(1, 3)}, []))
    assert torch.allclose(td["loc"], torch.tensor([5.0]))  # 5 · tanh(100 / 5)
    assert torch.allclose(td["action"], 2 * torch.tanh(torch.tensor([5.0])))  # squashed into [-2, 2]


@pytest.mark.parametrize(("override", "message"), [
    ("models.policy_model.init_param=inf", "models.policy_model.init_param=inf: a finite number within float32's"),
    ("models.policy_model.gaussian_init_param=nan", "models.policy_model.gaussian_init_param=nan: a finite number"),
    ("models.policy_model.high=nan", "models.policy_model.high=nan: null, a finite number, or a list"),
    ("models.policy_model.low=[-inf]", "models.policy_model.low=[-inf]: null, a finite number, or a list"),
    ("models.policy_model.action_dim=0", "models.policy_model.action_dim=0: null (read from the network) or a"),
    ("models.policy_model.every_n=3", "models.policy_model.every_n=3: null unless models.policy_model.schedule="),
])
def test_a_refused_sde_setting_is_named_by_its_key_before_anything_is_built(override, message):
    from sde_torchrl.config.torchrl_trainer import check_sde_models
    from sde_torchrl.utils.checks import ArgumentError

    check_sde_models(example_config(*TINY))  # the example's own settings pass
    with pytest.raises(ArgumentError) as info:
        check_sde_models(example_config(*TINY, override))
    assert str(info.value).startswith(message), str(info.value)


def test_make_sde_model_refuses_a_non_finite_init_param():
    with pytest.raises(ValueError, match=r"^init_param=nan: a finite number"):
        make_sde_model(MLP(in_features=3, out_features=2, num_cells=[4]), init_param=float("nan"))


@pytest.mark.e2e
def test_the_example_refuses_a_non_finite_init_param_in_one_line_with_the_config_exit_code(tmp_path):
    result = subprocess.run([sys.executable, str(EXAMPLE / "train.py"), *TINY, "models.policy_model.init_param=nan",
                             f"hydra.run.dir={tmp_path}"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=300)
    lines = own_stderr_lines(result.stderr)
    assert result.returncode == 2, result.stderr[-2000:]
    assert lines == ["error: models.policy_model.init_param=nan: a finite number within float32's range "
                     "(|x| <= 3.4e+38)"], lines
