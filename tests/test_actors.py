"""Controllers: linear and MLP maps with stacked runs, initialisation and shape checks."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from sde_torchrl import LinearActor, MLPActor
from sde_torchrl._shapes import stacked_matvec
from sde_torchrl.rng import RunStreams


@pytest.mark.parametrize("bias", [False, True])
def test_linear_actor_computes_theta_x_plus_b(bias):
    actor = LinearActor(3, 2, bias=bias, init=[-1.0, 1.0])
    x = torch.randn(5, 3)
    net = actor.module
    expected = x @ net.weight.T + (net.bias if bias else 0)
    torch.testing.assert_close(actor(TensorDict({"observation": x}, [5]))["loc"], expected)


def test_stacked_runs_are_independent_copies():
    stacked = MLPActor(2, 2, hidden=[3], runs=3, init=[-1.0, 0.0])
    x = torch.randn(3, 4, 2)
    out = stacked(TensorDict({"observation": x}, [3, 4]))["loc"]
    for r in range(3):
        single = MLPActor(2, 2, hidden=[3])
        for layer_s, layer_r in zip(single.module.layers, stacked.module.layers, strict=True):
            layer_s.weight.data, layer_s.bias.data = layer_r.weight[r].clone(), layer_r.bias[r].clone()
        torch.testing.assert_close(single(TensorDict({"observation": x[r]}, [4]))["loc"], out[r])


def test_paper_mlp_has_18_parameters_with_single_sigma():
    """2 → 3 sigmoid → 2 with bias units: 17 weights; one shared σ̂ makes 18 (section 4.1)."""
    from sde_torchrl import StateDependentExplorer

    actor = MLPActor(2, 2, hidden=[3], activation="sigmoid", bias=True)
    explorer = StateDependentExplorer(2, 2, sharing="single")
    assert sum(p.numel() for p in (*actor.parameters(), *explorer.parameters())) == 18


def test_constant_and_uniform_initialisation():
    assert torch.equal(LinearActor(1, 1, init=-2.0).module.weight, torch.full((1, 1), -2.0))
    actor = MLPActor(2, 2, hidden=[3], init=[-1.0, 0.0], runs=50)
    values = torch.cat([p.detach().flatten() for p in actor.parameters()])
    assert float(values.min()) >= -1.0 and float(values.max()) < 0.0 and float(values.std()) > 0.2


def test_per_run_initialisation_streams_match_single_runs():
    stacked = MLPActor(2, 2, hidden=[3], init=[-1.0, 0.0], runs=3)
    stacked.module.reset_parameters(RunStreams(5, 3, "init"))
    single = MLPActor(2, 2, hidden=[3], init=[-1.0, 0.0], runs=1)
    single.module.reset_parameters(RunStreams(5, 1, "init", first_run=2))
    for a, b in zip(stacked.parameters(), single.parameters(), strict=True):
        torch.testing.assert_close(a[2], b[0])


def test_bad_input_is_rejected_by_name():
    with pytest.raises(ValueError, match="activation"):
        MLPActor(2, 2, activation="swish")
    with pytest.raises(ValueError, match="in_features"):
        LinearActor(0, 2)
    with pytest.raises(ValueError, match="low < high"):
        LinearActor(1, 1, init=[0.0, -1.0])
    with pytest.raises(ValueError, match="features"):
        LinearActor(3, 2)(TensorDict({"observation": torch.zeros(4, 2)}, [4]))


@pytest.mark.parametrize(("run_shape", "batch"), [((), (7,)), ((), (2, 5)), ((3,), (3, 4)), ((3,), (3, 2, 6))])
def test_stacked_matvec_is_theta_x_per_run(run_shape, batch):
    matrix, x = torch.randn(*run_shape, 4, 3), torch.randn(*batch, 3)
    run_dims = len(run_shape)
    expected = torch.einsum("ras,r...s->r...a" if run_dims else "as,...s->...a", matrix, x)
    torch.testing.assert_close(stacked_matvec(matrix, x, run_dims), expected)


def test_stacked_matvec_needs_a_run_dimension_in_the_data():
    with pytest.raises(ValueError, match="cannot hold 1 run dims"):
        stacked_matvec(torch.randn(3, 4, 3), torch.randn(3), run_dims=1)
