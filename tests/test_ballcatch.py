"""Tests of the pybullet ball-catching task (gymnasium env and batched TorchRL env)."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pybullet
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from sde_torchrl.envs.ballcatch import (
    ARM_MODELS,
    BALLCATCH_ID,
    DEFAULT_MODEL,
    EPISODE_STEPS,
    BallCatchConfig,
    BallCatchEnv,
    BallCatchWorld,
    BatchedBallCatchEnv,
    episode_return,
    make_ballcatch_env,
    make_parallel_ballcatch,
    register_ballcatch,
    scripted_action,
)
from sde_torchrl.envs.ballcatch.demo import main
from sde_torchrl.envs.ballcatch.models import PYBRAIN_FINGERS, PYBRAIN_SCRIPTED_WEIGHTS, SCRIPTED_WEIGHTS

SEEDS = range(5)
CUP_GROUND_Z = ARM_MODELS["cup"].ground_z


@pytest.fixture(scope="module")
def env():
    """The default arm's gymnasium env."""
    e = BallCatchEnv()
    yield e
    e.close()


@pytest.fixture(scope="module")
def cup_env():
    e = BallCatchEnv(model="cup")
    yield e
    e.close()


def scripted_policy(td):
    """The default arm's scripted controller on a batch, computed exactly as for the gymnasium env."""
    obs = td["observation"].reshape(-1, 3).numpy()
    action = np.stack([scripted_action(o).astype(np.float32) for o in obs])
    return td.set("action", torch.from_numpy(action).reshape(*td.batch_size, 4))


def test_the_default_arm_is_the_authors():
    assert DEFAULT_MODEL == "pybrain" and BallCatchConfig().model == "pybrain"
    assert make_ballcatch_env(1).base_env.config.model == "pybrain"


# ---------------------------------------------------------------------------- model "cup"
def test_scripted_linear_controller_catches(cup_env):
    returns = [episode_return(cup_env, "scripted", seed) for seed in SEEDS]
    assert np.mean(returns) >= -1.1
    assert min(returns) >= -1.0  # every one a "good catch" in the paper's terms


def test_zero_torque_drops_the_ball(cup_env):
    returns = [episode_return(cup_env, "zero", seed) for seed in SEEDS]
    assert np.mean(returns) <= -1.5


@pytest.mark.parametrize(
    ("finger_row", "low", "high"),
    [([-5.0, 0.0, 0.0], -1.5, -1.2), ([5.0, 0.0, 0.0], -1.0, -0.5)],
    ids=["always-open", "always-closed"],
)
def test_catch_needs_a_closed_hand(cup_env, monkeypatch, finger_row, low, high):
    """Holding the arm up is not enough: an open hand keeps the ball on its outer finger (the
    paper's R ~ -1.5 regime, not a catch); a hand closed from the start holds the ball in its cup."""
    weights = SCRIPTED_WEIGHTS.copy()
    weights[3] = finger_row
    monkeypatch.setattr("sde_torchrl.envs.ballcatch.models.SCRIPTED_WEIGHTS", weights)
    assert low <= episode_return(cup_env, "scripted", 0) <= high


def test_rewards_info_and_truncation(cup_env):
    obs, info = cup_env.reset(seed=3)
    assert obs.dtype == np.float32 and obs.shape == (3,)
    assert info["distance"] == pytest.approx(5.0, abs=0.1)
    rewards, held = [], []
    for t in range(EPISODE_STEPS):
        obs, reward, terminated, truncated, info = cup_env.step(scripted_action(obs, "cup"))
        rewards.append(reward)
        held.append(info["held"])
        assert not terminated
        assert truncated == (t == EPISODE_STEPS - 1)
    rewards = np.array(rewards)
    assert rewards.min() >= -3.0 and rewards.max() <= -0.5
    assert rewards[0] == -3.0  # distance 5 is capped at 3
    assert all(held[200:]) and not any(held[:50])
    assert info["distance"] == pytest.approx(0.5, abs=0.05)
    with pytest.raises(RuntimeError, match="before reset"):
        cup_env.step(np.zeros(4))


def test_ground_gives_minus_three_forever(cup_env):
    cup_env.reset(seed=0)
    rewards = [cup_env.step(np.zeros(4))[1] for _ in range(300)]
    first = rewards.index(-3.0, 100)
    assert all(r == -3.0 for r in rewards[first:])


def test_ground_contact_freezes_the_world(cup_env):
    """Ground contact is absorbing: no more physics, the observation stays put, rewards are -3."""
    obs, _ = cup_env.reset(seed=0)
    rewards, observations = [], []
    for _ in range(300):
        obs, reward, *_ = cup_env.step(np.zeros(4))
        rewards.append(reward)
        observations.append(obs)
    first = next(t for t, o in enumerate(observations) if o[2] < CUP_GROUND_Z)
    assert all(np.array_equal(o, observations[first]) for o in observations[first:])
    assert all(r == -3.0 for r in rewards[first:])


def test_batched_ground_contact_freezes_only_that_world():
    benv = BatchedBallCatchEnv(2, config=BallCatchConfig(model="cup"), seed=0)
    try:
        action = torch.tensor([[0.0] * 4, [1.0, 1.0, 1.0, -1.0]])  # world 0 drops, world 1 holds
        with torch.no_grad():
            td = benv.rollout(300, lambda td: td.set("action", action))
        height = td["next", "observation"][..., 2]
        grounded = (height[0] < CUP_GROUND_Z).nonzero()[0, 0]
        assert (height[0, grounded:] == height[0, grounded]).all()
        assert (td["next", "reward"][0, grounded:] == -3.0).all()
        assert (height[1] > CUP_GROUND_Z).all() and height[1, -1] != height[1, -2]  # still simulated
    finally:
        benv.close()


def seeded_observations(env, seed: int, action_seed: int, steps: int = 150) -> np.ndarray:
    """Observations of an episode from ``reset(seed)`` under uniform random actions."""
    rng = np.random.default_rng(action_seed)
    obs = [env.reset(seed=seed)[0]]
    obs += [env.step(rng.uniform(-1, 1, 4))[0] for _ in range(steps)]
    return np.array(obs)


def test_same_seed_same_episode(env):
    a, b, c = (seeded_observations(env, seed, 123) for seed in (7, 7, 8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[0], c[0])  # the seed moves the release point (jitter 0.05)
    assert np.abs(a[0, :2] - c[0, :2]).max() <= 0.1


@pytest.mark.parametrize(
    ("action", "match"),
    [(np.zeros(3), "shape"), (np.zeros((1, 4)), "shape"), (np.array([0.0, np.nan, 0.0, 0.0]), "non-finite")],
)
def test_bad_action_raises(env, action, match):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)


def test_gymnasium_check_env_and_render():
    e = BallCatchEnv(render_mode="rgb_array", render_size=(64, 48))
    try:
        check_env(e)
        e.reset(seed=0)
        frame = e.render()
        assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
        assert frame.std() > 5  # not a blank image
    finally:
        e.close()


def test_register_is_idempotent():
    register_ballcatch()
    register_ballcatch()
    assert BALLCATCH_ID in gym.registry
    e = gym.make(BALLCATCH_ID)
    try:
        obs, _ = e.reset(seed=0)
        assert e.observation_space.contains(obs)
    finally:
        e.close()


def test_bad_config_raises():
    with pytest.raises(ValueError, match="jitter"):
        BallCatchConfig(jitter=-1.0)
    with pytest.raises(ValueError, match="render_mode"):
        BallCatchEnv(render_mode="human")


def test_cli_prints_one_json_line(capsys):
    main(["--policy", "zero", "--episodes", "1", "--seed", "2", "--model", "cup"])
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    result = json.loads(out[0])
    assert result["returns"] == [pytest.approx(-3.0)] and result["mean_return"] == pytest.approx(-3.0)


# ---------------------------------------------------------------------------- batched TorchRL env
@pytest.fixture()
def benv():
    e = BatchedBallCatchEnv(num_worlds=3, seed=0)
    yield e
    e.close()


def test_batched_check_env_specs(benv):
    check_env_specs(benv)
    assert benv.action_spec.shape == (3, 4)
    assert benv.observation_spec["observation"].shape == (3, 3)


def test_batched_matches_gym_env_without_jitter():
    config = BallCatchConfig(jitter=0.0)
    gym_env, benv = BallCatchEnv(config=config), BatchedBallCatchEnv(2, config=config, seed=0)
    try:
        obs, _ = gym_env.reset(seed=0)
        total = 0.0
        for _ in range(EPISODE_STEPS):
            obs, reward, *_ = gym_env.step(scripted_action(obs).astype(np.float32))
            total += reward
        expected = total / EPISODE_STEPS
        with torch.no_grad():
            td = benv.rollout(EPISODE_STEPS, scripted_policy)
        returns = td["next", "reward"].mean(dim=(1, 2))
        torch.testing.assert_close(returns, torch.full((2,), expected, dtype=torch.float32))
        assert expected >= -1.0
        assert td["next", "truncated"][:, -1].all() and not td["next", "truncated"][:, :-1].any()
        assert not td["next", "terminated"].any()
    finally:
        gym_env.close()
        benv.close()


def test_batched_partial_reset(benv):
    td = benv.reset()
    start = td["observation"].clone()
    for _ in range(60):
        td = benv.step(td.set("action", torch.zeros(3, 4)))["next"]
    moved = td["observation"].clone()
    assert (moved[:, 2] < start[:, 2] - 1.0).all()  # the balls fell
    td.set("_reset", torch.tensor([[False], [True], [False]]))
    out = benv.reset(td)
    assert out["observation"][1, 2] == pytest.approx(float(start[1, 2]), abs=1e-5)  # back up top
    assert (out["observation"][1, :2] - start[1, :2]).abs().max() <= 0.1  # within twice the jitter
    torch.testing.assert_close(out["observation"][[0, 2]], moved[[0, 2]])
    assert [e.t for e in benv.episodes] == [60, 0, 60]


def test_batched_seed_is_private_and_reproducible(benv):
    np_state, torch_state = np.random.get_state()[1].copy(), torch.get_rng_state().clone()
    benv.set_seed(5)
    a = benv.reset()["observation"]
    benv.set_seed(5)
    b = benv.reset()["observation"]
    benv.set_seed(6)
    c = benv.reset()["observation"]
    torch.testing.assert_close(a, b)
    assert not torch.equal(a, c)
    assert len({tuple(x) for x in a[:, :2].tolist()}) == 3  # worlds get different jitter
    np.testing.assert_array_equal(np.random.get_state()[1], np_state)
    assert torch.equal(torch.get_rng_state(), torch_state)


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (torch.zeros(2, 4), "shape"),
        (torch.zeros(3, 3), "shape"),
        (torch.tensor([[0.0, 0, 0, 0], [0, float("inf"), 0, 0], [0, 0, 0, 0]]), r"worlds \[1\]"),
    ],
)
def test_batched_bad_action_raises(benv, action, match):
    benv.reset()
    with pytest.raises(ValueError, match=match):
        benv._step(TensorDict({"action": action}, batch_size=[]))


def test_batched_dead_client_names_the_world(benv):
    td = benv.reset()
    pybullet.disconnect(physicsClientId=benv.worlds[1].client)
    with pytest.raises(RuntimeError, match="world 1"):
        benv.step(td.set("action", torch.zeros(3, 4)))


@pytest.mark.e2e  # worker processes: spawned, each importing torch and the env
def test_parallel_helper_runs_two_processes():
    env = make_parallel_ballcatch(num_workers=2, worlds_per_worker=2)
    try:
        env.set_seed(0)
        with torch.no_grad():
            td = env.rollout(5, scripted_policy)
        assert td.batch_size == torch.Size([2, 2, 5])
        assert (td["next", "reward"] == -3.0).all()  # ball still 5 units above the palm
    finally:
        env.close()


def test_stacked_runs_layout_and_per_run_streams():
    """With runs, the batch is [runs, worlds] and run r's release jitter is that of a one-run
    env with first_run=r (same seed), so batched and single training jobs agree."""
    stacked = BatchedBallCatchEnv(num_worlds=2, runs=3, seed=4)
    single = BatchedBallCatchEnv(num_worlds=2, runs=1, first_run=2, seed=4)
    try:
        check_env_specs(stacked)
        stacked.set_seed(4)
        first = stacked.reset()["observation"]
        assert first.shape == (3, 2, 3)
        torch.testing.assert_close(first[2], single.reset()["observation"][0])
        assert not torch.equal(first[0], first[1])
        td = stacked.rand_step(stacked.reset())
        assert td["next", "reward"].shape == (3, 2, 1)
    finally:
        stacked.close()
        single.close()


def test_a_finished_job_closes_its_worlds(tmp_path, monkeypatch):
    """Launcher workers run job after job: each job must disconnect its pybullet clients."""
    from _helpers import compose_config

    from sde_torchrl.config import build
    from sde_torchrl.config.schemas.train import validate

    built = []
    original = build.build_trainer
    monkeypatch.setattr(build, "build_trainer", lambda *a, **k: built.append(original(*a, **k)) or built[-1])
    cfg = compose_config("+experiment=ballcatch_reinforce", "runs=2", "updates=1", "episode_queue=2",
                         "env.episode_length=5", "eval_episodes=1", "logger=none")
    build.run_job(validate(cfg), str(tmp_path), {})
    worlds = [w for env in (built[0].env, built[0].eval_env) for w in env.base_env.worlds]
    assert len(worlds) == 4 and not any(w.is_connected() for w in worlds)


def test_a_job_records_each_runs_level_in_its_summary(tmp_path):
    """summary.json says what each run reached: the final evaluation per step and its level."""
    import json

    from _helpers import compose_config

    from sde_torchrl.config import build
    from sde_torchrl.config.schemas.train import validate
    from sde_torchrl.envs.ballcatch.outcomes import catch_level

    cfg = compose_config("+experiment=ballcatch_paper", "runs=2", "updates=1", "episode_queue=2",
                         "env.episode_length=5", "eval_episodes=1", "logger=none")
    build.run_job(validate(cfg), str(tmp_path), {"env": "ballcatch"})
    summary = json.loads((tmp_path / "summary.json").read_text())
    per_step = [value / 5 for value in summary["final_eval_return"]]  # the paper's learner sums rewards
    assert summary["final_eval_mean_reward"] == pytest.approx(per_step)
    assert summary["final_eval_level"] == [catch_level(value) for value in per_step]


# ---------------------------------------------------------------------------- model "pybrain" (arm.xode)
PYBRAIN_SEEDS = range(3)
PULL_BACK_WEIGHTS = np.array([[-2.0, 0, 0], [2.0, 0, 0], [0, 0, 0], [0, 0, 0]])
"""Shoulder back, elbow up (full torques, the ball's x ~ 3.5 acting as a bias): the hand leaves."""


@pytest.fixture(scope="module")
def pybrain_env():
    e = BallCatchEnv(model="pybrain")
    yield e
    e.close()


def linear_policy(weights):
    return lambda obs: np.tanh(weights @ np.asarray(obs, dtype=np.float64))


def closes(model: str, settle_steps: int, command: float) -> bool:
    """Whether a constant finger command (no arm torque), given after ``settle_steps`` steps with
    zero torques, closes every finger of an empty hand of ``model``: each first hinge past half its
    range (limits [0, 1.5]) after 90 steps, the ball released far above (60) so it stays away."""
    world = BallCatchWorld(BallCatchConfig(model=model, jitter=0.0, drop_height=60.0))
    try:
        world.reset((0.0, 0.0))
        for _ in range(settle_steps):
            world.step((0.0, 0.0, 0.0, 0.0))
        for _ in range(90):
            world.step((0.0, 0.0, 0.0, command))
        angles = world.joint_angles()
    finally:
        world.close()
    return min(angles[f"{finger}_0"] for finger in PYBRAIN_FINGERS) > 0.75


def test_pybrain_scripted_linear_controller_catches(pybrain_env):
    """Hand open while the ball falls, closed once it is below z ~ 2: a good catch every time."""
    returns = [episode_return(pybrain_env, "scripted", seed) for seed in PYBRAIN_SEEDS]
    assert min(returns) >= -1.0


def test_pybrain_zero_torques_give_the_open_hand_regime(pybrain_env):
    """The arm sinks onto the ground, the ball lands on the open palm, rolls over the fingers and
    drops: the paper's R ~ -2, neither a catch nor the worst case."""
    for seed in PYBRAIN_SEEDS:
        obs, _ = pybrain_env.reset(seed=seed)
        rewards, held, grounded = [], [], []
        for _ in range(EPISODE_STEPS):
            obs, reward, _, _, info = pybrain_env.step(np.zeros(4))
            rewards.append(reward)
            held.append(info["held"])
            grounded.append(info["grounded"])
        assert -2.5 <= np.mean(rewards) <= -1.5
        first_held, first_grounded = held.index(True), grounded.index(True)
        assert first_held < first_grounded  # on the hand first, then on the ground
        assert sum(held) >= 50  # for at least half a second


def test_pybrain_pull_back_drops_the_ball(pybrain_env):
    returns = [episode_return(pybrain_env, linear_policy(PULL_BACK_WEIGHTS), seed) for seed in PYBRAIN_SEEDS]
    assert max(returns) <= -2.8


def test_strong_fingers_keep_the_regimes_and_close_a_settled_hand_sooner():
    """The diagnostic arm with the finger actuator doubled: the scripted controller still catches,
    zero torques and pulling back do as in the shipped arm, and once the arm has sunk and its
    fingers rest on the ground a command of 0.6 closes its hand but not the shipped one."""
    env = BallCatchEnv(model="pybrain_strong_fingers")
    try:
        assert min(episode_return(env, "scripted", seed) for seed in PYBRAIN_SEEDS) >= -1.1
        assert all(-2.5 <= episode_return(env, "zero", seed) <= -1.5 for seed in PYBRAIN_SEEDS)
        assert max(episode_return(env, linear_policy(PULL_BACK_WEIGHTS), seed) for seed in PYBRAIN_SEEDS) <= -2.8
    finally:
        env.close()
    assert BallCatchConfig(model="pybrain_strong_fingers").max_torques[3] == 2 * BallCatchConfig().max_torques[3]
    assert closes("pybrain_strong_fingers", 150, 0.6) and not closes("pybrain", 150, 0.6)


def test_pybrain_same_seed_same_episode(pybrain_env):
    a, b, c = (seeded_observations(pybrain_env, seed, 5) for seed in (4, 4, 9))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[0], c[0])


def test_pybrain_masses_follow_the_densities():
    """Masses and inertias of arm.xode's solids (capsules = cylinder + two hemispheres), loaded
    from the URDF's inertia tensors; ball of radius 0.4 and density 10; ground 0.5 below the palm."""

    def capsule(density, r, length):
        cylinder, hemisphere = density * np.pi * r**2 * length, density * 2 / 3 * np.pi * r**3
        axial = cylinder * r**2 / 2 + 2 * 2 / 5 * hemisphere * r**2
        across = cylinder * (r**2 / 4 + length**2 / 12) + 2 * hemisphere * (
            2 / 5 * r**2 + length**2 / 4 + 3 * length * r / 8)
        return cylinder + 2 * hemisphere, axial, across

    world = BallCatchWorld(BallCatchConfig(model="pybrain"))
    try:
        cid, robot = world.client, world.robot
        names = {pybullet.getJointInfo(robot, j, physicsClientId=cid)[12].decode(): j
                 for j in range(pybullet.getNumJoints(robot, physicsClientId=cid))}
        expected = {"upper_arm": capsule(5, 0.3, 3.0), "forearm": capsule(5, 0.25, 3.0),
                    "index_link0": capsule(5, 0.1, 0.75), "thumb_link1": capsule(5, 0.1, 0.4)}
        for link, (mass, axial, across) in expected.items():
            info = pybullet.getDynamicsInfo(robot, names[link], physicsClientId=cid)
            assert info[0] == pytest.approx(mass, rel=1e-5)
            assert sorted(info[2]) == pytest.approx(sorted([axial, across, across]), rel=1e-5)
        palm = pybullet.getDynamicsInfo(robot, names["palm"], physicsClientId=cid)
        assert palm[0] == pytest.approx(30 * 1 * 1 * 0.2)
        last = pybullet.getDynamicsInfo(robot, names["middle_link2"], physicsClientId=cid)  # with the tip sphere
        assert last[0] == pytest.approx(capsule(5, 0.1, 0.29)[0] + 5 * 4 / 3 * np.pi * 0.1**3, rel=1e-5)
        ball = pybullet.getDynamicsInfo(world.ball, -1, physicsClientId=cid)
        assert ball[0] == pytest.approx(10 * 4 / 3 * np.pi * 0.4**3)
        assert ARM_MODELS["pybrain"].ground_z == pytest.approx(0.41)
        assert world.palm_home.tolist() == pytest.approx([3.5, 0.0, 0.5])
        assert len(world.joints) == 15  # 3 arm hinges, 4 fingers of 3 hinges
    finally:
        world.close()


def test_torques_act_on_top_of_the_friction_motors():
    """pybullet adds TORQUE_CONTROL torques to a velocity motor (target 0, max force F), which is
    how model "pybrain" has ODE's FMax joint friction: a torque below F leaves a weightless hinge
    at rest, a torque T above it accelerates the hinge as a free T - F would."""

    def spin(friction, torque):
        cid = pybullet.connect(pybullet.DIRECT)
        try:
            pybullet.setTimeStep(0.01, physicsClientId=cid)
            box = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.5, 0.05, 0.05], physicsClientId=cid)
            body = pybullet.createMultiBody(
                0, -1, -1, linkMasses=[1], linkCollisionShapeIndices=[box], linkVisualShapeIndices=[-1],
                linkPositions=[[0, 0, 0]], linkOrientations=[[0, 0, 0, 1]], linkInertialFramePositions=[[0.5, 0, 0]],
                linkInertialFrameOrientations=[[0, 0, 0, 1]], linkParentIndices=[0],
                linkJointTypes=[pybullet.JOINT_REVOLUTE], linkJointAxis=[[0, 1, 0]], physicsClientId=cid)
            pybullet.changeDynamics(body, 0, linearDamping=0, angularDamping=0, physicsClientId=cid)
            pybullet.setJointMotorControl2(body, 0, pybullet.VELOCITY_CONTROL, targetVelocity=0, force=friction,
                                           physicsClientId=cid)
            for _ in range(50):
                pybullet.setJointMotorControl2(body, 0, pybullet.TORQUE_CONTROL, force=torque, physicsClientId=cid)
                pybullet.stepSimulation(physicsClientId=cid)
            return pybullet.getJointState(body, 0, physicsClientId=cid)[1]
        finally:
            pybullet.disconnect(cid)

    assert spin(0.5, 0.4) == 0.0
    assert spin(0.5, 1.5) == pytest.approx(spin(0.0, 1.0), rel=1e-6)


def test_pybrain_batched_env_and_fast_path_match_the_gym_env():
    """The model reaches the batched env and its whole-episode path (transmission, ground height).

    Stepped with the same float32 actions, batched and gymnasium env agree exactly. The fast path
    works in float64: a ball held by the fingers is a chaotic contact problem where a 1e-7 change
    of the actions moves the return by up to about 0.02, so there it must give the same regime."""
    config = BallCatchConfig(jitter=0.0, model="pybrain")
    gym_env = BallCatchEnv(config=config)
    benv = make_ballcatch_env(2, jitter=0.0, seed=0, model="pybrain").base_env
    try:
        expected = episode_return(gym_env, lambda o: scripted_action(o, "pybrain").astype(np.float32), 0)
        with torch.no_grad():
            td = benv.rollout(EPISODE_STEPS, lambda td: td.set("action", torch.from_numpy(np.stack(
                [scripted_action(o, "pybrain").astype(np.float32) for o in td["observation"].numpy()]))))
        torch.testing.assert_close(td["next", "reward"].mean(dim=(1, 2)), torch.full((2,), expected))
        matrices = torch.as_tensor(np.stack([PYBRAIN_SCRIPTED_WEIGHTS, PULL_BACK_WEIGHTS]), dtype=torch.float32)
        observations, _, rewards = benv.linear_episodes(matrices, EPISODE_STEPS)
        catch, drop = rewards.mean(dim=(1, 2)).tolist()
        assert expected >= -1.0 and catch >= -1.0
        assert drop == pytest.approx(episode_return(gym_env, linear_policy(PULL_BACK_WEIGHTS), 0), abs=1e-6)
        assert observations[1, -1, 2] < ARM_MODELS["pybrain"].ground_z < observations[0, -1, 2]
    finally:
        gym_env.close()
        benv.close()


def test_model_option_reaches_gymnasium_and_is_checked():
    e = gym.make(BALLCATCH_ID, model="pybrain")
    try:
        assert e.unwrapped.config.model == "pybrain"
        assert e.unwrapped.config.max_torques == ARM_MODELS["pybrain"].max_torques
    finally:
        e.close()
    with pytest.raises(ValueError, match="model must be one of pybrain, cup"):
        BallCatchConfig(model="ode")
    with pytest.raises(ValueError, match="contradicts"):
        BallCatchEnv(config=BallCatchConfig(), model="cup")


@pytest.mark.e2e
def test_config_knows_the_arm_models_and_passes_the_choice_to_the_env(tmp_path):
    """``env.model`` (checked against a copy of the model names: config.py imports no pybullet)
    reaches the batched env that ``train.py`` builds."""
    from _helpers import compose_config, run_cli

    from sde_torchrl.config import build
    from sde_torchrl.config.schemas import envs as config

    assert config.ARM_MODELS == tuple(ARM_MODELS)
    cfg = compose_config("+experiment=ballcatch_reinforce", "env.model=pybrain", "runs=1", "updates=1",
                         "episode_queue=2", "env.episode_length=5", "eval_episodes=1", "logger=none")
    trainer = build.build_trainer(cfg)
    try:
        assert {env.base_env.config.model for env in (trainer.env, trainer.eval_env)} == {"pybrain"}
    finally:
        trainer.close()
    result = run_cli("+experiment=ballcatch_reinforce", "env.model=pybrain", "runs=1", "updates=2", "episode_queue=2",
                     "env.episode_length=20", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    bad = run_cli("+experiment=ballcatch_reinforce", "env.model=ode", "runs=1", "updates=1", run_dir=tmp_path / "bad")
    assert bad.returncode != 0
    assert "env.model=ode: one of pybrain, cup, pybrain_held, pybrain_strong_fingers" in bad.stderr


def test_reset_after_close_names_the_problem():
    env = BallCatchEnv()
    env.reset(seed=0)
    env.close()
    with pytest.raises(RuntimeError, match="is closed .*make a new env"):
        env.reset(seed=0)


def test_a_dropped_world_frees_its_physics_client():
    import gc

    from sde_torchrl.envs.ballcatch.world import BallCatchWorld

    world = BallCatchWorld()
    client = world.client
    assert pybullet.isConnected(physicsClientId=client)
    del world
    gc.collect()
    assert not pybullet.isConnected(physicsClientId=client)
