"""The on-policy updates' fast path: the losses call the policy and critic themselves
(``functional=False``) and give TorchRL's default functional losses' numbers bit for bit; the
compiled objective gives the eager one's value and gradients to rounding; ``fused`` picks torch's
fused kernel only where the optimiser has one."""

from __future__ import annotations

import copy

import pytest
import torch
from _helpers import compose_config
from test_ppo_job import TINY
from torchrl.objectives import A2CLoss, ClipPPOLoss

from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.objectives.actor_critic import make_a2c_loss, make_ppo_loss
from sde_torchrl.trainers.a2c import A2CUpdate
from sde_torchrl.trainers.objective import loss_objective
from sde_torchrl.trainers.optim import make_optimizer
from sde_torchrl.trainers.ppo import PPOUpdate


@pytest.fixture(scope="module")
def rollout():
    """A trainer of the tiny PPO job (SDE, Pendulum) and one rollout with its advantages."""
    trainer = build_onpolicy_trainer(validate(compose_config(*TINY, "explorer=gsde_freq4", "logger=none")))
    batch = trainer.collector.rollout()
    with torch.no_grad():
        trainer.advantage(batch)
    yield trainer, batch
    trainer.close()


def updated_parameters(make_loss, make_update, trainer, batch) -> list[torch.Tensor]:
    """The parameters after one update of copies of the trainer's policy and critic."""
    policy, critic = copy.deepcopy(trainer.policy), copy.deepcopy(trainer.critic)
    loss = make_loss(policy, critic)
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-2)
    torch.manual_seed(0)  # the minibatch order
    make_update(loss, optimizer)(batch.clone(), 0)
    return [p.detach().clone() for p in (*policy.parameters(), *critic.parameters())]


def test_ppo_calling_the_modules_gives_the_functional_losses_numbers(rollout):
    trainer, batch = rollout
    terms = {"clip_epsilon": 0.2, "entropy_bonus": False, "critic_coeff": 0.5, "loss_critic_type": "l2",
             "normalize_advantage": True}
    update = lambda loss, opt: PPOUpdate(loss, opt, n_epochs=2, batch_size=16, max_grad_norm=0.5)  # noqa: E731
    ours = updated_parameters(lambda p, c: make_ppo_loss(p, c, clip_range=0.2, ent_coef=0.0, vf_coef=0.5),
                              update, trainer, batch)
    torchrl_default = updated_parameters(lambda p, c: ClipPPOLoss(p, c, **terms), update, trainer, batch)
    before = [p.detach() for p in (*trainer.policy.parameters(), *trainer.critic.parameters())]
    assert any(not torch.equal(a, b) for a, b in zip(ours, before, strict=True))  # the update moved them
    assert all(torch.equal(a, b) for a, b in zip(ours, torchrl_default, strict=True))


def test_a2c_calling_the_modules_gives_the_functional_losses_numbers(rollout):
    trainer, batch = rollout
    update = lambda loss, opt: A2CUpdate(loss, opt, max_grad_norm=0.5)  # noqa: E731
    ours = updated_parameters(lambda p, c: make_a2c_loss(p, c, ent_coef=0.01, vf_coef=0.4), update, trainer, batch)
    torchrl_default = updated_parameters(
        lambda p, c: A2CLoss(p, c, entropy_bonus=True, entropy_coeff=0.01, critic_coeff=0.4, loss_critic_type="l2"),
        update, trainer, batch)
    assert all(torch.equal(a, b) for a, b in zip(ours, torchrl_default, strict=True))


@pytest.mark.e2e  # torch.compile (inductor)
def test_the_compiled_objective_gives_the_eager_value_and_gradients_to_rounding(rollout):
    trainer, batch = rollout
    loss = make_ppo_loss(trainer.policy, trainer.critic, clip_range=0.2, ent_coef=0.01, vf_coef=0.5)
    minibatch = batch.reshape(-1)[:16]
    results = []
    for compiled in (False, True):
        loss.zero_grad()
        value = loss_objective(loss, compile=compiled)(minibatch.clone())
        value.backward()
        results.append((value.detach(), [p.grad.clone() for p in loss.parameters()]))
    (eager, eager_grads), (compiled_value, compiled_grads) = results
    assert torch.isfinite(eager) and any(bool(g.abs().sum() > 0) for g in eager_grads)
    torch.testing.assert_close(compiled_value, eager, rtol=1e-5, atol=1e-6)
    for got, expected in zip(compiled_grads, eager_grads, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize(("target", "fused"), [("torch.optim.Adam", True), ("torch.optim.SGD", True),
                                               ("torch.optim.RMSprop", None)])
def test_fused_steps_with_the_fused_kernel_only_where_there_is_one(target, fused):
    theta = torch.nn.Parameter(torch.zeros(3))
    optimizer, _ = make_optimizer([theta], 0.1, {"_target_": target}, 10, fused=True)
    assert optimizer.defaults.get("fused") is fused
    assert make_optimizer([theta], 0.1, {"_target_": target}, 10)[0].defaults.get("fused") in (None, False)
