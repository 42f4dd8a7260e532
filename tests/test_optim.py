"""The optimiser group: eq. 1 by default, momentum and Adam, learning-rate
schedules; stacked runs stay independent and a resumed job steps as an uninterrupted one."""

from __future__ import annotations

import math

import pytest
import torch
from _helpers import Crash, build, compose_config, crash_at, read_rows

from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.trainers.optim import LearningRateSchedule, exploration_parameters, lr_factor, make_optimizer

OPTIONS = {
    "sgd": {"_target_": "torch.optim.SGD"},
    "momentum": {"_target_": "torch.optim.SGD", "momentum": 0.9},
    "nesterov": {"_target_": "torch.optim.SGD", "momentum": 0.9, "nesterov": True},
    "adam": {"_target_": "torch.optim.Adam", "betas": [0.9, 0.999], "eps": 1e-8},
}


# ------------------------------------------------------------------------------- schedules


@pytest.mark.parametrize("final", [0.0, 0.1, 0.5])
def test_linear_and_cosine_schedules_match_their_closed_forms(final):
    updates = 40
    for k in range(updates):
        assert lr_factor("linear", k, updates, final) == pytest.approx(1 - (1 - final) * k / updates, abs=1e-12)
        cosine = final + (1 - final) * (1 + math.cos(math.pi * k / updates)) / 2
        assert lr_factor("cosine", k, updates, final) == pytest.approx(cosine, abs=1e-12)
        assert lr_factor("constant", k, updates, final) == 1.0
    for schedule in ("linear", "cosine"):
        factors = [lr_factor(schedule, k, updates, final) for k in range(updates)]
        assert factors[0] == 1.0 and all(a > b for a, b in zip(factors, factors[1:], strict=False)), schedule
        assert factors[-1] > final  # the last step is never zero
        assert lr_factor(schedule, updates, updates, final) == pytest.approx(final, abs=1e-12)


def test_schedule_sets_every_group_from_its_own_base_rate():
    a, b = torch.nn.Parameter(torch.zeros(1)), torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.SGD([{"params": [a], "lr": 0.1}, {"params": [b], "lr": 1.0}])
    schedule = LearningRateSchedule(optimizer, "linear", updates=4, final_fraction=0.0)
    schedule.apply(2)
    schedule.apply(1)  # a pure function of the update: no drift from repeated calls
    assert [g["lr"] for g in optimizer.param_groups] == pytest.approx([0.075, 0.75])


def test_plain_sgd_is_eq_1():
    """``θ ← θ + α g``: the estimators' loss has gradient ``-g``."""
    theta = torch.nn.Parameter(torch.tensor([1.0, -2.0]))
    optimizer, schedule = make_optimizer([theta], 0.5, OPTIONS["sgd"], updates=10)
    assert schedule is None
    g = torch.tensor([3.0, 4.0])
    (-(g * theta).sum()).backward()
    optimizer.step()
    assert torch.equal(theta.detach(), torch.tensor([1.0 + 0.5 * 3.0, -2.0 + 0.5 * 4.0]))


# ----------------------------------------------------------------- stacked runs, bit for bit


@pytest.mark.parametrize("name", list(OPTIONS))
@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_stacked_runs_step_exactly_as_single_runs(name, schedule):
    """Run ``r`` of parameters stacked over runs steps bit for bit as that run alone."""
    runs, steps = 4, 6
    generator = torch.Generator().manual_seed(0)
    start = torch.randn(runs, 3, 2, generator=generator)
    grads = torch.randn(steps, runs, 3, 2, generator=generator) * torch.logspace(-3, 3, runs).view(1, runs, 1, 1)
    options = {**OPTIONS[name], "lr_schedule": schedule, "final_lr_fraction": 0.1}

    def train(first: int, count: int) -> torch.Tensor:
        theta = torch.nn.Parameter(start[first:first + count].clone())
        optimizer, lr_schedule = make_optimizer([theta], 0.01, options, updates=steps)
        for k in range(steps):
            theta.grad = grads[k, first:first + count].clone()
            if lr_schedule is not None:
                lr_schedule.apply(k)
            optimizer.step()
        return theta.detach()

    stacked = train(0, runs)
    assert not torch.equal(stacked, start)
    for r in range(runs):
        assert torch.equal(stacked[r:r + 1], train(r, 1)), f"run {r}"


@pytest.mark.parametrize("overrides", [("optimizer=adam", "lr=0.01", "optimizer.lr_schedule=cosine"),
                                       ("optimizer=momentum", "optimizer.lr_schedule=linear")])
def test_batched_job_run_equals_the_single_job(tmp_path, overrides):
    budget = ("updates=8", "episodes_per_update=5", "seed=3", "eval_period=4", *overrides)
    build("runs=3", *budget).train(tmp_path / "batched")
    build("runs=1", "first_run=1", *budget).train(tmp_path / "single")
    run1 = [row for row in read_rows(tmp_path / "batched") if row["run"] == "1"]
    single = read_rows(tmp_path / "single")
    assert len(single) == len(run1) == 8
    for mine, theirs in zip(single, run1, strict=True):
        for key, value in mine.items():
            if value and key not in ("run", "update", "episodes"):
                assert float(value) == pytest.approx(float(theirs[key]), rel=1e-5, abs=1e-6), (key, mine["update"])


# ------------------------------------------------------------- the exploration scale's rate


def test_exploration_scale_steps_at_its_own_rate_by_eq_1():
    """With ``sigma_lr_factor=k`` SGD steps σ̂'s parameter ``p`` by ``k α g_p`` and the actor's
    ``θ`` by ``α g_θ`` (eq. 1 per group); the linear schedule keeps the ratio."""
    trainer = build("runs=2", "optimizer.sigma_lr_factor=10", "optimizer.lr_schedule=linear")
    policy, optimizer = trainer.policy, trainer.optimizer
    scale = exploration_parameters(policy)
    names = [name.rsplit(".", 1)[-1] for name, p in policy.named_parameters() if any(p is q for q in scale)]
    assert names == ["sigma_param"]
    lr = float(compose_config("+experiment=minimize").lr)
    trainer.lr_schedule.apply(150)
    assert [group["lr"] for group in optimizer.param_groups] == pytest.approx([lr / 2, 10 * lr / 2])
    before = {name: p.detach().clone() for name, p in policy.named_parameters()}
    grads = {name: torch.randn_like(p) for name, p in policy.named_parameters()}
    for name, p in policy.named_parameters():
        p.grad = -grads[name]  # the estimators' loss has gradient -g
    optimizer.step()
    for name, p in policy.named_parameters():
        factor = 10 if "sigma" in name else 1
        assert torch.allclose(p.detach(), before[name] + factor * lr / 2 * grads[name], rtol=0, atol=1e-7), name


def test_adam_steps_the_exploration_scale_k_times_further():
    """Adam's first step is ``α g / (|g| + ε)``: about ``α`` per parameter, ``k α`` for σ̂'s."""
    theta, sigma = torch.nn.Parameter(torch.zeros(3)), torch.nn.Parameter(torch.zeros(2))
    optimizer, _ = make_optimizer([theta, sigma], 0.01, {**OPTIONS["adam"], "sigma_lr_factor": 4.0}, 10,
                                  scale_parameters=[sigma])
    theta.grad, sigma.grad = torch.tensor([-2.0, 3.0, -0.5]), torch.tensor([1e-3, -5.0])
    optimizer.step()
    assert torch.allclose(theta.detach(), -0.01 * theta.grad.sign(), atol=1e-6)
    assert torch.allclose(sigma.detach(), -0.04 * sigma.grad.sign(), atol=1e-5)


def test_a_factor_of_one_or_a_fixed_scale_keeps_one_group():
    """The default job's optimiser is the one it always was (one group), and so is a job whose σ̂
    is fixed, whatever the factor."""
    assert len(build("runs=1").optimizer.param_groups) == 1
    fixed = build("runs=1", "optimizer.sigma_lr_factor=10", "explorer.learn_sigma=false")
    assert exploration_parameters(fixed.policy) == [] and len(fixed.optimizer.param_groups) == 1


def test_a_factor_without_the_scale_split_is_refused():
    theta = torch.nn.Parameter(torch.zeros(2))
    with pytest.raises(ValueError, match=r"optimizer.sigma_lr_factor=2.0: 1 for this job"):
        make_optimizer([theta], 0.01, {"sigma_lr_factor": 2.0}, 10)


# ----------------------------------------------------------------------------------- resume


@pytest.mark.parametrize("overrides", [("optimizer=adam", "lr=0.01", "optimizer.lr_schedule=cosine"),
                                       ("optimizer=momentum", "optimizer.lr_schedule=linear",
                                        "optimizer.final_lr_fraction=0.2")])
def test_resumed_job_equals_the_uninterrupted_one(tmp_path, overrides):
    """The optimiser's state (momentum buffers, Adam's moments and step) is checkpointed and the
    rate is a function of the update: metrics.csv comes out byte for byte the same."""
    budget = ("runs=2", "updates=12", "episodes_per_update=4", "eval_period=5", *overrides)
    build(*budget).train(tmp_path / "reference", checkpoint_period=4)
    trainer = build(*budget)
    crash_at(trainer, 10)
    with pytest.raises(Crash):
        trainer.train(tmp_path / "resumed", checkpoint_period=4)
    resumed = build(*budget)
    resumed.train(tmp_path / "resumed", checkpoint_period=4)
    reference = (tmp_path / "reference" / "metrics.csv").read_bytes()
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == reference
    assert resumed.optimizer.state_dict()["param_groups"][0]["lr"] == pytest.approx(
        float(compose_config("+experiment=minimize", *overrides).lr)
        * lr_factor(resumed.lr_schedule.schedule, 11, 12, resumed.lr_schedule.final_fraction))


def test_the_default_is_plain_ascent():
    trainer = build("runs=1")
    assert type(trainer.optimizer) is torch.optim.SGD and trainer.lr_schedule is None
    assert trainer.optimizer.param_groups[0]["momentum"] == 0


# ----------------------------------------------------------------------------------- config


@pytest.mark.parametrize("overrides, expected", [
    (("optimizer=lbfgs",), "optimizer=lbfgs: expected one of adam, momentum, rmsprop, sgd"),
    (("optimizer=rmsprop", "optimizer.alpha=1"), "optimizer.alpha=1.0: a number in [0, 1)"),
    (("optimizer.momentum=1.0",), "optimizer.momentum=1.0: a number in [0, 1)"),
    (("optimizer.momentum=-0.5",), "optimizer.momentum=-0.5: a number in [0, 1)"),
    (("optimizer.nesterov=true",), "optimizer.nesterov=true: false unless optimizer.momentum > 0"),
    (("optimizer.lr_schedule=step",), "optimizer.lr_schedule=step: one of constant, linear, cosine"),
    (("optimizer.final_lr_fraction=2",), "optimizer.final_lr_fraction=2.0: a number in [0, 1]"),
    (("optimizer=adam", "optimizer.betas=[0.9]"), "optimizer.betas=[0.9]: two numbers in [0, 1)"),
    (("optimizer=adam", "optimizer.betas=[0.9,1.5]"), "optimizer.betas=1.5: a number in [0, 1)"),
    (("optimizer=adam", "optimizer.eps=0"), "optimizer.eps=0.0: a finite number > 0"),
    (("optimizer=adam", "optimizer.momentum=0.9"), "optimizer.momentum: unknown key"),
    (("optimizer.sigma_lr_factor=0",), "optimizer.sigma_lr_factor=0.0: a finite number > 0"),
    (("optimizer=adam", "optimizer.sigma_lr_factor=nan"), "optimizer.sigma_lr_factor=nan: a finite number > 0"),
])
def test_bad_optimizer_settings_fail_in_one_line(overrides, expected):
    with pytest.raises(Exception) as info:
        validate(compose_config("+experiment=minimize", *overrides))
    assert describe_error(info.value) == expected
