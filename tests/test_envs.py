"""The function-minimisation env (paper section 4.1): dynamics, reward, specs, seeding and
per-run random streams."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from sde_torchrl import MinimizeEnv, make_minimize_env
from sde_torchrl.envs import expected_linear_return, midway_threshold


@pytest.mark.parametrize("runs", [None, 3])
def test_specs_pass_torchrl_checks(runs):
    check_env_specs(MinimizeEnv(episodes=4, dim=2, runs=runs))
    check_env_specs(make_minimize_env(5, episodes=4, dim=2, runs=runs))


def test_dynamics_and_reward_follow_section_4_1_without_noise():
    env = MinimizeEnv(episodes=2, dim=2, x0=[1.0, -2.0], step_size=0.1, noise_std=0.0)
    td = env.reset()
    torch.testing.assert_close(td["observation"], torch.tensor([[1.0, -2.0]]).expand(2, 2))
    td["action"] = torch.tensor([[3.0, 4.0], [-1.0, 0.0]])
    nxt = env.step(td)["next"]
    expected = torch.tensor([[1.3, -1.6], [0.9, -2.0]])
    torch.testing.assert_close(nxt["observation"], expected)
    torch.testing.assert_close(nxt["reward"], -expected.square().sum(-1, keepdim=True))


def test_state_noise_has_the_configured_std():
    env = MinimizeEnv(episodes=20_000, x0=0.0, noise_std=1.5, seed=3)
    td = env.reset()
    td["action"] = torch.zeros(20_000, 1)
    x = env.step(td)["next", "observation"]
    assert abs(float(x.std()) - 1.5) < 0.03 and abs(float(x.mean())) < 0.03


def test_x0_spread_jitters_uniformly_around_x0():
    x = MinimizeEnv(episodes=5000, x0=5.0, x0_spread=1.0).reset()["observation"]
    assert float(x.min()) >= 4.0 and float(x.max()) <= 6.0 and float(x.std()) > 0.5


def test_episodes_last_episode_length_steps():
    env = make_minimize_env(7, episodes=2)
    td = env.rollout(20, break_when_any_done=False)
    ends = td["next", "truncated"].squeeze(-1)[0]
    assert ends.nonzero().squeeze(-1).tolist() == [6, 13]


def test_same_seed_same_episode_and_other_seed_differs():
    def run(seed):
        env = make_minimize_env(5, episodes=3, runs=2)
        env.set_seed(seed)
        torch.manual_seed(0)
        return env.rollout(5, break_when_any_done=False)["next", "observation"]

    assert torch.equal(run(1), run(1))
    assert not torch.equal(run(1), run(2))


def test_run_r_of_a_batched_env_equals_a_single_run_env_with_first_run_r():
    def states(runs, first_run):
        env = MinimizeEnv(episodes=4, runs=runs, first_run=first_run, x0_spread=1.0, seed=7)
        td = env.reset()
        td["action"] = torch.ones(runs, 4, 1)
        return env.step(td)["next", "observation"]

    torch.testing.assert_close(states(3, 0)[2], states(1, 2)[0])
    assert not torch.equal(states(3, 0)[0], states(3, 0)[1])


def test_wrong_action_shape_is_rejected():
    env = MinimizeEnv(episodes=2, dim=2)
    td = env.reset()
    td["action"] = torch.zeros(2, 3)
    with pytest.raises(ValueError, match="action"):
        env._step(td)


@pytest.mark.parametrize("kwargs, match", [
    ({"episodes": 0}, "episodes"), ({"dim": 0}, "dim"), ({"noise_std": -1.0}, "noise_std"),
    ({"x0_spread": -0.1}, "x0_spread"),
])
def test_bad_arguments_are_rejected_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MinimizeEnv(**kwargs)


def test_bad_episode_length_is_rejected():
    with pytest.raises(ValueError, match="episode_length"):
        make_minimize_env(0)


def test_noise_free_reward_scores_the_successor_before_the_state_noise():
    """Hand-computed step: x = 2, u = -4, s = 0.1 → successor 1.6, reward -2.56, whatever the noise."""
    env = MinimizeEnv(episodes=3, x0=2.0, noise_std=1.0, reward_state="noise_free", seed=1)
    x = env.initial_state()
    x_next, reward = env.transition(x, torch.full_like(x, -4.0))
    torch.testing.assert_close(reward, torch.full((3, 1), -2.56))
    assert not torch.allclose(x_next, torch.full_like(x_next, 1.6))  # the noise is in the next state only


def test_unknown_reward_state_is_rejected():
    with pytest.raises(ValueError, match="reward_state"):
        MinimizeEnv(reward_state="next")


@pytest.mark.parametrize("reward_state", ["noise_free", "noisy"])
@pytest.mark.parametrize("episode_return", ["sum", "mean"])
@pytest.mark.parametrize("theta, episode_length, noise_std", [(-2.0, 15, 0.5), (-5.0, 5, 1.5)])
def test_expected_linear_return_matches_monte_carlo(theta, episode_length, noise_std, reward_state, episode_return):
    env = MinimizeEnv(episodes=40_000, x0=2.0, noise_std=noise_std, reward_state=reward_state, seed=0)
    x, total = env.initial_state(), 0.0
    for _ in range(episode_length):
        x, reward = env.transition(x, theta * x)
        total = total + reward
    monte_carlo = float((total if episode_return == "sum" else total / episode_length).mean())
    expected = expected_linear_return(theta, episode_length, 2.0, 0.1, noise_std, reward_state, episode_return)
    assert monte_carlo == pytest.approx(expected, rel=0.01)


def test_expected_linear_return_of_a_hand_computed_noise_free_episode():
    """θ = -2, x0 = 2, T = 2, σ = 0.5: a² = 0.64; r_0 = -0.64·4, r_1 = -0.64·(0.64·4 + 0.25)."""
    expected = -(0.64 * 4 + 0.64 * (0.64 * 4 + 0.25))
    assert expected_linear_return(-2.0, 2, 2.0, 0.1, 0.5, "noise_free", "sum") == pytest.approx(expected)
    assert expected_linear_return(-2.0, 2, 2.0, 0.1, 0.5, "noise_free", "mean") == pytest.approx(expected / 2)


def test_midway_threshold_lies_half_way_between_start_and_optimum():
    start = expected_linear_return(-2.0, 15, 5.0, 0.1, 0.5)
    best = expected_linear_return(-10.0, 15, 5.0, 0.1, 0.5)
    assert best == pytest.approx(-0.25)  # θ* = -1/s leaves only the noise: E[x²] = σ²
    assert midway_threshold(15, 5.0, 0.1, 0.5, -2.0) == pytest.approx((start + best) / 2)
