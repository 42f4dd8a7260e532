"""Queued episodes scored by the policy that collected them (``queue_scores=as_collected``), as
the authors' PyBrain learners store each step's log-likelihood derivative when the action is
taken, against scoring them again under the current parameters (``rescored``)."""

from __future__ import annotations

import copy

import pytest
import torch
from _helpers import build
from tensordict import TensorDict

from sde_torchrl.objectives.base import EpisodesError
from sde_torchrl.objectives.estimators import (
    enac_gradient,
    flatten_scores,
    gpomdp_gradient,
    reinforce_gradient,
    step_rewards,
)
from sde_torchrl.utils.checks import ArgumentError

#: 2 runs, 2 new episodes per update, a queue of 6: update k uses collections k, k+1 and k+2.
BUDGET = ("runs=2", "episodes_per_update=2", "episode_queue=6", "eval_period=0", "updates=5")


def _recorded(trainer) -> tuple[list, list]:
    """Records the parameters at every collection, and at every update the episodes with the
    estimates from the kept scores and from rescoring (before the step)."""
    snapshots, updates = [], []
    collect, update = trainer.collect_scored, trainer.estimate

    def recording_collect():
        snapshots.append({n: p.detach().clone() for n, p in trainer.estimator.learnable_parameters().items()})
        return collect()

    def recording_update(episodes, k, scores):
        kept = trainer.estimator(episodes, scores=scores)["gradient"]
        rescored = trainer.estimator(episodes)["gradient"]
        updates.append((episodes.clone(), kept, rescored))
        return update(episodes, k, scores)

    trainer.collect_scored, trainer.estimate = recording_collect, recording_update
    return snapshots, updates


@pytest.mark.parametrize("overrides", [(), ("scores=closed_form",), ("estimator=enac",),
                                       ("estimator=gpomdp", "scores=closed_form")])
def test_each_update_uses_the_scores_of_the_parameters_that_collected_each_episode(tmp_path, overrides):
    trainer = build(*BUDGET, "lr=0.02", "queue_scores=as_collected", *overrides)
    snapshots, updates = _recorded(trainer)
    trainer.train(tmp_path)
    assert len(snapshots) == 3 + 4 and len(updates) == 5  # the queue filled by 3 collections, then 1 per update

    scorer = copy.deepcopy(trainer.estimator)  # scores each episode anew under its collection's parameters
    params = scorer.learnable_parameters()
    for k, (episodes, kept, rescored) in enumerate(updates):
        per_step, per_episode = [], []
        for slot, collection in enumerate(range(k, k + 3)):
            with torch.no_grad():
                for name, p in params.items():
                    p.copy_(snapshots[collection][name])
            part = episodes[:, 2 * slot:2 * slot + 2]
            scores, steps = scorer.episode_and_step_scores(part)
            per_episode.append(flatten_scores(scores, 1))
            if steps is not None:
                per_step.append(flatten_scores(steps, 2))
        scores = torch.cat(per_episode, 1)
        returns = scorer.returns(episodes)
        if "estimator=enac" in overrides:
            expected = enac_gradient(scores, returns)[0]
        elif "estimator=gpomdp" in overrides:
            rewards = step_rewards(episodes, ("next", "reward"), scorer.episode_return)
            expected = gpomdp_gradient(torch.cat(per_step, 1), rewards)[0]
        else:
            expected = reinforce_gradient(scores, returns)[0]
        torch.testing.assert_close(kept, scorer.surrogate(expected, returns, 1)["gradient"], rtol=1e-4, atol=1e-6)
        if k == 0:  # the queue was filled under one set of parameters: both ways agree
            torch.testing.assert_close(kept, rescored)
    assert not torch.allclose(updates[-1][1], updates[-1][2], rtol=1e-4, atol=1e-6)  # the parameters moved


def test_the_option_changes_training_only_after_the_parameters_move(tmp_path):
    kept = build(*BUDGET, "queue_scores=as_collected").train(tmp_path / "kept")
    rescored = build(*BUDGET).train(tmp_path / "rescored")
    first, *_ = (tmp_path / "kept" / "metrics.csv").read_text().splitlines()[1:2]
    assert first == (tmp_path / "rescored" / "metrics.csv").read_text().splitlines()[1]  # update 0 alike
    assert kept["final_parameters"] != rescored["final_parameters"]


def test_scores_that_do_not_fit_the_episodes_are_refused():
    trainer = build(*BUDGET, "queue_scores=as_collected")
    estimator = trainer.estimator
    episodes = trainer.collect()
    scores = estimator.collected_scores(episodes)
    with pytest.raises(EpisodesError, match=r"expected the TensorDict of collected_scores\(episodes\)"):
        estimator(episodes, scores=scores[:, :1])
    with pytest.raises(EpisodesError, match="expected the TensorDict"):
        estimator(episodes, scores={"episode": dict(scores["episode"].items())})
    renamed = TensorDict({"episode": {"other": torch.zeros(2, 2, 3)}}, batch_size=[2, 2])
    with pytest.raises(EpisodesError, match=r"cover \['other'\], but the learnable parameters are"):
        estimator(episodes, scores=renamed)
    name = next(iter(scores["episode"].keys()))
    wrong = scores.clone()
    wrong["episode"][name] = torch.zeros(2, 2, 7)
    with pytest.raises(EpisodesError, match=rf"scores\['episode'\]\['{name}'\] has shape \(2, 2, 7\)"):
        estimator(episodes, scores=wrong)

    gpomdp = build(*BUDGET, "estimator=gpomdp").estimator
    with pytest.raises(EpisodesError, match=r"scores lack 'step': make them with collected_scores\(episodes\)"):
        gpomdp(episodes, scores=scores)


def test_pgpe_scores_each_queued_draw_under_the_distribution_that_drew_it(tmp_path):
    trainer = build(*BUDGET, "lr=0.02", "explorer=pgpe", "estimator=pgpe", "explorer.symmetric=false",
                    "queue_scores=as_collected")
    snapshots, updates = _recorded(trainer)
    trainer.train(tmp_path)
    explorer, estimator = trainer.estimator.explorer, trainer.estimator
    for k, (episodes, kept, rescored) in enumerate(updates):
        theta = episodes.get(explorer.parameters_key)[..., 0, :]
        drawn = [snapshots[c] for c in range(k, k + 3) for _ in range(2)]  # two episodes per collection
        mu = torch.stack([torch.cat([d[f"actor.module.{n}"].flatten(1) for n in explorer.parameter_names], -1)
                          for d in drawn], 1)
        sigma = torch.stack([d["explorer.sigma"] for d in drawn], 1)
        returns = estimator.returns(episodes)
        advantage = (returns - returns.mean(-1, keepdim=True)).unsqueeze(-1)
        g_mu = (advantage * (theta - mu) / sigma**2).mean(1)
        g_sigma = (advantage * ((theta - mu) ** 2 - sigma**2) / sigma**3).mean(1)
        expected = estimator.surrogate(torch.cat([g_mu, g_sigma], -1), returns, 1)["gradient"]
        torch.testing.assert_close(kept, expected, rtol=1e-4, atol=1e-6)
        if k == 0:
            torch.testing.assert_close(kept, rescored)
    assert not torch.allclose(updates[-1][1], updates[-1][2], rtol=1e-4, atol=1e-6)


def test_the_config_refuses_kept_scores_without_a_queue_or_with_symmetric_pgpe():
    with pytest.raises(ArgumentError, match="queue_scores=as_collected: rescored without an episode queue"):
        build("queue_scores=as_collected")
    with pytest.raises(ArgumentError, match="queue_scores=as_collected: rescored with explorer.symmetric=true"):
        build(*BUDGET, "explorer=pgpe", "estimator=pgpe", "explorer.symmetric=true", "queue_scores=as_collected")
    with pytest.raises(ArgumentError, match="queue_scores=kept: one of"):
        build(*BUDGET, "queue_scores=kept")
