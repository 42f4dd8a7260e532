"""The closed-form scores of a linear SDE controller (eqs. 16, 21, 24) against autograd's, and
the estimators built with ``scores="closed_form"``."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from sde_torchrl import LinearActor, MLPActor, SDEParams, make_sde_actor
from sde_torchrl.objectives.estimators import (
    EpisodeLogLikelihood,
    GPOMDPEstimator,
    ReinforceEstimator,
    episode_scores,
    step_scores,
)
from sde_torchrl.objectives.linear_scores import closed_form_refusal, linear_scores


def _likelihood(runs, sharing="element", transform="expln", weighted=False, squash=False, learn_sigma=True,
                init_param=-1.0):
    actor = LinearActor(3, 2, runs=runs, init=(-1.0, 1.0))
    sde = SDEParams(2, 3, runs=runs, sharing=sharing, sigma_transform=transform, init_param=init_param,
                    learn_sigma=learn_sigma)
    with torch.no_grad():  # spread σ̂'s parameters over both branches of expln (eq. 23)
        if learn_sigma:
            sde.sigma_param.add_(torch.linspace(-1.0, 2.5, sde.sigma_param.numel()).view_as(sde.sigma_param))
    policy = make_sde_actor(actor, sde, squash=True, low=-1.0, high=1.0) if squash else make_sde_actor(actor, sde)
    return EpisodeLogLikelihood(policy, variance_weighted=weighted), policy


def _episodes(likelihood, runs, n=5, t=7, seed=0):
    generator = torch.Generator().manual_seed(seed)
    batch = (*(() if runs is None else (runs,)), n, t)
    x = torch.randn(*batch, 3, generator=generator)
    x[..., 0, 1] = 0.0  # a zero feature: it contributes no variance and no θ score
    return TensorDict({"observation": x, likelihood.sample_key: 2 * torch.randn(*batch, 2, generator=generator)},
                      batch)


@pytest.mark.parametrize("runs", [None, 3])
@pytest.mark.parametrize("sharing", ["element", "action", "single", "feature"])
@pytest.mark.parametrize("transform", ["expln", "exp"])
@pytest.mark.parametrize("weighted", [False, True])
def test_closed_form_scores_equal_autograds(runs, sharing, transform, weighted):
    likelihood, _ = _likelihood(runs, sharing, transform, weighted)
    episodes = _episodes(likelihood, runs)
    closed, reference = linear_scores(likelihood, episodes), episode_scores(likelihood, episodes)
    assert list(closed) == list(reference)  # the same parameters in the same (flattening) order
    for name in reference:
        assert closed[name].shape == reference[name].shape, name
        torch.testing.assert_close(closed[name], reference[name], rtol=2e-5, atol=2e-5)


@pytest.mark.parametrize("weighted", [False, True])
def test_closed_form_step_scores_equal_autograds(weighted):
    likelihood, _ = _likelihood(3, "action", weighted=weighted)
    episodes = _episodes(likelihood, 3)
    closed, reference = linear_scores(likelihood, episodes, per_step=True), step_scores(likelihood, episodes)
    for name in reference:
        assert closed[name].shape == reference[name].shape, name
        torch.testing.assert_close(closed[name], reference[name], rtol=2e-5, atol=2e-5)


def test_closed_form_scores_of_a_squashed_policy_and_a_fixed_sigma():
    """Squashed, the pre-squash sample is scored; with σ̂ fixed only Θ has a score."""
    likelihood, _ = _likelihood(2, squash=True, learn_sigma=False)
    episodes = _episodes(likelihood, 2)
    assert likelihood.sample_key == "action_sample"
    closed, reference = linear_scores(likelihood, episodes), episode_scores(likelihood, episodes)
    assert list(closed) == list(reference) and len(reference) == 1
    torch.testing.assert_close(closed[next(iter(reference))], reference[next(iter(reference))])


def test_eq_16_and_21_by_hand_for_one_step():
    """One step, one action, two features: the paper's formulas written out."""
    actor, sde = LinearActor(2, 1, init=0.5), SDEParams(1, 2, init_param=-1.0)
    likelihood = EpisodeLogLikelihood(make_sde_actor(actor, sde))
    x, u = torch.tensor([2.0, -1.0]), torch.tensor([3.0])
    episodes = TensorDict({"observation": x.view(1, 1, 2), "action": u.view(1, 1, 1)}, [1, 1])
    scores = linear_scores(likelihood, episodes)
    sigma_hat = torch.exp(torch.tensor(-1.0))
    mu, variance = 0.5 * 2.0 + 0.5 * -1.0, float((x.square() * sigma_hat**2).sum())
    theta_score = (u - mu) / variance * x  # eq. 16
    sigma_score = ((u - mu) ** 2 - variance) / variance**2 * x.square() * sigma_hat * sigma_hat  # eqs. 21, 24
    weight_name, sigma_name = list(scores)
    torch.testing.assert_close(scores[weight_name].view(2), theta_score.float())
    torch.testing.assert_close(scores[sigma_name].view(2), sigma_score.float())


def test_closed_form_refuses_other_policies_by_name():
    mlp = EpisodeLogLikelihood(make_sde_actor(MLPActor(3, 2, hidden=(4,)), SDEParams(2, 4)))
    assert closed_form_refusal(mlp) == "the actor is not one bias-free linear layer of the exploration features"
    with pytest.raises(ValueError, match="closed-form scores need a linear SDE controller: the actor is not"):
        linear_scores(mlp, TensorDict({}, [2, 3]))
    biased = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2, bias=True), SDEParams(2, 3)))
    assert closed_form_refusal(biased) is not None
    gaussian = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3, gaussian_init_param=-1.0)))
    assert closed_form_refusal(gaussian) == "the exploration has a Gaussian part (eq. 22)"
    with pytest.raises(ValueError, match="scores=numeric: one of autograd, closed_form"):
        ReinforceEstimator(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3)), scores="numeric")
    with pytest.raises(ValueError, match="the actor is not one bias-free linear layer"):
        ReinforceEstimator(make_sde_actor(MLPActor(3, 2, hidden=(4,)), SDEParams(2, 4)), scores="closed_form")


@pytest.mark.parametrize("estimator", [ReinforceEstimator, GPOMDPEstimator])
def test_estimators_give_the_same_gradient_with_either_scores(estimator):
    likelihood, policy = _likelihood(3, weighted=True)
    episodes = _episodes(likelihood, 3)
    episodes["next", "reward"] = torch.randn(*episodes.batch_size, 1, generator=torch.Generator().manual_seed(1))
    autograd = estimator(policy, variance_weighted=True)(episodes.clone())["gradient"]
    closed = estimator(policy, variance_weighted=True, scores="closed_form")(episodes.clone())["gradient"]
    assert autograd.abs().max() > 0
    torch.testing.assert_close(closed, autograd, rtol=1e-4, atol=1e-5)


def test_the_config_key_reaches_the_estimator_and_refuses_an_mlp(tmp_path):
    from sde_torchrl.config.build import build_trainer
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate
    from sde_torchrl.utils.checks import ArgumentError

    closed_form = ["+experiment=minimize", "scores=closed_form", "runs=2", "logger=none"]
    trainer = build_trainer(compose(closed_form), str(tmp_path / "a"))
    assert trainer.estimator.closed_form
    trainer.close()
    with pytest.raises(ArgumentError, match="scores=numeric: one of autograd, closed_form"):
        validate(compose(["scores=numeric"]))
    for overrides, missing in ((["actor=mlp"], "actor=linear with actor.bias=false"),
                               (["actor.bias=true"], "actor=linear with actor.bias=false"),
                               (["explorer.gaussian_init_param=-1"], "no Gaussian part")):
        with pytest.raises(ArgumentError, match=f"scores=closed_form: autograd, or closed_form with {missing}"):
            validate(compose(["scores=closed_form", *overrides]))
    pgpe = build_trainer(compose([*closed_form, "explorer=pgpe", "estimator=pgpe"]), str(tmp_path / "c"))
    pgpe.close()  # PGPE's estimator, always in closed form, does not take the key
