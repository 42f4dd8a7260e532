"""SAC's gradient step with the SDE policy (``sde_torchrl.trainers.sac``): the losses draw a fresh
noise matrix per step rather than the stored one, the SDE actor is SB3's SAC + gSDE actor and its
loss SB3's, and the compiled step saves no boolean mask for its backward. Built as
``python train.py +experiment=sac_mountaincar`` builds them."""

from __future__ import annotations

import torch
from _helpers import compose_config
from tensordict import TensorDict
from torchrl.data import Bounded

from sde_torchrl.config.build_onpolicy import sde_options
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.modules.sac_actor import CLIP_MEAN, make_sac_networks
from sde_torchrl.objectives.sac import fresh_loss_noise, make_sac_loss
from sde_torchrl.trainers import compiler
from sde_torchrl.trainers.sac import SACUpdate

#: MountainCarContinuous's observation size; its one action lies in [-1, 1].
OBS_DIM = 2


def _conf():
    return validate(compose_config("+experiment=sac_mountaincar", "logger=none"))


def _sde_setup(seed: int = 0):
    """The job's networks, loss and (eager) gradient step, built from its composed config."""
    conf = _conf()
    torch.manual_seed(seed)
    policy, critic, sde = make_sac_networks(OBS_DIM, Bounded(-1.0, 1.0, shape=(1,)), conf.actor.hidden,
                                            sde_options=sde_options(conf.explorer), activation=conf.actor.activation)
    loss = make_sac_loss(policy, critic, 1, gamma=conf.algorithm.gamma, ent_coef=conf.algorithm.ent_coef)
    return loss, sde, SACUpdate(loss, sde, lr=conf.lr, tau=conf.algorithm.tau)


def _transitions(n: int, stored_noise: torch.Tensor) -> TensorDict:
    torch.manual_seed(1)
    return TensorDict({
        "observation": torch.randn(n, OBS_DIM), "action": torch.rand(n, 1) * 2 - 1, "sde_noise": stored_noise.clone(),
        "next": {"observation": torch.randn(n, OBS_DIM), "reward": torch.randn(n, 1),
                 "sde_noise": stored_noise.clone(), "done": torch.zeros(n, 1, dtype=torch.bool),
                 "terminated": torch.zeros(n, 1, dtype=torch.bool)},
    }, [n])


def _parameters(loss) -> TensorDict:
    return TensorDict.from_module(loss).detach().clone()


def test_the_sac_losses_draw_fresh_noise_not_the_stored_one():
    """Stored ξ set to NaN: the step must not read it (it would turn every parameter it reaches into NaN)."""
    n = 64
    loss, sde, update = _sde_setup()
    nan_noise = torch.full((n, 1, sde.feature_dim), float("nan"))
    before = _parameters(loss)
    update(_transitions(n, nan_noise))
    after = _parameters(loss)
    assert all(torch.isfinite(v).all() for v in after.values(True, True))
    assert max((after - before).abs().max().values(True, True)) > 1e-5  # the step did move the parameters
    # the control: the actor loss on the batch as stored does read its noise
    actor_loss, _ = loss.actor_loss(_transitions(n, nan_noise))
    assert torch.isnan(actor_loss)


def test_fresh_noise_is_one_matrix_per_gradient_step_shared_by_the_batch_and_the_next_states():
    """SB3's ``actor.reset_noise()`` before each gradient step: one exploration matrix for every row."""
    _, sde, _ = _sde_setup()
    zeros = torch.zeros(8, 1, sde.feature_dim)
    first, second = _transitions(8, zeros), _transitions(8, zeros)
    fresh_loss_noise(first, sde)
    fresh_loss_noise(second, sde)
    noise = first["sde_noise"]
    assert noise.shape == (8, 1, sde.feature_dim) and torch.equal(noise, noise[:1].expand_as(noise))
    assert torch.equal(first["next", "sde_noise"], noise)
    assert noise.std() > 0.5 and not torch.equal(second["sde_noise"], noise)


def test_the_sde_actor_is_sb3s_sac_gsde_actor():
    """Mean clipped to ±2 before the squash, features not detached, σ̂ per element, p = log_std_init."""
    loss, sde, _ = _sde_setup()
    assert sde.sigma_param.shape == (1, 64) and torch.allclose(sde.sigma_param, torch.tensor(-3.67))
    td = loss.actor_network(TensorDict({"observation": torch.full((4, OBS_DIM), 1e4),
                                        "sde_noise": torch.zeros(4, 1, 64)}, [4]))
    assert td["loc"].abs().max() <= CLIP_MEAN
    assert td["sde_features"].requires_grad  # gSDE's learn_features=True in SB3's SAC


def test_the_actor_loss_equals_sb3s_with_the_same_weights_and_noise_matrix():
    """Our SDE actor loss (SACLoss) and SB3's SAC + gSDE actor loss, same weights, same exploration matrix."""
    from stable_baselines3 import SAC

    conf = _conf()
    model = SAC("MlpPolicy", "MountainCarContinuous-v0", use_sde=True, ent_coef=conf.algorithm.ent_coef, seed=0,
                device="cpu", policy_kwargs={"log_std_init": conf.explorer.init_param,
                                             "net_arch": list(conf.actor.hidden)})
    actor, critic = model.actor, model.critic
    loss, _, _ = _sde_setup()
    torch.manual_seed(2)
    with torch.no_grad():  # train the log-std away from its constant start, then copy SB3's weights into ours
        actor.log_std.add_(0.3 * torch.randn_like(actor.log_std))
        ours = loss.actor_network_params.flatten_keys()
        for index, layer in (("0", actor.latent_pi[0]), ("1", actor.latent_pi[2]), ("2", actor.mu[0])):
            for name in ("weight", "bias"):
                ours[f"module.0.module.0.module.0.net.layers.{index}.{name}"].copy_(getattr(layer, name))
        ours["module.0.module.1.sigma_param"].copy_(actor.log_std.T)
        q = loss.qvalue_network_params.flatten_keys()
        for k, qf in enumerate(critic.q_networks):
            for index in ("0", "2", "4"):
                q[f"module.{index}.weight"][k].copy_(qf[int(index)].weight)
                q[f"module.{index}.bias"][k].copy_(qf[int(index)].bias)
    n, eps = 32, torch.randn(64, 1)  # SB3's exploration_mat is [S, A] = σ̂ᵀ ⊙ ε; ours ξ = εᵀ, [A, S]
    obs = torch.randn(n, OBS_DIM)
    actor.action_dist.exploration_mat = actor.action_dist.get_std(actor.log_std) * eps
    actions, log_prob = actor.action_log_prob(obs)
    q_pi = torch.cat(critic(obs, actions), dim=1).min(dim=1, keepdim=True)[0]
    sb3_loss = (conf.algorithm.ent_coef * log_prob.reshape(-1, 1) - q_pi).mean()
    sb3_loss.backward()
    batch = _transitions(n, eps.T.expand(n, 1, 64))
    batch["observation"] = obs
    our_loss, _ = loss.actor_loss(batch)
    our_loss.backward()
    torch.testing.assert_close(our_loss, sb3_loss, rtol=1e-4, atol=1e-4)
    grads = {k: p.grad for k, p in loss.actor_network_params.flatten_keys().items()}
    torch.testing.assert_close(grads["module.0.module.1.sigma_param"], actor.log_std.grad.T, rtol=1e-3, atol=1e-5)
    torch.testing.assert_close(grads["module.0.module.0.module.0.net.layers.0.weight"], actor.latent_pi[0].weight.grad,
                               rtol=1e-3, atol=1e-5)  # through the features too: learn_features=True


def _saved_for_backward(settings) -> list[torch.dtype]:
    """The dtypes the forward of ``relu(relu(x W) W)`` saves for its backward, partitioned as inductor does."""
    from functorch.compile import aot_function, min_cut_rematerialization_partition
    from torch._inductor.decomposition import select_decomp_table

    saved = []

    def forward_compiler(graph, _):
        output = next(node for node in graph.graph.nodes if node.op == "output")
        saved.extend(value.meta["val"].dtype for value in output.args[0][1:])  # [0] is the loss
        return graph

    step = aot_function(lambda x, w: torch.relu(torch.relu(x @ w) @ w).sum(), fw_compiler=forward_compiler,
                        bw_compiler=lambda graph, _: graph, partition_fn=min_cut_rematerialization_partition,
                        decompositions=select_decomp_table())
    with settings:
        step(torch.randn(4, 3, requires_grad=True), torch.randn(3, 3, requires_grad=True)).backward()
    return saved


def test_the_compiled_step_saves_no_boolean_mask_for_its_backward():
    """Without the pass, inductor's partitioner saves ReLU's boolean mask; with it, only float tensors."""
    assert torch.bool in _saved_for_backward(torch._functorch.config.patch(enable_autograd_cache=False))
    saved = _saved_for_backward(compiler.recomputing_boolean_masks())
    assert saved and torch.bool not in saved
