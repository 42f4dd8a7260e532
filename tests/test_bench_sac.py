"""analysis/benchmarks/bench_sac/: tiny runs of both sides, the SAC losses' SDE noise, the report."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from _helpers import REPO
from tensordict import TensorDict

from analysis.benchmarks.bench_sac import build, cli, report, train
from sde_torchrl.modules.sac_actor import CLIP_MEAN
from sde_torchrl.trainers import compiler
from sde_torchrl.trainers.sac import fresh_loss_noise


def _action_spec():
    from torchrl.data import Bounded

    return Bounded(-1.0, 1.0, shape=(1,))


def _sde_setup(loss_noise: str, seed: int = 0, compile_update: bool = False):
    torch.manual_seed(seed)
    zoo = build.ZOO["mountaincar"]
    policy, critic, sde = build.make_torchrl_policy("sde", 2, _action_spec(), zoo)
    loss = build.make_loss(policy, critic, _action_spec(), zoo)
    return loss, sde, train.make_update(loss, sde, zoo, loss_noise, compile_update)


def _transitions(n: int, stored_noise: torch.Tensor) -> TensorDict:
    torch.manual_seed(1)
    return TensorDict({
        "observation": torch.randn(n, 2), "action": torch.rand(n, 1) * 2 - 1, "sde_noise": stored_noise.clone(),
        "next": {"observation": torch.randn(n, 2), "reward": torch.randn(n, 1), "sde_noise": stored_noise.clone(),
                 "done": torch.zeros(n, 1, dtype=torch.bool), "terminated": torch.zeros(n, 1, dtype=torch.bool)},
    }, [n])


def _parameters(loss) -> TensorDict:
    return TensorDict.from_module(loss).detach().clone()


def test_the_sac_losses_draw_fresh_noise_not_the_stored_one():
    """Stored ξ set to NaN: the update must not read it (it would turn every parameter it reaches into NaN)."""
    n = 64
    loss, _, update = _sde_setup("fresh")
    before = _parameters(loss)
    update(_transitions(n, torch.full((n, 1, 64), float("nan"))))
    after = _parameters(loss)
    assert all(torch.isfinite(v).all() for v in after.values(True, True))
    assert max((after - before).abs().max().values(True, True)) > 1e-5  # the step did move the parameters
    # the control: the same update with the stored noise does read it
    loss, _, update = _sde_setup("stored")
    update(_transitions(n, torch.full((n, 1, 64), float("nan"))))
    assert any(torch.isnan(v).any() for v in _parameters(loss)["actor_network_params"].values(True, True))


@pytest.mark.e2e  # compiles the SAC update with inductor (the slowest test of the fast loop it was in)
def test_the_compiled_update_equals_the_eager_one():
    """``run --compile`` changes how the gradient step runs, not what it computes (stored ξ: no RNG inside).

    Compiled as in a run, by inductor: a partitioner that AOTAutograd's ``aot_eager`` backend ran
    correctly gave a wrong critic gradient under inductor (a sign-flipped Adam step in the critic's
    last layer), and its runs did not learn.
    """
    stored = torch.randn(32, 1, 64)
    after = {}
    for compile_update in (False, True):
        loss, _, update = _sde_setup("stored", compile_update=compile_update)
        for _ in range(2):  # the second step reads the first one's Adam state and target critics
            update(_transitions(32, stored))
        after[compile_update] = _parameters(loss)
    moved = (after[False] - _parameters(_sde_setup("stored")[0])).abs().max().values(True, True)
    assert max(moved) > 1e-5  # the steps did move the parameters
    for key, value in after[False].items(True, True):
        torch.testing.assert_close(after[True][key], value, rtol=1e-4, atol=1e-5, msg=str(key))


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


def test_fresh_noise_is_one_matrix_per_gradient_step_shared_by_the_batch_and_the_next_states():
    """SB3's ``actor.reset_noise()`` before each gradient step: one exploration matrix for every row."""
    _, sde, _ = _sde_setup("fresh")
    first, second = _transitions(8, torch.zeros(8, 1, 64)), _transitions(8, torch.zeros(8, 1, 64))
    fresh_loss_noise(first, sde)
    fresh_loss_noise(second, sde)
    noise = first["sde_noise"]
    assert noise.shape == (8, 1, 64) and torch.equal(noise, noise[:1].expand_as(noise))
    assert torch.equal(first["next", "sde_noise"], noise)
    assert noise.std() > 0.5 and not torch.equal(second["sde_noise"], noise)


def test_the_sde_actor_is_sb3s_sac_gsde_actor():
    """Mean clipped to ±2 before the squash, features not detached, σ̂ per element, p = log_std_init."""
    _, sde, _ = _sde_setup("fresh")
    assert sde.sigma_param.shape == (1, 64) and torch.allclose(sde.sigma_param, torch.tensor(-3.67))
    assert sde.schedule == "every_n" and sde.every_n == build.ZOO["mountaincar"]["train_freq"]
    policy = build.make_torchrl_policy("sde", 2, _action_spec(), build.ZOO["mountaincar"])[0]
    td = policy(TensorDict({"observation": torch.full((4, 2), 1e4), "sde_noise": torch.zeros(4, 1, 64)}, [4]))
    assert td["loc"].abs().max() <= CLIP_MEAN
    assert td["sde_features"].requires_grad  # gSDE's learn_features=True in SB3's SAC


@pytest.mark.parametrize("method", ["sde", "sb3"])
def test_a_tiny_run_writes_its_result(tmp_path, method):
    path = train.run(method, "mountaincar", 3, 64, tmp_path, eval_episodes=1)
    assert path.name == f"mountaincar_{method}_seed3.json"
    data = json.loads(path.read_text())
    assert data["env_steps"] == 64 and data["gradient_steps"] == 64  # 32 after each of 2 collections
    assert len(data["eval_returns"]) == 1 and np.isfinite(data["eval_returns"]).all()
    assert data["final_return_mean"] == pytest.approx(np.mean(data["eval_returns"]))
    assert data["env_steps_per_s"] == pytest.approx(64 / data["wall_s"])
    assert data["settings"]["log_std_init"] == -3.67 and data["env_id"] == "MountainCarContinuous-v0"
    if method == "sde":  # a round of 32 gradient steps after each of the 2 collections
        assert len(data["update_rounds_s"]) == 2 and all(w > 0 and c > 0 for w, c in data["update_rounds_s"])


@pytest.mark.parametrize("argv, message", [
    (["run", "--method", "sb3", "--loss-noise", "stored"], "--loss-noise applies to"),
    (["run", "--method", "sde", "--steps", "0"], "--steps must be positive"),
    (["run", "--method", "sde", "--eval-episodes", "0"], "--eval-episodes must be positive"),
    (["run", "--method", "sde", "--env", "pendulum"], "invalid choice"),
    (["run", "--method", "sde", "--steps", "100", "--learning-starts", "100"], "--learning-starts must be in"),
    (["update-speed", "--updates", "0"], "--updates and --rounds must be positive"),
    (["speed", "job", "sb3", "--rounds", "4"], "--rounds must be at least 5"),
    (["speed", "job", "--repeats", "0"], "--repeats at least 1"),
    (["run", "--method", "sb3", "--compile"], "--compile applies to the TorchRL methods"),
    (["run", "--method", "sde", "--compile", "--loss-noise", "stored"], "--compile runs the fresh loss noise only"),
    (["run", "--method", "sde", "--compile-policy"], "--compile-policy goes with --compile"),
])
def test_bad_command_lines_are_refused_by_name(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_the_speed_job_variant_times_the_sac_jobs_own_rounds():
    """``bench_sac speed job``: ``+experiment=sac_mountaincar``'s trainer, one round (32 env steps,
    32 gradient steps) an update, each round's end in wall and CPU seconds."""
    from analysis.benchmarks.bench_sac.speed import job_rounds

    ends = np.asarray(job_rounds(4, ("algorithm.compile=false", "algorithm.batch_size=64")))
    assert ends.shape == (4, 2) and (np.diff(ends[:, 0]) > 0).all() and (ends[:, 1] > 0).all()


def _fake_run(folder, env, method, seed, final, speed, loss_noise=None, compiled=False, compiled_policy=False):
    curve = [[1000 * (k + 1), final * k / 14] for k in range(15)]
    suffix = "_stored_noise" if loss_noise == "stored" else "_compiled" * compiled + "_policy" * compiled_policy
    name = f"{env}_{method}{suffix}_seed{seed}.json"
    (folder / name).write_text(json.dumps(
        {"method": method, "env": env, "seed": seed, "settings": build.ZOO[env], "env_steps": 15_000, "curve": curve,
         "final_return_mean": final,
         "env_steps_per_s": speed, "env_steps_per_cpu_s": 1.5 * speed, "wall_s": 15_000 / speed,
         "eval_returns": [final], "loss_noise": loss_noise, "compiled": compiled, "compiled_policy": compiled_policy,
         # 15 rounds of 1 s; compiled: the first takes 1,000 / 6 s more
         "update_rounds_s": [[1.0 + (15_000 / speed / 6 if compiled and k == 0 else 0.0), 1.0] for k in range(15)]}))


def test_report_gives_means_spreads_and_the_ratios_to_sb3(tmp_path):
    for seed, (sde, sb3) in enumerate([(80, 90), (90, 100), (100, 110)]):
        _fake_run(tmp_path, "mountaincar", "sde", seed, sde, 40)
        _fake_run(tmp_path, "mountaincar", "sb3", seed, sb3, 80)
        _fake_run(tmp_path, "mountaincar", "plain", seed, -1.0, 45)
        _fake_run(tmp_path, "mountaincar", "sb3_gauss", seed, -2.0, 90)
        _fake_run(tmp_path, "mountaincar", "sde", seed, sde, 72, compiled=True)  # a row of its own, beside eager
        _fake_run(tmp_path, "mountaincar", "sde", seed, sde, 76, compiled=True, compiled_policy=True)  # and another
    _fake_run(tmp_path, "mountaincar", "sde", 0, -1e6, 40, loss_noise="stored")  # the ablation: a row of its own
    _fake_run(tmp_path, "halfcheetah", "sde", 0, 500, 20)
    _fake_run(tmp_path, "halfcheetah", "sb3", 0, 600, 30)
    page = report.report(tmp_path, tmp_path / "out")
    # the fake curves end at the final return: the last quarter's episodes (> 11,250 steps) average 11/14 .. 14/14 of it
    late = [np.mean([final * k / 14 for k in (11, 12, 13, 14)]) for final in (80, 90, 100)]
    assert (f"| TorchRL SAC, SDE (ours) | 3 | 15,000 | 90.0 ± 10.0 | 80.0, 90.0, 100.0 | {np.mean(late):.1f} ± "
            f"{np.std(late, ddof=1):.1f} | {', '.join(f'{v:.1f}' for v in late)} | 40 | 60 | 375 |") in page
    assert "SDE / SB3 gSDE: final return 0.90×" in page and "env steps per second 0.50× [0.50, 0.50]" in page
    assert "late training return 0.90×" in page
    assert "| TorchRL SAC, SDE (ours), compiled update | 3 | 15,000 | 90.0 ± 10.0 |" in page
    assert "SDE, compiled update / SB3 gSDE: final return 0.90×" in page
    assert "env steps per second 0.90× [0.90, 0.90] (target ≥ 0.8)" in page
    # 15,000 steps at 72/s is 208 s, of which 35 s compile: without them 86.4/s, 1.08× SB3's 80
    assert "without the compilation (35 s a run) 1.08× [1.08, 1.08]" in page
    assert "| TorchRL SAC, SDE (ours), compiled update and policy forward | 3 | 15,000 | 90.0 ± 10.0 |" in page
    assert "SDE, compiled update and policy forward / SB3 gSDE: final return 0.90×" in page
    assert "env steps per second 0.95× [0.95, 0.95] (target ≥ 0.8)" in page
    assert "| ablation: TorchRL SAC, SDE, stored ξ in the losses | 1 | 15,000 | -1000000.0 ± 0.0 |" in page
    assert "env steps per CPU second 0.50× [0.50, 0.50]" in page
    # returns that are not both positive: the difference, not a ratio
    assert "Gaussian / SB3 Gaussian: final return difference (ours − SB3) 1.00 [1.00, 1.00]" in page
    assert ("Zoo settings (both sides; use_sde as the method says): learning_rate=0.0003, buffer_size=50000, "
            "batch_size=512, ent_coef=0.1") in page
    assert page.index("## MountainCarContinuous-v0") < page.index("## HalfCheetahBulletEnv-v0")
    assert "| SB3 SAC, gSDE | 1 | 15,000 | 600.0 ± 0.0 | 600.0 | 535.7 ± 0.0 | 535.7 | 30 | 45 | 500 |" in page
    stats = json.loads((tmp_path / "out" / "bench_sac.json").read_text())
    ratio = stats["mountaincar"]["sde_over_sb3"]["final"]
    assert ratio["estimate"] == pytest.approx(90 / 100) and ratio["low"] < ratio["estimate"] < ratio["high"]
    assert stats["mountaincar"]["plain_over_sb3_gauss"]["final_difference"]["estimate"] == pytest.approx(1.0)
    assert "sde_over_sb3" not in stats["halfcheetah"]
    assert (tmp_path / "out" / "bench_sac.png").stat().st_size > 0


def test_report_without_runs_says_what_to_run(tmp_path):
    with pytest.raises(SystemExit, match="analysis.benchmarks.bench_sac run"):
        report.report(tmp_path, tmp_path / "out")


def test_the_actor_loss_equals_sb3s_with_the_same_weights_and_noise_matrix():
    """Our SDE actor loss (SACLoss) and SB3's SAC + gSDE actor loss, same weights, same exploration matrix."""
    from stable_baselines3 import SAC

    zoo = build.ZOO["mountaincar"]
    model = SAC("MlpPolicy", "MountainCarContinuous-v0", use_sde=True, ent_coef=zoo["ent_coef"], seed=0, device="cpu",
                policy_kwargs={"log_std_init": zoo["log_std_init"], "net_arch": zoo["net_arch"]})
    actor, critic = model.actor, model.critic
    loss, sde, _ = _sde_setup("fresh")
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
    obs = torch.randn(n, 2)
    actor.action_dist.exploration_mat = actor.action_dist.get_std(actor.log_std) * eps
    actions, log_prob = actor.action_log_prob(obs)
    q_pi = torch.cat(critic(obs, actions), dim=1).min(dim=1, keepdim=True)[0]
    sb3_loss = (zoo["ent_coef"] * log_prob.reshape(-1, 1) - q_pi).mean()
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


def test_evaluation_counts_each_envs_first_episode_only():
    """Bang-bang on the velocity's sign reaches the goal in about 100 steps; the envs then reset and go on."""
    from tensordict.nn import TensorDictModule

    def bang_bang(observation):
        return torch.where(observation[..., 1:] >= 0, 1.0, -1.0)

    policy = TensorDictModule(bang_bang, in_keys=["observation"], out_keys=["action"])
    returns = train.evaluate_torchrl(policy, "MountainCarContinuous-v0", seed=0, episodes=3)
    assert len(returns) == 3 and all(85 < r < 100 for r in returns)  # +100 at the goal, -0.1 per full-thrust step


@pytest.mark.parametrize("page", ["sac", "sac/zoo_budget"])
def test_the_committed_page_is_what_report_writes_from_the_committed_runs(tmp_path, page):
    """bench_sac.md and .json (8,000 steps; the zoo's budget): regenerated from their runs/, they come out identical."""
    folder = REPO / "docs" / page
    assert cli.main(["report", str(REPO / "results" / page / "runs"), "--out", str(tmp_path)]) == 0
    for name in ("bench_sac.md", "bench_sac.json"):
        assert (tmp_path / name).read_text() == (folder / name).read_text(), name
