"""Every Stable-Baselines3 gSDE option has an equivalent here, checked against SB3's own
``StateDependentNoiseDistribution`` where SB3 has one.

Same weights, same features and the same noise matrix give the same action, mean, standard
deviation (eq. 20), log-probability (eq. 13, with the tanh correction when squashed) and entropy,
for ``use_expln`` True and False (``sigma_transform``) and ``full_std`` True and False
(``sharing="element"`` and ``"feature"``), in float64. SB3 adds ``epsilon = 1e-6`` to the
variance and to expln's positive branch; the comparisons set it to 0 to compare tightly, and one
test pins down that the default epsilon is the only difference. The noise schedules that count as
SB3's ``sde_sample_freq`` (``every_n_steps``, ``rollout``) are checked across full and partial
resets, with ``resample`` and with TorchRL's ``Collector``; ``use_sde_at_warmup`` is the
collector's ``init_random_frames``.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, GymEnv, InitTracker, SerialEnv, StepCounter, TransformedEnv

from sde_torchrl import LatentMLPActor, SDEParams, make_minimize_env, make_sde_actor
from sde_torchrl.collectors.rollout import noise_primer, tensor_rollout
from sde_torchrl.modules.noise import SDENoisePrimer
from sde_torchrl.utils.checks import ArgumentError

sb3_distributions = pytest.importorskip("stable_baselines3.common.distributions")
StateDependentNoiseDistribution = sb3_distributions.StateDependentNoiseDistribution

A, S, B = 3, 5, 7  # actions, features, batch
TIGHT = {"rtol": 1e-12, "atol": 1e-12}


def _pair(use_expln, full_std, squash, log_std_init=-1.0, epsilon=0.0, learn_features=False):
    """SB3's distribution and our policy with the same mean network and the same ``log_std``.

    ``log_std`` is spread over both signs around ``log_std_init`` so that both branches of expln
    are used; ours is its transpose (``[A, S]`` against SB3's ``[S, A]``, ``[1, S]`` against ``[S, 1]``).
    """
    torch.manual_seed(0)
    sb3 = StateDependentNoiseDistribution(A, full_std=full_std, use_expln=use_expln, squash_output=squash,
                                          learn_features=learn_features, epsilon=epsilon)
    mean_net, log_std = sb3.proba_distribution_net(S, log_std_init=log_std_init)
    mean_net = mean_net.double()
    log_std = nn.Parameter(log_std.detach().double() + torch.linspace(-1.5, 1.5, log_std.numel()).double()
                           .reshape(log_std.shape))
    sde = SDEParams(A, S, sharing="element" if full_std else "feature",
                    sigma_transform="expln" if use_expln else "exp", init_param=log_std_init).double()
    assert sde.sigma_param.shape == log_std.T.shape
    with torch.no_grad():
        sde.sigma_param.copy_(log_std.T)
    actor = TensorDictModule(mean_net, in_keys=["observation"], out_keys=["loc"])
    policy = make_sde_actor(actor, sde, squash=squash, low=-1.0, high=1.0)
    return sb3, mean_net, log_std, sde, policy


@pytest.mark.parametrize("squash", [False, True])
@pytest.mark.parametrize("full_std", [True, False])
@pytest.mark.parametrize("use_expln", [True, False])
def test_same_weights_features_and_noise_give_sb3s_distribution(use_expln, full_std, squash):
    sb3, mean_net, log_std, sde, policy = _pair(use_expln, full_std, squash)
    x = torch.randn(B, S, dtype=torch.float64)
    sb3.proba_distribution(mean_net(x), log_std, x)
    std = sb3.get_std(log_std)  # [S, A]: SB3's σ
    torch.testing.assert_close(sde.sde_sigma, std.T, **TIGHT)  # σ̂ = expln(p) or exp(p), shared as SB3 shares it

    noise = torch.randn(B, A, S, dtype=torch.float64)  # ξ, ours [A, S] per row
    sb3.exploration_matrices = std * noise.transpose(-1, -2)  # SB3's per-env matrices σ ⊙ ξ, [B, S, A]
    td = policy(TensorDict({"observation": x, "sde_noise": noise}, [B]))
    torch.testing.assert_close(td["action"], sb3.sample(), **TIGHT)  # u = loc + (σ̂ ⊙ ξ) x (eqs. 17-19)
    torch.testing.assert_close(td["loc"], sb3.distribution.mean, **TIGHT)
    dist = policy.get_dist(td.clone())
    torch.testing.assert_close(dist.scale, sb3.distribution.stddev, **TIGHT)  # eq. 20
    torch.testing.assert_close(td["action_log_prob"], sb3.log_prob(td["action"]), **TIGHT)  # eq. 13
    torch.testing.assert_close(dist.deterministic_sample, sb3.mode(), **TIGHT)
    if not squash:
        torch.testing.assert_close(dist.entropy(), sb3.entropy(), **TIGHT)


def test_sb3s_own_noise_draw_gives_the_same_action():
    """SB3 draws its matrices (``sample_weights``); ``ξ = matrix / σ`` in our layout acts the same."""
    sb3, mean_net, log_std, _, policy = _pair(use_expln=True, full_std=True, squash=False)
    x = torch.randn(B, S, dtype=torch.float64)
    sb3.sample_weights(log_std, batch_size=B)
    sb3.proba_distribution(mean_net(x), log_std, x)
    noise = (sb3.exploration_matrices / sb3.get_std(log_std)).transpose(-1, -2)
    td = policy(TensorDict({"observation": x, "sde_noise": noise.detach()}, [B]))
    torch.testing.assert_close(td["action"], sb3.sample(), **TIGHT)


@pytest.mark.parametrize("use_expln", [True, False])
def test_sb3s_default_epsilon_is_the_only_difference(use_expln):
    """SB3's scale is ``sqrt(σ² + 1e-6)`` and its expln ``log1p(p + 1e-6) + 1`` above 0."""
    sb3, mean_net, log_std, sde, policy = _pair(use_expln, full_std=True, squash=False, epsilon=1e-6)
    x = torch.randn(B, S, dtype=torch.float64)
    sb3.proba_distribution(mean_net(x), log_std, x)
    std = sb3.get_std(log_std)
    if use_expln:
        assert not torch.equal(sde.sde_sigma, std.T)  # p > 0 somewhere: SB3 shifts it by epsilon
        torch.testing.assert_close(sde.sde_sigma, std.T, rtol=0, atol=1e-6)
    with torch.no_grad():  # give ours SB3's σ exactly: then the scales differ only by the variance's epsilon
        sde.sigma_param.copy_(std.T.log())
        sde.sigma_transform = "exp"
    dist = policy.get_dist(policy(TensorDict({"observation": x, "sde_noise": torch.zeros(B, A, S)}, [B])))
    torch.testing.assert_close((dist.scale.square() + 1e-6).sqrt(), sb3.distribution.stddev, **TIGHT)


@pytest.mark.parametrize("learn_features", [False, True])
def test_learn_features_matches_sb3s_gradient_into_the_features(learn_features):
    """``LatentMLPActor(learn_features=...)`` is SB3's ``learn_features``: the likelihood's gradient
    reaches the layers under the latent features only through the mean unless it is set."""
    torch.manual_seed(1)
    actor = LatentMLPActor(4, A, hidden=[S], activation="tanh", learn_features=learn_features).double()
    sde = SDEParams(A, S, feature_key="sde_features", init_param=-0.5).double()
    policy = make_sde_actor(actor, sde)
    obs = torch.randn(B, 4, dtype=torch.float64)
    td = policy(TensorDict({"observation": obs, "sde_noise": torch.randn(B, A, S, dtype=torch.float64)}, [B]))
    action = td["action"].detach()
    first = actor.net.layers[0].weight
    (ours,) = torch.autograd.grad(policy.get_dist(td.select("observation", "sde_noise")).log_prob(action).sum(), first)

    sb3 = StateDependentNoiseDistribution(A, use_expln=True, learn_features=learn_features, epsilon=0.0)
    sb3.latent_sde_dim = S
    latent, mean = actor.net.hidden_and_output(obs)
    sb3.proba_distribution(mean, sde.sigma_param.T, latent)
    (theirs,) = torch.autograd.grad(sb3.log_prob(action).sum(), first)
    torch.testing.assert_close(ours, theirs, **TIGHT)
    through_mean_only = StateDependentNoiseDistribution(A, use_expln=True, learn_features=False, epsilon=0.0)
    through_mean_only.latent_sde_dim = S
    latent, mean = actor.net.hidden_and_output(obs)
    through_mean_only.proba_distribution(mean, sde.sigma_param.T, latent)
    (mean_part,) = torch.autograd.grad(through_mean_only.log_prob(action).sum(), first)
    assert torch.allclose(ours, mean_part) != learn_features  # the option changes the gradient


def test_log_std_init_is_init_param_under_both_transforms():
    """SB3's ``log_std_init`` is our ``init_param``: ``σ̂ = exp(p)`` for ``p <= 0`` under both."""
    for init in (-3.67, -2.0, 0.0):
        for use_expln in (True, False):
            _, _, _, sde, _ = _pair(use_expln, full_std=True, squash=False, log_std_init=init)
            fresh = SDEParams(A, S, sigma_transform="expln" if use_expln else "exp", init_param=init)
            torch.testing.assert_close(fresh.sde_sigma, torch.full((A, S), torch.tensor(init).exp().item()))
    assert SDEParams(1, 1, sigma_transform="exp", init_param=1.0).sde_sigma.item() == pytest.approx(2.718281828)
    assert SDEParams(1, 1, init_param=1.0).sde_sigma.item() == pytest.approx(1.693147181)  # expln: ln 2 + 1


@pytest.mark.parametrize(("options", "key"), [
    ({"sigma_transform": "softplus"}, "sigma_transform"),
    ({"sharing": "features"}, "sharing"),
    ({"schedule": "every_n_steps"}, "every_n"),
    ({"schedule": "rollout", "every_n": 3}, "every_n"),
    ({"schedule": "episode", "rollout_steps": 4}, "rollout_steps"),
    ({"schedule": "rollout", "rollout_steps": 0}, "rollout_steps"),
])
def test_bad_new_options_are_named(options, key):
    with pytest.raises(ArgumentError, match=rf"^{key}="):
        SDEParams(1, 1, **options)


def test_explorer_config_takes_the_new_options():
    from sde_torchrl.config.schemas.policy import ExplorerConf

    conf = ExplorerConf(schedule="every_n_steps", every_n=4, rollout_steps=8, sharing="feature",
                        sigma_transform="exp")
    assert (conf.rollout_steps, conf.sigma_transform) == (8, "exp")
    with pytest.raises(ArgumentError, match=r"^explorer\.sigma_transform=softplus"):
        ExplorerConf(sigma_transform="softplus")
    with pytest.raises(ArgumentError, match=r"^explorer\.rollout_steps=8: null unless"):
        ExplorerConf(rollout_steps=8)


# ------------------------------------------------------------- SB3's counting: sde_sample_freq

def _minimize_rollout(schedule, steps=14, episode_length=5, **options):
    """Three synchronised episodes of ``episode_length`` steps, resets after 5 and 10 steps."""
    torch.manual_seed(0)
    sde = SDEParams(1, 1, schedule=schedule, **options)
    env = make_minimize_env(episode_length, episodes=3)
    env.append_transform(sde.make_tensordict_primer())
    policy = make_sde_actor(TensorDictModule(nn.Linear(1, 1), in_keys=["observation"], out_keys=["loc"]), sde)
    with torch.no_grad():
        return env.rollout(steps, policy, break_when_any_done=False)


def _changes(noise):
    """Booleans ``[*, T-1]``: where ξ differs from the previous step's."""
    flat = noise.flatten(-2)
    return (flat[..., 1:, :] != flat[..., :-1, :]).any(-1)


@pytest.mark.parametrize(("n", "rollout_steps"), [(3, None), (2, None), (3, 4), (4, 6)])
def test_every_n_steps_counts_the_rollout_not_the_episode(n, rollout_steps):
    td = _minimize_rollout("every_n_steps", every_n=n, rollout_steps=rollout_steps)
    t = torch.arange(14)
    into_rollout = t if rollout_steps is None else t % rollout_steps
    assert torch.equal(td["sde_age"][0, :, 0], into_rollout)  # the count goes on through the resets
    expected = ((into_rollout % n == 0) | (into_rollout == 0))[1:]  # SB3: n_steps % sde_sample_freq == 0
    assert torch.equal(_changes(td["sde_noise"]), expected.expand(3, 13))
    assert td["is_init"][:, [5, 10]].all()  # there were resets, and they redrew nothing


def test_rollout_schedule_holds_through_resets_and_redraws_per_rollout():
    held = _minimize_rollout("rollout")
    assert not _changes(held["sde_noise"]).any()  # SB3's sde_sample_freq=-1 within one rollout
    assert len(set(held["sde_noise"][:, 0].flatten().tolist())) == 3  # each env its own matrix
    per_rollout = _minimize_rollout("rollout", rollout_steps=4)
    assert torch.equal(_changes(per_rollout["sde_noise"])[0], (torch.arange(1, 14) % 4 == 0))


def test_the_episode_schedules_are_unchanged():
    """``every_n`` still counts the episode and redraws at each reset: the paper's schedules stay."""
    td = _minimize_rollout("every_n", every_n=3)
    step_in_episode = torch.arange(14) % 5
    assert torch.equal(_changes(td["sde_noise"])[0], (step_in_episode % 3 == 0)[1:])


def _two_pendulums(sde):
    """Two envs with episodes of 3 and 5 steps: partial resets inside one rollout."""
    def make(n):
        return lambda: TransformedEnv(GymEnv("Pendulum-v1"), StepCounter(max_steps=n))
    return TransformedEnv(SerialEnv(2, [make(3), make(5)]), Compose(InitTracker(), sde.make_tensordict_primer()))


def _pendulum_actor():
    return TensorDictModule(nn.Linear(3, 1), in_keys=["observation"], out_keys=["loc"])


@pytest.mark.parametrize(("schedule", "every_n"), [("every_n_steps", 2), ("every_n_steps", 4), ("rollout", None)])
def test_sb3_counting_across_partial_resets(schedule, every_n):
    torch.manual_seed(0)
    sde = SDEParams(1, 3, schedule=schedule, every_n=every_n)
    env = _two_pendulums(sde)
    td = env.rollout(12, make_sde_actor(_pendulum_actor(), sde), break_when_any_done=False)
    assert td["is_init"][:, 1:].sum() >= 4  # partial resets happened
    expected = torch.arange(1, 12) % every_n == 0 if every_n else torch.zeros(11, dtype=torch.bool)
    for e in range(2):
        assert torch.equal(_changes(td["sde_noise"][e]), expected)  # whatever the env's episode boundaries
    assert torch.equal(td["sde_age"][..., 0], torch.arange(12).expand(2, 12))


def test_resample_starts_a_rollout_in_a_hand_written_loop():
    """SB3's ``collect_rollouts``: ``reset_noise`` at the start of each rollout, never at episode ends."""
    torch.manual_seed(0)
    sde = SDEParams(1, 3, schedule="rollout")
    env = _two_pendulums(sde)
    primer, policy = noise_primer(env), make_sde_actor(_pendulum_actor(), sde)
    carried, rollouts = env.reset(), []
    for _ in range(3):
        before = carried["sde_noise"].clone()
        carried = primer.resample(carried)
        assert not torch.equal(carried["sde_noise"], before)
        batch = env.rollout(4, policy, auto_reset=False, tensordict=carried, break_when_any_done=False)
        rollouts.append(batch)
        carried = env.maybe_reset(env.step_mdp(batch[:, -1]))
    for batch in rollouts:
        assert not _changes(batch["sde_noise"]).any()  # held through the partial resets
    assert not torch.equal(rollouts[0]["sde_noise"][:, 0], rollouts[1]["sde_noise"][:, 0])
    with pytest.raises(KeyError, match="resample"):
        primer.resample(TensorDict({}, []))


def test_rollout_steps_resamples_at_every_collector_batch():
    """With TorchRL's Collector, ``rollout_steps = frames_per_batch // num_envs`` redraws ξ at the
    start of each batch, SB3's ``sde_sample_freq=-1`` (its PPO default)."""
    torch.manual_seed(0)
    sde = SDEParams(1, 3, schedule="rollout", rollout_steps=4)
    env = _two_pendulums(sde)
    collector = Collector(env, make_sde_actor(_pendulum_actor(), sde), frames_per_batch=8, total_frames=24)
    batches = [batch.clone() for batch in collector]
    collector.shutdown()
    noise = torch.cat([b["sde_noise"] for b in batches], dim=1)  # [env, 12, A, S]
    for e in range(2):
        assert torch.equal(_changes(noise[e]), torch.arange(1, 12) % 4 == 0)


def test_fast_path_draws_like_the_env_for_the_sb3_schedules():
    """The tensor-stepping path (whole fresh episodes) calls the primer's start/advance: one rollout
    per call, the same numbers as ``env.rollout``."""
    sde = SDEParams(1, 1, schedule="every_n_steps", every_n=2)
    policy = make_sde_actor(TensorDictModule(nn.Linear(1, 1), in_keys=["observation"], out_keys=["loc"]), sde)
    env = make_minimize_env(6, episodes=3, seed=1)
    env.append_transform(sde.make_tensordict_primer())
    torch.manual_seed(5)
    with torch.no_grad():
        reference = env.rollout(6, policy, break_when_any_done=False)
        torch.manual_seed(5)
        env.reset()  # the env's own start; the fast path draws its own reset noise
        torch.manual_seed(5)
        fast = tensor_rollout(env.base_env, policy, 6, noise_primer(env))
    assert torch.equal(_changes(fast["sde_noise"]), _changes(reference["sde_noise"]))
    assert torch.equal(_changes(fast["sde_noise"])[0], torch.arange(1, 6) % 2 == 0)


# ------------------------------------------------------------------------------ use_sde_at_warmup

@pytest.mark.parametrize("init_random_frames", [0, 8])
def test_warmup_is_the_collectors_init_random_frames(init_random_frames):
    """SB3's ``use_sde_at_warmup=False`` samples uniform actions for ``learning_starts`` steps:
    TorchRL's ``init_random_frames``. With ``init_random_frames=0`` the warm-up explores with SDE
    (``use_sde_at_warmup=True``): every action is the policy's, rebuilt from the stored ``ξ``."""
    torch.manual_seed(0)
    sde = SDEParams(1, 3, init_param=-3.0)
    transforms = Compose(StepCounter(max_steps=50), InitTracker(), sde.make_tensordict_primer())
    env = TransformedEnv(GymEnv("Pendulum-v1"), transforms)
    policy = make_sde_actor(_pendulum_actor(), sde, squash=True, action_spec=env.action_spec)
    collector = Collector(env, policy, frames_per_batch=8, total_frames=16, init_random_frames=init_random_frames)
    batches = [batch.clone() for batch in collector]
    collector.shutdown()
    for index, batch in enumerate(batches):
        with torch.no_grad():
            replayed = policy(batch.select("observation", "sde_noise").clone())["action"]
        from_policy = torch.isclose(batch["action"], replayed).all(-1)
        warmup = index * 8 < init_random_frames
        assert bool(from_policy.any()) != warmup and bool(from_policy.all()) != warmup
        assert bool((batch["action"].abs() <= 2).all())


def test_primer_option_checks():
    with pytest.raises(ArgumentError, match="^rollout_steps=3: null unless schedule=every_n_steps or rollout"):
        SDENoisePrimer(1, 1, schedule="every_n", every_n=2, rollout_steps=3)
