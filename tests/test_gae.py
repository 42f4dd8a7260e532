"""``RolloutGAE`` writes what TorchRL's ``GAE`` writes, bit for bit, and hands TorchRL the cases it
does not reproduce."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives.value import GAE

from sde_torchrl.objectives.gae import RolloutGAE

GAMMA, LMBDA = 0.99, 0.92


def _critic(obs_dim: int = 3) -> ValueOperator:
    torch.manual_seed(0)
    return ValueOperator(MLP(in_features=obs_dim, out_features=1, num_cells=[256, 256]), in_keys=["observation"])


def _rollout(envs: int = 4, steps: int = 9, obs_dim: int = 3, seed: int = 1) -> TensorDict:
    """Random steps with episodes that end inside the rollout, by termination and by truncation."""
    gen = torch.Generator().manual_seed(seed)
    terminated = torch.rand(envs, steps, 1, generator=gen) < 0.15
    truncated = ~terminated & (torch.rand(envs, steps, 1, generator=gen) < 0.1)
    return TensorDict({
        "observation": torch.randn(envs, steps, obs_dim, generator=gen),
        "next": {"observation": torch.randn(envs, steps, obs_dim, generator=gen),
                 "reward": torch.randn(envs, steps, 1, generator=gen), "done": terminated | truncated,
                 "terminated": terminated, "truncated": truncated},
    }, [envs, steps])


def _both(rollout: TensorDict, critic: ValueOperator, grad: bool = False, **kwargs) -> tuple[TensorDict, TensorDict]:
    with torch.set_grad_enabled(grad):
        ours = RolloutGAE(gamma=GAMMA, lmbda=LMBDA, value_network=critic, **kwargs)(rollout.clone())
        torchrls = GAE(gamma=GAMMA, lmbda=LMBDA, value_network=critic, **kwargs)(rollout.clone())
    return ours, torchrls


def _assert_same(ours: TensorDict, torchrls: TensorDict) -> None:
    assert set(ours.keys(True, True)) == set(torchrls.keys(True, True))
    for key in torchrls.keys(True, True):
        torch.testing.assert_close(ours[key].detach(), torchrls[key].detach(), rtol=0, atol=0, equal_nan=True,
                                   msg=str(key))  # equal bit for bit (NaN where both have NaN)


@pytest.mark.parametrize(("envs", "steps", "obs_dim", "seed"),
                         [(4, 9, 3, 1), (1, 5, 3, 2), (16, 64, 17, 3), (3, 1, 2, 4)])
def test_the_advantages_targets_and_values_are_torchrls(envs, steps, obs_dim, seed):
    rollout = _rollout(envs, steps, obs_dim, seed)
    ours, torchrls = _both(rollout, _critic(obs_dim))
    assert {"advantage", "value_target", "state_value", ("next", "state_value")} <= set(ours.keys(True, True))
    _assert_same(ours, torchrls)


def test_a_job_rollout_gets_torchrls_advantages():
    """A2C on Pendulum with episodes shorter than the rollout, as the trainer calls it (no gradient)."""
    from _helpers import compose_config

    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.schemas.train import validate

    trainer = build_onpolicy_trainer(validate(compose_config(
        "algorithm=a2c", "env=gym", "env.episode_length=5", "algorithm.n_steps=7", "algorithm.n_envs=3",
        "actor.hidden=[8]", "logger=none")))
    assert isinstance(trainer.advantage, RolloutGAE)
    for _ in range(3):
        rollout = trainer.collector.rollout()
        _assert_same(*_both(rollout, trainer.critic))


def test_what_the_tensor_path_does_not_reproduce_goes_to_torchrl():
    """With gradients on, a hooked critic or a NaN next observation, the numbers are TorchRL's own:
    a hook that shifts the values would be skipped by a direct call of the network."""
    rollout, critic = _rollout(), _critic()
    _assert_same(*_both(rollout, critic, grad=True))
    handle = critic.register_forward_hook(lambda module, args, out: out.set("state_value", out["state_value"] + 1.0))
    try:
        ours, torchrls = _both(rollout, critic)
        _assert_same(ours, torchrls)
        plain = _both(rollout, _critic())[0]
        assert not torch.equal(ours["state_value"], plain["state_value"])  # the hook ran
    finally:
        handle.remove()
    holed = rollout.clone()
    holed["next", "observation"][0, 2, 1] = float("nan")
    _assert_same(*_both(holed, critic))
