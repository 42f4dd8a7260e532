"""Every tensor the library makes is made on the data's device.

Three kinds of test:

- training end to end on each device present (``cpu`` always; ``cuda`` where there is one,
  skipped with its reason where not);
- the same code paths on PyTorch's ``meta`` device, which carries shapes and devices but no
  data: an op mixing a meta tensor with a non-scalar CPU tensor fails ("Tensor on device cpu is
  not on the expected device meta"), and the tests check that every output is on ``meta``, so a
  module that makes a CPU tensor of its own is caught here, without a GPU. What cannot run on
  ``meta`` (anything that reads values: the estimators' input checks, ENAC's least squares, which
  has no meta kernel, ``bool(...)`` guards) is said where it is left out;
- ``device=cuda`` on a machine without CUDA: one line, exit code 2, before any work.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import pytest
import torch
from _helpers import Crash, build, crash_at, own_stderr_lines, read_rows, run_cli
from tensordict import TensorDict

from sde_torchrl import LinearActor, SDEParams, make_sde_actor
from sde_torchrl.collectors.rollout import episode_matrix, noise_primer, tensor_rollout
from sde_torchrl.config.schemas.train import TrainConf
from sde_torchrl.envs.minimize import make_minimize_env
from sde_torchrl.modules.actors import MLPActor
from sde_torchrl.modules.distribution import SDENormal, TanhSDENormal, sde_sample, sde_variance
from sde_torchrl.modules.noise import SDENoisePrimer, draw_noise
from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.objectives.estimators import (
    EpisodeLogLikelihood,
    enac_gradient,
    episode_scores,
    gpomdp_gradient,
    reinforce_gradient,
)
from sde_torchrl.trainers.summary import exploration_state
from sde_torchrl.utils.checks import ArgumentError
from sde_torchrl.utils.devices import check_device_name, training_device
from sde_torchrl.utils.nonfinite import nonfinite_policy
from sde_torchrl.utils.rng import RunStreams

META = torch.device("meta")
NO_CUDA = "no CUDA device here (torch.cuda.is_available() is False)"
DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA))]


def devices_of(td) -> set[str]:
    """The device types of every leaf of a TensorDict."""
    return {value.device.type for value in td.values(include_nested=True, leaves_only=True)}


def sde_policy(*, squash=False, gaussian=None, mlp=False, runs=2, action_dim=2, feature_dim=3, device=META):
    """An SDE policy on ``device`` (runs stacked) and its primer drawing from per-run streams."""
    sde = SDEParams(action_dim, feature_dim, runs=runs, gaussian_init_param=gaussian)
    sde.streams = RunStreams(0, runs, "explore")
    actor = (MLPActor(feature_dim, action_dim, runs=runs) if mlp
             else LinearActor(feature_dim, action_dim, runs=runs, init=-0.5))
    policy = make_sde_actor(actor, sde, squash=squash, low=-1.0, high=1.0).to(device)
    return policy, sde.make_tensordict_primer()


# ------------------------------------------------------------------------------ on every device
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("overrides", [
    ("estimator=reinforce",),
    ("estimator=enac", "episode_queue=4", "explorer.squash=true"),  # ENAC solves on the CPU; the queue
    ("tensor_rollout=false", "explorer=every_n", "explorer.every_n=2"),  # env.rollout with the primer
], ids=["reinforce", "enac_queue_squash", "env_rollout_every_n"])
def test_training_runs_on_the_device(device, overrides, tmp_path):
    settings = (f"device={device}", "updates=4", "episodes_per_update=2", "eval_period=2", "checkpoint_period=2")
    trainer = build(*settings, *overrides)
    assert {p.device.type for p in trainer.policy.parameters()} == {device}
    assert devices_of(trainer.collect()) == {device}
    crash_at(trainer, 3)
    with pytest.raises(Crash):
        trainer.train(tmp_path)
    summary = build(*settings, *overrides).train(tmp_path)  # resumed from the checkpoint (read onto the CPU)
    assert summary["updates_done"] == 4 and len(read_rows(tmp_path)) == 4 * summary["runs"]
    assert all(map(math.isfinite, summary["final_return"] + summary["final_eval_return"]))


@pytest.mark.parametrize("device", DEVICES)
def test_training_device_is_checked_against_the_machine(device):
    assert training_device(device) == torch.device(device)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA: the refusal needs a machine without")
def test_cuda_is_refused_without_cuda_before_anything_is_built():
    with pytest.raises(ArgumentError, match=r"^device=cuda: this machine has no CUDA device .*run with device=cpu$"):
        build("device=cuda")


def test_device_names_are_checked_by_the_schema_without_torch():
    assert TrainConf().device == "cpu"
    for bad in ("gpu", "meta", "cuda:x", 1):
        with pytest.raises(ArgumentError, match=r"^device="):
            TrainConf(device=bad)
    assert check_device_name("cuda:3") == "cuda:3"  # the form only; the machine is asked when building


# ------------------------------------------------------------------------------ on meta
@pytest.mark.parametrize("squash", [False, True])
@pytest.mark.parametrize("gaussian", [None, -1.0])
@pytest.mark.parametrize("mlp", [False, True])
def test_policy_forward_on_meta_makes_nothing_on_the_cpu(squash, gaussian, mlp):
    policy, primer = sde_policy(squash=squash, gaussian=gaussian, mlp=mlp)
    noise, eps, _ = primer.start((2, 4), META)
    td = TensorDict({"observation": torch.randn(2, 4, 3, device=META), "sde_noise": noise}, [2, 4])
    if eps is not None:
        td["sde_gaussian_noise"] = eps
    out = policy(td)
    assert devices_of(out) == {"meta"}
    assert out["action"].shape == (2, 4, 2) and out["action_log_prob"].shape == (2, 4)


@pytest.mark.parametrize("schedule, every_n", [("episode", None), ("step", None), ("every_n", 3)])
def test_primer_draws_on_meta(schedule, every_n):
    primer = SDENoisePrimer(2, 3, schedule=schedule, every_n=every_n, gaussian=True,
                            streams=RunStreams(0, 2, "explore"))
    state = primer.start((2, 5), META)
    for _ in range(4):
        state = primer.advance(*state)
    assert {t.device.type for t in state if t is not None} == {"meta"}
    assert draw_noise((2, 3), RunStreams(0, 2, "explore"), device=META).device == META
    assert draw_noise((2, 3), device=META).device == META  # torch's global generator


def test_distributions_on_meta():
    loc, x = torch.zeros(6, 2, device=META), torch.ones(6, 3, device=META)
    sigma, noise = torch.full((2, 3), 0.5, device=META), torch.randn(6, 2, 3, device=META)
    scale, eps = torch.ones(6, 2, device=META), torch.randn(6, 2, device=META)
    assert sde_sample(loc, sigma, noise, x, scale, eps).device == META
    assert sde_variance(sigma, x, scale).device == META
    assert sde_variance(sigma.expand(4, 2, 3), x[:4], run_dims=1).device == META
    dist = SDENormal(loc, sigma, x, noise, scale, eps)
    drawn = dist.rsample((5,))  # fresh draws: made here, on the data's device
    for value in (dist.rsample(), drawn, dist.log_prob(drawn), dist.entropy(), dist.stddev):
        assert value.device == META
    tanh = TanhSDENormal(loc, sigma, x, noise, low=-2.0, high=torch.tensor([2.0, 3.0]))
    action, log_prob = tanh.rsample_and_log_prob((3,))
    assert {action.device, log_prob.device, tanh.log_prob(action).device, tanh.deterministic_sample.device} == {META}


def test_estimator_functions_on_meta():
    scores, returns = torch.randn(2, 8, 5, device=META), torch.randn(2, 8, device=META)
    assert {t.device for t in reinforce_gradient(scores, returns)} == {META}
    step_scores, rewards = torch.randn(2, 8, 4, 5, device=META), torch.randn(2, 8, 4, device=META)
    assert {t.device for t in gpomdp_gradient(step_scores, rewards)} == {META}


def test_episode_scores_on_meta():
    """The per-episode scores (``torch.func`` over the policy's likelihood) of meta episodes."""
    policy, _ = sde_policy(squash=True, mlp=True, action_dim=3)
    env = make_minimize_env(4, episodes=3, runs=2, dim=3, device="meta")
    env.append_transform(policy.sde.make_tensordict_primer())
    with nonfinite_policy("guarded"):  # meta tensors have no values to check
        episodes = tensor_rollout(env.base_env, policy, 4, noise_primer(env))
    scores = episode_scores(EpisodeLogLikelihood(policy), episodes)
    assert {s.device for s in scores.values()} == {META}
    assert {s.shape[:2] for s in scores.values()} == {(2, 3)}  # [runs, episodes, ...]


def test_enac_gradient_returns_on_the_scores_device():
    """ENAC's least squares (``gelsd``) has no meta kernel and reads values (its finite check):
    it is solved on the CPU whatever the device, and its results are put back on the scores'
    device. Here only the CPU round trip; on CUDA, ``test_training_runs_on_the_device``."""
    with pytest.raises((NotImplementedError, RuntimeError)):
        enac_gradient(torch.randn(2, 8, 5, device=META), torch.randn(2, 8, device=META))
    out = enac_gradient(torch.randn(2, 8, 5), torch.randn(2, 8))
    assert {t.device.type for t in out} == {"cpu"} and out[0].shape == (2, 5)


@pytest.mark.parametrize("squash", [False, True])
@pytest.mark.parametrize("schedule", ["episode", "step", "every_n"])
@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_tensor_rollout_on_meta(squash, schedule, gaussian):
    """The fast collection path on a meta minimisation env: every entry of the episodes (the
    ``done`` and ``is_init`` flags it builds itself among them) is on meta."""
    sde = SDEParams(2, 2, runs=2, schedule=schedule, every_n=2 if schedule == "every_n" else None,
                    gaussian_init_param=gaussian)
    sde.streams = RunStreams(0, 2, "explore")
    policy = make_sde_actor(LinearActor(2, 2, runs=2), sde, squash=squash, low=-1.0, high=1.0).to(META)
    env = make_minimize_env(5, episodes=3, runs=2, dim=2, device="meta")
    env.append_transform(sde.make_tensordict_primer())
    with nonfinite_policy("guarded"):  # meta tensors have no values to check
        episodes = tensor_rollout(env.base_env, policy, 5, noise_primer(env))
    assert episodes.batch_size == (2, 3, 5)
    assert devices_of(episodes) == {"meta"}


@pytest.mark.parametrize("schedule", ["episode", "step"])
def test_episode_matrix_on_meta(schedule):
    sde = SDEParams(4, 3, runs=2, schedule=schedule)
    sde.streams = RunStreams(0, 2, "explore")
    sde.to(META)
    matrix, noise = episode_matrix(sde.make_tensordict_primer(), sde, torch.zeros(2, 4, 3, device=META),
                                   torch.Size([2, 5]), 6)
    assert matrix.device == META and noise.device == META


def test_minimize_env_steps_on_meta():
    """The env's own tensor functions (TorchRL's ``reset``/``step`` read values: not on meta)."""
    env = make_minimize_env(5, episodes=3, runs=2, device="meta").base_env
    x = env.initial_state()
    with nonfinite_policy("guarded"):  # meta tensors have no values to check
        x_next, reward = env.transition(x, torch.zeros_like(x))
        assert {x.device, x_next.device, reward.device} == {META}
        assert devices_of(env._step(TensorDict({"observation": x, "action": x}, env.batch_size))) == {"meta"}


def test_pgpe_draws_on_meta():
    actor = LinearActor(3, 2, runs=2)
    explorer = ParameterExplorer(actor, runs=2)
    explorer.streams = RunStreams(0, 2, "explore")
    explorer.to(META)
    assert explorer.next_noise(None, None, torch.Size([2, 4])).device == META


def test_exploration_state_on_meta():
    policy, _ = sde_policy()
    assert exploration_state(policy, 2).device == META
    no_explorer = torch.nn.Linear(3, 2).to(META)  # its σ entries are NaN, made here
    assert exploration_state(no_explorer, 2).device == META


# ------------------------------------------------------------------------------ the command line
@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA: the refusal needs a machine without")
def test_device_cuda_without_cuda_fails_in_one_line_before_any_work(tmp_path):
    cases = {"cuda": "device=cuda", "meta": "device=meta"}
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {name: pool.submit(run_cli, "+experiment=minimize", override, run_dir=tmp_path / name)
                   for name, override in cases.items()}
        results = {name: future.result() for name, future in futures.items()}
    expected = {"cuda": "error: device=cuda: this machine has no CUDA device (torch.cuda.is_available() is False); "
                        "run with device=cpu",
                "meta": "error: device=meta: cpu, cuda or cuda:N (meta holds no data: it is for tests)"}
    for name, result in results.items():
        assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
        assert own_stderr_lines(result.stderr) == [expected[name]], name
        assert "Traceback" not in result.stdout
        written = {p.relative_to(tmp_path / name).parts[0] for p in (tmp_path / name).rglob("*") if p.is_file()}
        # besides error.txt, only what any job writes before its config is checked: the lock, the
        # saved config (.hydra) and the log holding the error line; no metrics, checkpoint, summary
        assert written <= {"error.txt", ".hydra", ".lock", "train.log"}, (name, written)
        assert "error.txt" in written
    assert "build_env" not in (tmp_path / "cuda" / "error.txt").read_text()  # refused before the envs
