"""Controllers: linear and MLP maps with stacked runs, initialisation and shape checks."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from sde_torchrl import LatentMLPActor, LinearActor, MLPActor
from sde_torchrl.utils.rng import RunStreams
from sde_torchrl.utils.shapes import stacked_matvec


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
    from sde_torchrl import SDEParams, make_sde_actor

    actor = MLPActor(2, 2, hidden=[3], activation="sigmoid", bias=True)
    policy = make_sde_actor(actor, SDEParams(2, 2, sharing="single"))
    assert sum(p.numel() for p in policy.parameters()) == 18


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


# ------------------------------------------------------------------- latent features (gSDE-style)

def _latent_actor(learn_features=False, runs=None):
    torch.manual_seed(0)
    return LatentMLPActor(3, 2, hidden=[5, 4], activation="relu", learn_features=learn_features, runs=runs)


def test_latent_actor_writes_the_mlp_output_and_its_last_hidden_layer():
    actor = _latent_actor()
    x = torch.randn(6, 3)
    td = actor(TensorDict({"observation": x}, [6]))
    first, second, out = actor.net.layers
    hidden = torch.relu(second(torch.relu(first(x))))
    torch.testing.assert_close(td["sde_features"], hidden)
    torch.testing.assert_close(td["loc"], out(hidden))
    torch.testing.assert_close(td["loc"], actor.net(x))


@pytest.mark.parametrize("learn_features", [False, True])
def test_latent_features_pass_the_sde_gradient_only_when_learned(learn_features):
    from sde_torchrl import SDEParams, make_sde_actor

    actor = _latent_actor(learn_features)
    policy = make_sde_actor(actor, SDEParams(2, 4, feature_key="sde_features"))
    td = TensorDict({"observation": torch.randn(6, 3), "sde_noise": torch.randn(6, 2, 4)}, [6])
    dist = policy.get_dist(td)
    variance = (policy.sde.sde_sigma.square() * td["sde_features"].square().unsqueeze(-2)).sum(-1)
    torch.testing.assert_close(dist.scale.square(), variance)  # eq. (20) with x = h
    dist.scale.sum().backward()  # the scale depends on the mean's layers only through h
    first_layer_grad = actor.net.layers[0].weight.grad
    assert (first_layer_grad is not None and first_layer_grad.abs().sum() > 0) == learn_features


def test_latent_actor_stacks_runs_and_without_hidden_layers_uses_the_observation():
    stacked = _latent_actor(runs=3)
    x = torch.randn(3, 4, 3)
    td = stacked(TensorDict({"observation": x}, [3, 4]))
    assert td["loc"].shape == (3, 4, 2) and td["sde_features"].shape == (3, 4, 4)
    plain = LatentMLPActor(3, 2, hidden=[])
    assert plain.feature_dim == 3
    torch.testing.assert_close(plain(TensorDict({"observation": x[0]}, [4]))["sde_features"], x[0])


def test_actors_doctests():
    import doctest

    import sde_torchrl.modules.actors

    result = doctest.testmod(sde_torchrl.modules.actors, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_the_latent_actors_clipped_mean_is_a_hardtanh_module_after_it():
    """``clip_loc`` inside the actor gives what a ``Hardtanh`` module after it gives, values and
    gradients (SAC's clipped mean, one module instead of two)."""
    from tensordict.nn import TensorDictModule, TensorDictSequential

    torch.manual_seed(0)
    clipped = LatentMLPActor(3, 2, hidden=[8], clip_loc=0.3, learn_features=True)
    plain = LatentMLPActor(3, 2, hidden=[8], learn_features=True)
    plain.load_state_dict(clipped.state_dict())
    chain = TensorDictSequential(plain, TensorDictModule(torch.nn.Hardtanh(-0.3, 0.3), ["loc"], ["loc"]))
    obs = torch.randn(64, 3) * 3
    ours, theirs = clipped(TensorDict({"observation": obs}, [64])), chain(TensorDict({"observation": obs}, [64]))
    assert (ours["loc"].abs() == 0.3).any() and (ours["loc"].abs() < 0.3).any()  # both sides of the clip
    assert torch.equal(ours["loc"], theirs["loc"])
    grads = [torch.autograd.grad(td["loc"].sum(), list(m.parameters())) for td, m in ((ours, clipped), (theirs, plain))]
    assert all(torch.equal(a, b) for a, b in zip(*grads, strict=True))
