"""The on-policy jobs' env follows Stable-Baselines3 where the two sides must agree: the vector env
steps with the action clipped to its bounds while the batch keeps the sampled one, and
``RunningNormalize`` is ``VecNormalize``'s rule (running observation statistics, rewards scaled
by the running spread of the discounted return, both clipped)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from sde_torchrl.envs.normalize import CLIP, EPS, RunningNormalize, running_update
from sde_torchrl.envs.vector import GymVectorEnv

BULLET = "pybullet_envs_gymnasium:HalfCheetahBulletEnv-v0"


def test_running_statistics_match_stable_baselines3():
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    reference, rng = RunningMeanStd(shape=(3,)), np.random.default_rng(0)
    mean, var, count = torch.zeros(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64), torch.tensor(1e-4)
    for _ in range(5):
        batch = rng.normal(2.0, 3.0, size=(16, 3))
        reference.update(batch)
        mean, var, count = running_update(mean, var, count.double(), torch.from_numpy(batch))
    np.testing.assert_allclose(mean.numpy(), reference.mean, rtol=1e-12)
    np.testing.assert_allclose(var.numpy(), reference.var, rtol=1e-12)
    assert float(count) == pytest.approx(reference.count)


def test_running_normalize_is_vecnormalizes_rule():
    """Observations standardised and rewards divided by the running spread of each env's discounted
    return (reset where an episode ends), both clipped at 10, as ``VecNormalize`` does."""
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    gamma, envs = 0.9, 4
    norm = RunningNormalize(2, n_envs=envs, gamma=gamma)
    obs_stats, ret_stats = RunningMeanStd(shape=(2,)), RunningMeanStd(shape=())
    returns, rng = np.zeros(envs), np.random.default_rng(1)
    for step in range(6):
        obs = rng.normal(5.0, 2.0, size=(envs, 2)).astype(np.float32)
        reward = np.full((envs, 1), float(step + 1), dtype=np.float32)
        done = np.array([[False]] * 3 + [[step == 2]])
        out = norm._step(TensorDict({}, [envs]), TensorDict(
            {"observation": torch.from_numpy(obs), "reward": torch.from_numpy(reward),
             "done": torch.from_numpy(done)}, [envs]))
        obs_stats.update(obs.astype(np.float64))
        returns = returns * gamma + reward[:, 0]
        ret_stats.update(returns)
        expected_obs = np.clip((obs - obs_stats.mean) / np.sqrt(obs_stats.var + EPS), -CLIP, CLIP)
        expected_reward = np.clip(reward[:, 0] / np.sqrt(ret_stats.var + EPS), -CLIP, CLIP)
        np.testing.assert_allclose(out["observation"].numpy(), expected_obs, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(out["reward"][:, 0].numpy(), expected_reward, rtol=1e-6)
        returns[done[:, 0]] = 0
    far = norm.normalize(torch.tensor([[1e6, -1e6]]))
    assert far.tolist() == [[CLIP, -CLIP]]  # clipped at 10


def test_a_frozen_copy_normalises_with_the_same_statistics_and_leaves_rewards_raw():
    norm = RunningNormalize(2, n_envs=3, gamma=0.99)
    step = TensorDict({"observation": torch.randn(3, 2) * 4 + 1, "reward": torch.ones(3, 1),
                       "done": torch.zeros(3, 1, dtype=torch.bool)}, [3])
    norm._step(TensorDict({}, [3]), step.clone())
    frozen = norm.frozen(n_envs=3)
    before = frozen.obs_mean.clone()
    out = frozen._step(TensorDict({}, [3]), step.clone())
    assert torch.equal(frozen.obs_mean, before)  # no update
    assert torch.equal(out["reward"], step["reward"])
    torch.testing.assert_close(out["observation"], norm.normalize(step["observation"]))


@pytest.mark.parametrize(("n_envs", "obs_dim"), [(4, 16), (1, 3), (16, 27), (8, 1)])
def test_a_step_updates_the_statistics_to_the_tensor_arithmetics_numbers(n_envs, obs_dim):
    """``observe`` works on numpy views of the buffers; its statistics, observations and rewards are
    those of :func:`running_update` and the formulas on tensors, bit for bit."""
    norm, gen = RunningNormalize(obs_dim, n_envs=n_envs, gamma=0.99), torch.Generator().manual_seed(n_envs)
    mean, var, count, r_mean, r_var, r_count, returns = (buffer.clone() for buffer in norm.buffers())
    for _ in range(200):
        scale = 100 * float(torch.rand(1, generator=gen))
        obs = torch.randn(n_envs, obs_dim, generator=gen) * scale + 5
        reward, done = torch.randn(n_envs, 1, generator=gen) * scale, torch.rand(n_envs, 1, generator=gen) < 0.1
        normalized, scaled = norm.observe(obs, reward, done)
        mean, var, count = running_update(mean, var, count, obs)
        returns = returns * 0.99 + reward.double()
        r_mean, r_var, r_count = running_update(r_mean, r_var, r_count, returns)
        expected = ((obs.double() - mean) / (var + EPS).sqrt()).clamp(-CLIP, CLIP).float()
        assert torch.equal(normalized, expected) and torch.equal(norm.obs_var, var) and torch.equal(norm.obs_mean, mean)
        assert torch.equal(scaled, (reward.double() / (r_var + EPS).sqrt()).clamp(-CLIP, CLIP).float())
        assert torch.equal(norm.ret_var, r_var) and torch.equal(norm.obs_count, count)
        returns = returns.masked_fill(done, 0.0)
        assert torch.equal(norm.returns, returns)


def test_a_copied_normaliser_updates_its_own_statistics():
    """The numpy views follow the buffers' memory: a deep copy or a state loaded into a fresh
    normaliser steps its own buffers."""
    import copy

    norm = RunningNormalize(2, n_envs=2, gamma=0.9)
    step = (torch.randn(2, 2), torch.ones(2, 1), torch.zeros(2, 1, dtype=torch.bool))
    norm.observe(*step)
    twin, loaded = copy.deepcopy(norm), RunningNormalize(2, n_envs=2, gamma=0.9)
    loaded.observe(*step)
    loaded.load_state_dict(norm.state_dict())
    twin.observe(*step)
    loaded.observe(*step)
    assert float(norm.obs_count) == pytest.approx(2.0001) and float(twin.obs_count) == pytest.approx(4.0001)
    assert torch.equal(twin.obs_mean, loaded.obs_mean) and torch.equal(twin.returns, loaded.returns)


def test_the_vector_env_steps_with_the_clipped_action_and_the_batch_keeps_the_sampled_one():
    """SB3 clips before ``env.step``; pybullet charges its electricity and stall costs on the action it
    is given, so an unclipped action outside ``[-1, 1]`` would be a harsher reward."""
    pytest.importorskip("pybullet_envs_gymnasium")
    env, reference = GymVectorEnv(BULLET, n_envs=2, seed=3), GymVectorEnv(BULLET, n_envs=2, seed=3)
    try:
        action = torch.tensor([[3.0, -3.0, 0.5, 1.0, -1.0, 0.0]] * 2)
        out = env.step(env.reset().set("action", action))
        expected = reference.step(reference.reset().set("action", action.clamp(-1, 1)))
        assert torch.equal(out["action"], action)  # what the loss scores: the sampled action
        assert torch.equal(out["next", "reward"], expected["next", "reward"])  # what pybullet got: the clipped one
        assert torch.equal(out["next", "observation"], expected["next", "observation"])
    finally:
        env.close()
        reference.close()


def test_an_unclipped_action_would_cost_the_halfcheetah_more():
    """Why the clip matters: stepping pybullet with the raw action charges a larger energy cost."""
    pytest.importorskip("pybullet_envs_gymnasium")
    import gymnasium

    action = np.array([3.0, -3.0, 0.5, 1.0, -1.0, 0.0], dtype=np.float32)
    rewards = []
    for given in (action, np.clip(action, -1, 1)):
        env = gymnasium.make("pybullet_envs_gymnasium:HalfCheetahBulletEnv-v0")
        env.reset(seed=3)
        rewards.append(env.step(given)[1])
        env.close()
    assert rewards[0] < rewards[1] - 0.5


def test_torchrls_clip_transform_steps_with_the_clipped_action_and_keeps_the_sampled_one():
    """The reuse guide's advice for a TorchRL env of your own: ``ClipTransform(in_keys_inv=["action"])``
    gives pybullet the clipped action and leaves the batch the sampled one, as SB3 does."""
    pytest.importorskip("pybullet_envs_gymnasium")
    import gymnasium
    from torchrl.envs import ClipTransform, GymWrapper, TransformedEnv

    def make(clip: bool):
        env = GymWrapper(gymnasium.make("pybullet_envs_gymnasium:HalfCheetahBulletEnv-v0"))
        env.set_seed(3)
        transform = ClipTransform(in_keys_inv=["action"], out_keys_inv=["action"], low=-1.0, high=1.0)
        return TransformedEnv(env, transform) if clip else env

    action = torch.tensor([3.0, -3.0, 0.5, 1.0, -1.0, 0.0])
    clipped, plain = make(True), make(False)
    try:
        out = clipped.step(clipped.reset().set("action", action))
        expected = plain.step(plain.reset().set("action", action.clamp(-1, 1)))
    finally:
        clipped.close()
        plain.close()
    assert torch.equal(out["action"], action)
    assert torch.equal(out["next", "reward"], expected["next", "reward"])
