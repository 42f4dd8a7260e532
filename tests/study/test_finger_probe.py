"""The finger probe's pieces: its scores are the shipped learner's, its direction does what its
rule says, and its central difference is a derivative."""

from __future__ import annotations

import doctest

import pytest
import torch
from tensordict import TensorDict

from analysis.paper import ballcatch_finger_probe as probe
from sde_torchrl import LinearActor, SDEParams, make_sde_actor
from sde_torchrl.objectives.estimators import EpisodeLogLikelihood, reinforce_gradient
from sde_torchrl.objectives.linear_scores import linear_scores


def test_controller_scores_are_the_shipped_learners_variance_weighted_scores():
    torch.manual_seed(0)
    likelihood = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 4), SDEParams(4, 3)), variance_weighted=True)
    theta = dict(likelihood.named_parameters())
    weight_name = next(name for name in theta if name.endswith("weight"))
    observations = torch.randn(5, 8, 3, dtype=torch.float64) + torch.tensor([3.5, 0.0, 2.0], dtype=torch.float64)
    samples = torch.randn(5, 7, 4, dtype=torch.float64)
    steps = TensorDict({"observation": observations[:, :-1].float(), "action": samples.float()}, [5, 7])
    expected = linear_scores(likelihood, steps)[weight_name].double().flatten(1)
    got = probe.controller_scores(theta[weight_name].detach().double(), observations, samples)
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-4)


def test_the_closing_direction_moves_the_finger_command_at_rest_only():
    u = probe.closing_direction()
    rest, release = (torch.tensor(p, dtype=torch.float64) for p in (probe.REST, probe.RELEASE))
    torch.testing.assert_close(u @ rest, torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(u @ release, torch.zeros(4, dtype=torch.float64))
    # the shortest such row: orthogonal to every direction that changes neither command
    kernel = torch.linalg.cross(rest, release)
    assert abs(float(u[probe.FINGERS] @ kernel)) < 1e-12


def test_the_central_difference_of_a_smooth_return_is_its_derivative():
    noise = torch.randn(200, dtype=torch.float64, generator=torch.Generator().manual_seed(1))

    def mean_return(theta: float) -> torch.Tensor:  # per episode, the same noise on both sides
        return -(theta - 1.0) ** 2 + noise

    step = 0.1
    d = probe.central_difference(mean_return(0.5 + step), mean_return(0.5 - step), step)
    assert d["derivative"] == pytest.approx(1.0)  # -2 (θ - 1) at θ = 0.5, exact for a quadratic
    assert probe.closing_pays(d) == "pays"


def test_raises_fingers_reads_the_step_of_a_known_finger_gradient():
    # a REINFORCE estimate from episodes whose return grows with the finger noise at rest
    torch.manual_seed(2)
    noise = torch.randn(400, 4, 3, dtype=torch.float64) * 0.05
    rest = torch.tensor(probe.REST, dtype=torch.float64)
    scores = noise.flatten(1) * 100.0  # scores ∝ Θ̂ (one step with x x^T = 100 I)
    returns = noise[:, probe.FINGERS] @ rest
    gradient, _ = reinforce_gradient(scores.reshape(20, 20, 12), returns.reshape(20, 20))
    assert probe.raises_fingers(gradient).double().mean() > 0.9
    assert probe.raises_fingers(-gradient).double().mean() < 0.1


def test_docstring_examples_run():
    result = doctest.testmod(probe, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_a_sweep_the_probe_cannot_read_is_refused_by_name(tmp_path, capsys):
    from _helpers import REPO

    from sde_torchrl.jobs.run_dir import finished_runs

    rex = finished_runs(REPO / "results" / "ballcatch" / "runs" / "fig5_seed3" / "rex")[0]
    with pytest.raises(SystemExit, match="not a linear ball-catching job with SDE"):
        probe.probe_job(rex)
    with pytest.raises(SystemExit) as stop:
        probe.main([str(tmp_path), "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and "no finished jobs under" in capsys.readouterr().err
