"""analysis/benchmarks/gsde_table/: the cells, the SB3 settings read off our composed configs (set
beside rl-baselines3-zoo's entries), the folder's fraction, the paper's table, the report's
comparisons, and one tiny cell run on both sides and reported."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from _helpers import REPO

from analysis.benchmarks.gsde_table import cli, report, run, sb3
from analysis.benchmarks.gsde_table.cells import (
    ALGORITHMS,
    ENVS,
    EXPERIMENTS,
    NOISES,
    Cell,
    cells,
    compose_cell,
    steps_per_update,
    train_overrides,
    updates_for,
)
from analysis.benchmarks.gsde_table.paper import PAPER

# rl-baselines3-zoo, hyperparams/ppo.yml, HalfCheetahBulletEnv-v0 (the pybullet-defaults anchor);
# Ant: log_std_init=-1; Hopper and Walker2D: clip_range lin_0.4.
ZOO_PPO = {
    "n_steps": 512, "batch_size": 128, "gamma": 0.99, "gae_lambda": 0.9, "n_epochs": 20, "ent_coef": 0.0,
    "sde_sample_freq": 4, "max_grad_norm": 0.5, "vf_coef": 0.5, "learning_rate": 3e-5, "use_sde": True,
    "clip_range": 0.4,
}
ZOO_PPO_POLICY = {"log_std_init": -2, "ortho_init": False, "activation_fn": "ReLU",
                  "net_arch": {"pi": [256, 256], "vf": [256, 256]}}
# hyperparams/a2c.yml, HalfCheetahBulletEnv-v0 (the same for the four envs): TimeFeatureWrapper,
# normalize, 4 envs; SB3's defaults: MlpPolicy 2 × 64 tanh, sde_sample_freq -1, rms_prop_eps 1e-5.
ZOO_A2C = {
    "ent_coef": 0.0, "max_grad_norm": 0.5, "n_steps": 8, "gae_lambda": 0.9, "vf_coef": 0.4, "gamma": 0.99,
    "use_rms_prop": True, "normalize_advantage": False, "learning_rate": "lin_0.00096", "use_sde": True,
    "sde_sample_freq": -1, "rms_prop_eps": 1e-5,
}
ZOO_A2C_POLICY = {"log_std_init": -2, "ortho_init": False, "activation_fn": "Tanh",
                  "net_arch": {"pi": [64, 64], "vf": [64, 64]}}
# hyperparams/sac.yml, HalfCheetahBulletEnv-v0 (pybullet-defaults); Hopper, Walker2D: lin_7.3e-4.
ZOO_SAC = {
    "learning_rate": 7.3e-4, "buffer_size": 300_000, "batch_size": 256, "ent_coef": "auto", "gamma": 0.98,
    "tau": 0.02, "train_freq": 8, "gradient_steps": 8, "learning_starts": 10_000, "use_sde": True,
    "sde_sample_freq": -1,
}
ZOO_SAC_POLICY = {"log_std_init": -3, "net_arch": [400, 300], "activation_fn": "ReLU"}


def settings_of(algorithm: str, env: str, noise: str = "sde", fraction: float = 1.0, extra=()):
    conf, _ = compose_cell(Cell(algorithm, env, noise, 0), fraction, extra)
    return sb3.sb3_settings(conf)


def rate(setting) -> tuple[str, float]:
    """A rate in the zoo's notation as (schedule, value): ``lin_7.3e-4`` and ``lin_0.00073`` alike."""
    if isinstance(setting, str):
        return "linear", float(setting.removeprefix("lin_"))
    return "constant", float(setting)


def assert_zoo(settings: dict, zoo: dict, zoo_policy: dict) -> None:
    kwargs = dict(settings["kwargs"])
    for key in ("learning_rate", "clip_range"):
        if key in zoo:
            assert rate(kwargs.pop(key)) == rate(zoo[key]), key
    assert {k: kwargs[k] for k in zoo if k not in ("learning_rate", "clip_range")} == \
        {k: v for k, v in zoo.items() if k not in ("learning_rate", "clip_range")}
    policy = kwargs["policy_kwargs"]
    assert {k: policy[k] for k in zoo_policy} == zoo_policy


@pytest.mark.parametrize("env", ENVS)
def test_ppo_cells_map_to_the_zoo_entries(env):
    settings = settings_of("ppo", env)
    zoo = {**ZOO_PPO, "clip_range": "lin_0.4" if env in ("hopper", "walker2d") else 0.4}
    assert_zoo(settings, zoo, {**ZOO_PPO_POLICY, "log_std_init": -1 if env == "ant" else -2})
    assert settings["algorithm"] == "PPO"
    assert settings["kwargs"]["policy_kwargs"]["optimizer_kwargs"]["eps"] == 1e-5  # SB3's PPO Adam eps
    assert settings["kwargs"]["normalize_advantage"] is True
    assert settings["env"] == {"id": f"pybullet_envs_gymnasium:{ENV_NAMES[env]}",
                               "gym_kwargs": {"max_episode_steps": None}, "episode_length": 1000, "n_envs": 16,
                               "time_feature": False, "normalize": True,
                               "gamma": 0.99}
    assert settings["total_timesteps"] == 245 * 8192  # the first update past the zoo's 2M
    assert settings["eval"] == {"period_steps": 10 * 8192, "episodes": 10}


ENV_NAMES = {"halfcheetah": "HalfCheetahBulletEnv-v0", "ant": "AntBulletEnv-v0", "hopper": "HopperBulletEnv-v0",
             "walker2d": "Walker2DBulletEnv-v0"}


@pytest.mark.parametrize("env", ENVS)
def test_a2c_cells_map_to_the_zoo_entries_with_the_time_feature(env):
    settings = settings_of("a2c", env)
    assert_zoo(settings, ZOO_A2C, ZOO_A2C_POLICY)
    assert settings["env"]["time_feature"] and settings["env"]["normalize"] and settings["env"]["n_envs"] == 4
    assert settings["total_timesteps"] == 2_000_000


@pytest.mark.parametrize("env", ENVS)
def test_sac_cells_map_to_the_zoo_entries(env):
    settings = settings_of("sac", env)
    zoo = {**ZOO_SAC, "learning_rate": "lin_7.3e-4" if env in ("hopper", "walker2d") else 7.3e-4}
    assert_zoo(settings, zoo, ZOO_SAC_POLICY)
    assert not settings["env"]["time_feature"] and not settings["env"]["normalize"]
    assert settings["kwargs"]["policy_kwargs"]["optimizer_kwargs"]["eps"] == 1e-8  # torch's Adam default, as SB3's SAC
    assert "full_std" not in settings["kwargs"]["policy_kwargs"]  # SAC's policy takes none
    assert settings["total_timesteps"] == 1_000_000 and settings["eval"]["period_steps"] == 20_000


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_the_gaussian_side_differs_only_by_use_sde(algorithm):
    sde, gaussian = settings_of(algorithm, "walker2d"), settings_of(algorithm, "walker2d", "gaussian")
    assert gaussian["kwargs"]["use_sde"] is False and "sde_sample_freq" not in gaussian["kwargs"]
    sde_only = {"use_sde", "sde_sample_freq"}
    assert {k: v for k, v in sde["kwargs"].items() if k not in sde_only | {"policy_kwargs"}} == \
        {k: v for k, v in gaussian["kwargs"].items() if k not in sde_only | {"policy_kwargs"}}
    sde_policy_only = {"use_expln", "full_std"} | ({"log_std_init"} if algorithm == "sac" else set())
    sde_policy = {k: v for k, v in sde["kwargs"]["policy_kwargs"].items() if k not in sde_policy_only}
    gauss_policy = gaussian["kwargs"]["policy_kwargs"]
    if algorithm != "sac":  # PPO and A2C: log_std_init is also the Gaussian's log σ₀ (explorer.init_param)
        assert gauss_policy.pop("log_std_init") == sde_policy["log_std_init"]
        sde_policy.pop("log_std_init")
    assert sde_policy == gauss_policy
    assert {k: v for k, v in sde.items() if k != "kwargs"} == {k: v for k, v in gaussian.items() if k != "kwargs"}


@pytest.mark.parametrize("override, key", [
    ("explorer=sde", "explorer.schedule"),  # redrawn at every reset: no sde_sample_freq counts that
    ("optimizer.lr_schedule=cosine", "optimizer.lr_schedule"),
    ("actor.init=[-0.1,0.1]", "actor.init"),
    ("explorer.learn_sigma=false", "explorer.learn_sigma"),
])
def test_a_setting_sb3_cannot_run_is_refused_by_name(override, key):
    with pytest.raises(sb3.UnmappableSetting, match=rf"^{key}="):
        settings_of("ppo", "hopper", extra=[override])


def test_overrides_reach_both_sides():
    settings = settings_of("ppo", "hopper", fraction=0.01, extra=["algorithm.n_epochs=3", "eval_episodes=4",
                                                                  "explorer.every_n=8"])
    assert settings["kwargs"]["n_epochs"] == 3 and settings["eval"]["episodes"] == 4
    assert settings["kwargs"]["sde_sample_freq"] == 8
    assert settings["total_timesteps"] == 3 * 8192  # ceil(20,000 / 8,192) updates


def test_schedules_in_the_zoo_notation():
    assert sb3.lr_setting(3e-5, "constant") == 3e-5
    assert sb3.schedule_function(sb3.lr_setting(9.6e-4, "linear"))(0.5) == pytest.approx(4.8e-4)
    with pytest.raises(sb3.UnmappableSetting):
        sb3.lr_setting(1e-3, "linear", final_fraction=0.1)


def test_cells_and_their_train_overrides():
    table = cells(seeds=[0, 1])
    assert len(table) == len(ALGORITHMS) * len(ENVS) * len(NOISES) * 2 == len(set(table))
    assert train_overrides(Cell("sac", "ant", "sde", 3), 7) == ("+experiment=sac_ant_bullet", "seed=3", "updates=7")
    assert "explorer=gaussian" in train_overrides(Cell("sac", "ant", "gaussian", 3))
    with pytest.raises(ValueError, match="noise"):
        Cell("ppo", "ant", "ou", 0)
    assert Cell("sac", "mountaincar", "gaussian", 1).name == "sac_mountaincar_gaussian_seed1"
    with pytest.raises(ValueError, match="ppo on mountaincar: no train.py experiment trains it"):
        Cell("ppo", "mountaincar", "sde", 0)


def test_every_cells_experiment_exists():
    assert len(EXPERIMENTS) == len(ALGORITHMS) * len(ENVS) + 1
    for experiment in EXPERIMENTS.values():
        assert (REPO / "conf" / "experiment" / f"{experiment}.yaml").exists(), experiment


def test_a_cell_beyond_the_papers_table_is_refused_on_the_command_line_by_name(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["run", "--fraction", "0.01", "--algorithms", "a2c", "--envs", "mountaincar"])
    assert exit_info.value.code == 2 and "a2c on mountaincar" in capsys.readouterr().err


#: The paper's budget in env steps (rl-baselines3-zoo's n_timesteps of its entries), and the zoo's
#: for MountainCarContinuous's SAC entry.
BUDGET = {"ppo": 2_000_000, "a2c": 2_000_000, "sac": 1_000_000}


@pytest.mark.parametrize(("algorithm", "env"), list(EXPERIMENTS))
def test_the_full_fraction_is_each_experiments_own_budget(algorithm, env):
    """At fraction 1 the cell runs the updates its experiment file gives, which reach the zoo's
    budget (the paper's, for the PyBullet envs) at the first update past it."""
    conf, _ = compose_cell(Cell(algorithm, env, "sde", 0), 1.0)
    steps = conf.updates * steps_per_update(conf)
    budget = 50_000 if env == "mountaincar" else BUDGET[algorithm]
    assert budget <= steps < budget + steps_per_update(conf)


def test_a_fraction_sets_updates_and_refuses_the_reserved_overrides():
    conf, overrides = compose_cell(Cell("a2c", "ant", "gaussian", 2), 0.01)
    assert conf.updates == 625 and conf.seed == 2 and "updates=625" in overrides
    for reserved in ("updates=3", "seed=1"):
        with pytest.raises(ValueError, match="--fraction"):
            compose_cell(Cell("a2c", "ant", "gaussian", 2), 0.01, [reserved])
    with pytest.raises(ValueError, match="fraction"):
        updates_for(1.5, 245)
    assert compose_cell(Cell("ppo", "halfcheetah", "sde", 0), 0.25)[0].updates == 62  # 507,904 steps


def test_the_mountaincar_cell_maps_to_the_zoos_sac_entry():
    """rl-baselines3-zoo, hyperparams/sac.yml, MountainCarContinuous-v0: 50k steps, one env, no normalisation."""
    conf, overrides = compose_cell(Cell("sac", "mountaincar", "sde", 0), 1.0)
    settings = sb3.sb3_settings(conf)
    assert overrides[0] == "+experiment=sac_mountaincar"
    assert settings["env"] | {"gym_kwargs": {}} == {"id": "MountainCarContinuous-v0", "gym_kwargs": {},
                                                    "episode_length": 999, "n_envs": 1, "time_feature": False,
                                                    "normalize": False, "gamma": 0.9999}
    kwargs = settings["kwargs"]
    assert {k: kwargs[k] for k in ("learning_rate", "buffer_size", "batch_size", "ent_coef", "train_freq",
                                   "gradient_steps", "gamma", "tau", "learning_starts", "use_sde")} == {
        "learning_rate": 3e-4, "buffer_size": 50_000, "batch_size": 512, "ent_coef": 0.1, "train_freq": 32,
        "gradient_steps": 32, "gamma": 0.9999, "tau": 0.01, "learning_starts": 0, "use_sde": True}
    assert kwargs["policy_kwargs"]["log_std_init"] == -3.67 and kwargs["policy_kwargs"]["net_arch"] == [64, 64]


def test_a_folder_refuses_runs_at_another_fraction_or_overrides(tmp_path):
    assert run.open_folder(tmp_path, 0.01, ["eval_episodes=2"]) == {"fraction": 0.01, "overrides": ["eval_episodes=2"]}
    assert run.open_folder(tmp_path, 0.01, ["eval_episodes=2"])["fraction"] == 0.01  # the same: accepted
    with pytest.raises(run.FolderMismatch) as refused:
        run.open_folder(tmp_path, 0.05, ["eval_episodes=2"])
    message = str(refused.value)
    assert "--fraction 0.01" in message and "--fraction 0.05" in message and "--out another folder" in message
    with pytest.raises(run.FolderMismatch, match="eval_episodes=3"):
        run.open_folder(tmp_path, 0.01, ["eval_episodes=3"])


def test_the_command_refuses_a_folder_of_another_fraction_before_training(tmp_path, capsys, monkeypatch):
    def no_cell(*args, **kwargs):
        raise AssertionError("the folder was not refused: a cell was composed")

    monkeypatch.setattr(run, "compose_cell", no_cell)  # a broken refusal fails here rather than training
    run.open_folder(tmp_path, 0.01, [])
    code = cli.main(["run", "--fraction", "0.02", "--algorithms", "ppo", "--envs", "hopper", "--out", str(tmp_path)])
    assert code == 2
    assert "--fraction 0.01" in capsys.readouterr().err
    assert not (tmp_path / "ours").exists() and not (tmp_path / "sb3").exists()


def test_a_failed_sb3_run_leaves_an_error_file_and_no_record(tmp_path, monkeypatch):
    def crash(settings, seed):
        raise RuntimeError("pybullet went away")

    monkeypatch.setattr(run, "train_sb3", crash)
    cell = Cell("ppo", "hopper", "sde", 0)
    message = run.run_sb3(cell, {"env": {"time_feature": False}}, 0.01, [], tmp_path)
    assert message.startswith("RuntimeError: pybullet went away")
    assert "pybullet went away" in run.sb3_error(tmp_path, cell).read_text()
    assert not run.sb3_record(tmp_path, cell).exists()


def test_the_paper_table_has_every_cell():
    for algorithm in ALGORITHMS:
        for env in ENVS:
            assert set(PAPER[(algorithm, env)]) == set(NOISES)
    assert len(PAPER) == len(ALGORITHMS) * len(ENVS)
    # the numbers the brief quotes: PPO Gaussian → gSDE, and A2C Walker2D
    assert [(PAPER[("ppo", e)]["gaussian"][0], PAPER[("ppo", e)]["sde"][0]) for e in ENVS] == \
        [(1976, 2826), (2364, 2782), (1567, 2512), (1230, 2019)]
    assert (PAPER[("a2c", "walker2d")]["gaussian"][0], PAPER[("a2c", "walker2d")]["sde"][0]) == (577, 839)


def _run(final: float, speed: float = 100.0) -> dict:
    return {"final": final, "env_steps": 1000, "wall_s": 1000 / speed, "speed": speed, "evals": [[1000, final]]}


def test_the_report_compares_by_ratio_or_by_difference_across_zero():
    runs = {
        ("ppo", "hopper", "sde"): {"ours": {0: _run(1100.0, 90.0), 1: _run(900.0, 110.0)},
                                   "sb3": {0: _run(1000.0, 100.0), 1: _run(1000.0, 100.0)}},
        ("ppo", "hopper", "gaussian"): {"ours": {0: _run(-50.0), 1: _run(30.0)}, "sb3": {0: _run(200.0)}},
    }
    stats = report.statistics(runs)
    sde = stats["cells"]["ppo/hopper/sde"]
    assert sde["ours_vs_sb3"]["kind"] == "ratio" and sde["ours_vs_sb3"]["estimate"] == pytest.approx(1.0)
    assert sde["speed_ratio"]["estimate"] == pytest.approx(1.0)
    assert sde["ours"]["mean"] == 1000.0 and sde["paper"] == [2512, 21]
    gaussian = stats["cells"]["ppo/hopper/gaussian"]
    assert gaussian["ours_vs_sb3"]["kind"] == "difference"
    assert gaussian["ours_vs_sb3"]["estimate"] == pytest.approx(-10.0 - 200.0)
    gain = stats["sde_minus_gaussian"]["ppo/hopper"]
    assert gain["ours"]["estimate"] == pytest.approx(1000.0 + 10.0) and gain["sb3"]["estimate"] == 800.0
    assert gain["paper"] == 2512 - 1567
    text = report.page({"fraction": 0.1, "overrides": []}, stats)
    assert "2512 ± 21" in text and "(difference)" in text and "+945" in text
    assert "Budget: 0.1 of each experiment's" in text
    assert "Budget: all of each experiment's" in report.page({"fraction": 1.0, "overrides": []}, stats)


def test_returns_about_zero_print_their_digits_not_minus_zero():
    """MountainCar's Gaussian policies end at returns of a few thousandths below 0."""
    assert report._mean_sd([-0.002, -0.009]) == "-0.0055 ± 0.0049"
    difference = {"kind": "difference", "estimate": -0.0035, "low": -0.0074, "high": 0.0001}
    assert report._interval_text(difference) == "-0.0035 [-0.0074, +0.0001]"
    assert report._mean_sd([2374.0, 2200.0]) == "2287 ± 123" and report._mean_sd([0.0, 0.0]) == "0 ± 0"


@pytest.mark.e2e
def test_a_tiny_cell_on_both_sides_then_the_report(tmp_path):
    """A2C Hopper with SDE, 1,024 env steps a side (TimeFeatureWrapper, VecNormalize, RMSprop, the
    linear rate), evaluated every 10 updates on both sides; then the report, and a rerun that skips."""
    out = tmp_path / "table"
    command = [sys.executable, "-m", "analysis.benchmarks.gsde_table", "run", "--fraction", "0.0005",
               "--algorithms", "a2c", "--envs", "hopper", "--noises", "sde", "--workers", "1",
               "--override", "eval_episodes=2", "--override", "eval_period=10", "--out", str(out)]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "2 of 2 runs done; report: python -m analysis.benchmarks.gsde_table report" in result.stderr
    record = json.loads((out / "sb3" / "a2c_hopper_sde_seed0.json").read_text())
    ours = report.read_ours(out / "ours" / "a2c_hopper_sde_seed0")
    assert record["env_steps"] == ours["env_steps"] == 1024
    assert [step for step, _ in record["evals"]] == [step for step, _ in ours["evals"]] == [320, 640, 960, 1024]
    assert len(record["eval_returns"]) == 2 and "sb3_contrib" in record["versions"]
    assert record["settings"]["env"]["time_feature"] and record["fraction"] == 0.0005

    again = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "0 of 2 runs to train (2 finished already)" in again.stderr

    shown = subprocess.run([sys.executable, "-m", "analysis.benchmarks.gsde_table", "report", str(out),
                            "--out", str(out)],
                           cwd=REPO, capture_output=True, text=True, timeout=300)
    assert shown.returncode == 0, shown.stderr[-3000:]
    data = json.loads((out / "gsde_table.json").read_text())
    cell = data["cells"]["a2c/hopper/sde"]
    assert cell["ours"]["seeds"] == cell["sb3"]["seeds"] == [0] and cell["paper"] == [1561, 220]
    assert {"ours_vs_sb3", "speed_ratio"} <= set(cell)
    assert "HopperBulletEnv-v0" in (out / "gsde_table.md").read_text()
    assert (out / "gsde_table_hopper.png").stat().st_size > 0
