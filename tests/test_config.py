"""Config schemas and validation: bad configs fail before any work, in one line."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from importlib.util import find_spec

import pytest
from _helpers import compose_config, own_stderr_lines, read_rows, run_cli

from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.utils.checks import ArgumentError


def config_error_line(*overrides: str, experiment: str = "minimize") -> str:
    """The one line a bad config produces, composing and validating in this process."""
    with pytest.raises(Exception) as info:
        validate(compose_config(f"+experiment={experiment}", *overrides))
    line = describe_error(info.value)
    assert line is not None, f"not recognised as a config error: {info.value!r}"
    assert "\n" not in line
    return line


@pytest.mark.parametrize("overrides, expected", [
    (("explorer=nonsense",),
     "explorer=nonsense: expected one of every_n, gaussian, gsde, gsde_freq4, pgpe, rex, sde, sde_gauss"),
    (("logger=nope",), "logger=nope: expected one of csv, none, tensorboard, wandb"),
    (("env.episode_length=-3",), "env.episode_length=-3: a positive integer"),
    (("env.episode_length=ten",), "env.episode_length=ten: an integer"),
    (("explorer.sharing=both",), "explorer.sharing=both: one of element, action, single, feature"),
    (("explorer.schedule=sometimes",),
     "explorer.schedule=sometimes: one of episode, step, every_n, every_n_steps, rollout"),
    (("explorer=every_n", "explorer.every_n=0"), "explorer.every_n=0: a positive integer"),
    (("explorer.every_n=3",), "explorer.every_n=3: null unless explorer.schedule=every_n or every_n_steps"),
    (("updates=abc",), "updates=abc: an integer"),
    (("runs=0",), "runs=0: a positive integer"),
    (("seed=-1",), "seed=-1: an integer >= 0"),
    (("lr=-0.1",), "lr=-0.1: a finite number > 0"),
    (("actor=mlp", "actor.activation=gelu"), "actor.activation=gelu: one of sigmoid, tanh, relu"),
    (("actor.init=[0,-1]",), "actor.init=[0, -1]: a number, or [low, high] with low < high"),
    (("estimator.max_grad_norm=0",), "estimator.max_grad_norm=0.0: a number > 0, or null (no bound)"),
    (("env.noise_std=-1",), "env.noise_std=-1.0: a finite number >= 0"),
    (("env.reward_state=next",), "env.reward_state=next: one of noise_free, noisy"),
    (("estimator.max_grad_entry=-1",), "estimator.max_grad_entry=-1.0: a number > 0, or null (no bound)"),
    (("estimator.episode_return=total",), "estimator.episode_return=total: one of sum, mean"),
    (("r_lim=null", "stop_at_threshold=true"),
     "stop_at_threshold=true: needs a convergence threshold r_lim (not null)"),
    (("explorer.bogus=1",), "explorer.bogus: unknown key"),
    (("logger.exp_name=../../x",), "logger.exp_name=../../x: a plain folder name (no '/', not '.' or '..'): the "
                                   "logger writes into <run directory>/<exp_name>"),
    (("logger=tensorboard", "logger.exp_name=.."), "logger.exp_name=..: a plain folder name (no '/', not '.' or "
                                                   "'..'): the logger writes into <run directory>/<exp_name>"),
    (("seed=18446744073709551616",), "seed=18446744073709551616: an integer >= 0 and below 2**64"),
    (("explorer.init_param=-1e308",),
     "explorer.init_param=-1e+308: a finite number within float32's range (|x| <= 3.4e+38)"),
    (("explorer=pgpe", "estimator=pgpe", "explorer.init_param=1e39"),
     "explorer.init_param=1e+39: a finite number within float32's range (|x| <= 3.4e+38)"),
    (("logger.exp_name=checkpoint.pt",), "logger.exp_name=checkpoint.pt: a folder name other than the run "
                                         "directory's own files (.hydra, .lock, job_config.json, metrics.csv, "
                                         "summary.json, checkpoint.pt, checkpoint.prev.pt, error.txt, train.log, "
                                         "final_policy.json)"),
    (("logger.exp_name=summary.json.tmp",), "logger.exp_name=summary.json.tmp: a folder name other than the run "
                                            "directory's own files (.hydra, .lock, job_config.json, metrics.csv, "
                                            "summary.json, checkpoint.pt, checkpoint.prev.pt, error.txt, train.log, "
                                            "final_policy.json)"),
])
def test_bad_value_gives_one_line_naming_key_value_and_allowed(overrides, expected):
    assert config_error_line(*overrides) == expected


ESTIMATOR_OPTIONS = "max_grad_norm, max_grad_entry, episode_return, variance_weighted"


@pytest.mark.parametrize("estimator", ["reinforce", "enac", "gpomdp", "pgpe"])
def test_a_key_the_estimator_does_not_take_is_refused_naming_the_estimator_and_its_options(estimator):
    """``estimator.symmetric`` is ``explorer=pgpe``'s option: each estimator's own schema refuses it,
    named, with the keys that estimator takes, whether overridden or added with ``+``."""
    assert config_error_line(f"estimator={estimator}", "estimator.symmetric=true") == (
        f"estimator.symmetric: unknown key (estimator={estimator}'s options: {ESTIMATOR_OPTIONS})")
    assert config_error_line(f"estimator={estimator}", "+estimator.symmetric=true") == (
        f"estimator.symmetric=true: unknown key (estimator={estimator}'s options: {ESTIMATOR_OPTIONS})")


@pytest.mark.parametrize("overrides, expected", [
    (("+explorer.bogus=1",), "explorer.bogus=1: unknown key"),
    (("+optimizer.momentun=0.9",), "optimizer.momentun=0.9: unknown key"),
    (("+epochs=3",), "epochs=3: unknown key"),
])
def test_a_key_added_with_plus_that_no_schema_has_is_refused(overrides, expected):
    """``+group.key=value`` adds a key that Hydra would refuse without the ``+``; unchecked and
    unused, it would still be recorded in the job's config."""
    assert config_error_line(*overrides) == expected


def test_each_estimator_option_has_its_own_schema_naming_its_estimator():
    from sde_torchrl.config.compose import CONF_DIR
    from sde_torchrl.config.registration import SCHEMAS

    options = sorted(path.stem for path in (CONF_DIR / "estimator").glob("*.yaml"))
    schemas = {path.split("/")[1]: schema for path, schema in SCHEMAS.items() if path.startswith("estimator/")}
    assert sorted(schemas) == options
    for option, schema in schemas.items():
        conf = validate(compose_config(f"estimator={option}", *(("explorer=pgpe",) if option == "pgpe" else ())))
        assert type(conf.estimator) is schema and conf.estimator.option == option
        assert conf.estimator._target_.rsplit(".", 1)[-1].lower() == f"{option}estimator"


def test_unknown_gym_id_is_rejected_before_building():
    line = config_error_line("env.id=Pendulm-v1", experiment="pendulum")
    assert line.startswith("env.id=Pendulm-v1: a registered gymnasium env id")


@pytest.mark.parametrize("overrides", [
    (), ("explorer=rex",), ("explorer=every_n",), ("explorer=sde_gauss",), ("estimator=enac",),
    ("actor=mlp", "env.dim=2"), ("logger=tensorboard",), ("logger=none",),
    pytest.param(("logger=wandb",), marks=pytest.mark.skipif(find_spec("wandb") is None, reason="wandb not installed")),
])
def test_shipped_options_validate(overrides):
    validate(compose_config("+experiment=minimize", *overrides))


@pytest.mark.skipif(find_spec("wandb") is not None, reason="wandb is installed")
def test_a_logger_whose_package_is_missing_is_a_config_error_with_the_install_hint():
    assert config_error_line("logger=wandb") == ("logger=wandb: a logger whose package is installed: wandb is not "
                                                 "(pip install wandb; or logger=csv or logger=none)")


@pytest.mark.parametrize("overrides", [
    ("env=gym",), ("env=gym", "actor.bias=true", "env.id=MountainCarContinuous-v0"),
    ("env=gym", "env.normalize_obs=stats", "env.constant_feature=true", "explorer=rex", "estimator=enac"),
])
def test_gym_options_validate(overrides):
    validate(compose_config(*overrides))


def test_gym_normalisation_must_be_known():
    line = config_error_line("env.normalize_obs=running", experiment="pendulum")
    assert line == "env.normalize_obs=running: null or one of bounds, stats"


@pytest.mark.parametrize("overrides, expected", [
    (("env.id=CartPole-v1",),
     "env.id=CartPole-v1: an env with a continuous (Box) action space; CartPole-v1 has Discrete(2)"),
    (("env.episode_length=201",),
     "env.episode_length=201: at most 200 (Pendulum-v1's time limit; raise it with "
     "env.gym_kwargs.max_episode_steps=201)"),
    (("env.gym_kwargs.max_episode_steps=0",),
     "env.gym_kwargs.max_episode_steps=0: a positive integer, or null (the env's own time limit)"),
    (("+env.gym_kwargs.foo=1",),
     "env.gym_kwargs={'foo': 1}: keyword arguments Pendulum-v1 takes "
     "(PendulumEnv.__init__() got an unexpected keyword argument 'foo')"),
])
def test_unusable_gym_env_is_rejected_before_building(overrides, expected):
    assert config_error_line(*overrides, experiment="pendulum") == expected


def test_gym_time_limit_raised_without_plus():
    """The advice of the time-limit error, typed as printed (no ``+``), validates."""
    conf = validate(compose_config("env=gym", "env.episode_length=300", "env.gym_kwargs.max_episode_steps=300"))
    assert conf.env.gym_kwargs == {"max_episode_steps": 300}
    assert validate(compose_config("env=gym")).env.gym_kwargs == {"max_episode_steps": None}
    assert validate(compose_config("env=gym", "+env.gym_kwargs.g=9.81")).env.gym_kwargs["g"] == 9.81


@pytest.mark.parametrize("experiment", ["minimize", "minimize2d_mlp", "pendulum"])
def test_experiments_validate(experiment):
    """The library's experiments (the study's: ``tests/study/test_study_configs.py``)."""
    validate(compose_config(f"+experiment={experiment}"))


def test_config_and_constructors_refuse_the_same_values():
    """Each allowed-values tuple is written once (sde_torchrl.utils.options): a value the config
    refuses, the constructor refuses too, naming the same option."""
    from sde_torchrl import MLPActor, SDEParams, make_minimize_env

    assert "explorer.schedule=sometimes" in config_error_line("explorer.schedule=sometimes")
    with pytest.raises(ArgumentError, match="schedule=sometimes"):
        SDEParams(1, 1, schedule="sometimes")
    assert "explorer.sharing=per_state" in config_error_line("explorer.sharing=per_state")
    with pytest.raises(ArgumentError, match="sharing=per_state"):
        SDEParams(1, 1, sharing="per_state")
    assert "actor.activation=gelu" in config_error_line("actor=mlp", "actor.activation=gelu")
    with pytest.raises(ArgumentError, match="activation=gelu"):
        MLPActor(1, 1, hidden=[2], activation="gelu")
    assert "env.reward_state=later" in config_error_line("env.reward_state=later")
    with pytest.raises(ArgumentError, match="reward_state=later"):
        make_minimize_env(5, reward_state="later")


def test_config_error_message():
    error = ArgumentError("explorer.sharing", "both", "one of element, action, single")
    assert str(error) == "explorer.sharing=both: one of element, action, single"
    assert isinstance(error, ValueError) and error.key == "explorer.sharing"


# The command line: one line on stderr, exit code 2, nothing trained.
CLI_CASES = {
    "unknown_explorer": (("explorer=nonsense",), "error: explorer=nonsense: expected one of"),
    "negative_length": (("env.episode_length=-3",), "error: env.episode_length=-3: a positive integer"),
    "no_such_sharing": (("explorer.sharing=both",), "error: explorer.sharing=both: one of element"),
    "wrong_type": (("updates=1.5",), "error: updates=1.5: an integer"),
}


def test_bad_configs_on_the_command_line_fail_in_one_line(tmp_path):
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = {name: pool.submit(run_cli, "+experiment=minimize", *overrides, run_dir=tmp_path / name)
                   for name, (overrides, _) in CLI_CASES.items()}
        results = {name: future.result() for name, future in results.items()}
    for name, (_, expected) in CLI_CASES.items():
        result = results[name]
        assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
        lines = own_stderr_lines(result.stderr)
        assert len(lines) == 1, (name, lines)
        assert lines[0].startswith(expected), (name, lines[0])
        assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
        assert not (tmp_path / name / "metrics.csv").exists(), name  # failed before any work


def test_module_gym_id_is_refused_when_built_as_a_config_error():
    """A ``module:Env-v0`` id registers on import: the schema leaves it to the build, whose error
    (through Hydra's ``InstantiationException``) is still a one-line config error."""
    from sde_torchrl.config.build import build_trainer

    with pytest.raises(Exception) as info:
        build_trainer(compose_config("env=gym", "env.id=gymnasium.envs.classic_control:CartPole-v1"))
    assert type(info.value).__name__ == "InstantiationException"
    assert describe_error(info.value) == (
        "env.id=gymnasium.envs.classic_control:CartPole-v1: an env with a continuous (Box) action space; "
        "gymnasium.envs.classic_control:CartPole-v1 has Discrete(2)")


@pytest.mark.e2e
def test_gym_env_errors_on_the_command_line_fail_in_one_line(tmp_path):
    """Discrete actions and a too-long episode give one line and exit 2, refused by the schema
    before any env is built; the time-limit advice, run as printed, starts the job."""
    cases = {"discrete": "env.id=CartPole-v1", "too_long": "env.episode_length=201"}
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {name: pool.submit(run_cli, "env=gym", override, run_dir=tmp_path / name)
                   for name, override in cases.items()}
        results = {name: future.result() for name, future in futures.items()}
    lines = {}
    for name, result in results.items():
        assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
        assert len(own_stderr_lines(result.stderr)) == 1, (name, result.stderr)
        assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
        assert "make_gym_env" not in (tmp_path / name / "error.txt").read_text(), name  # not built
        lines[name] = own_stderr_lines(result.stderr)[0]
    assert lines["discrete"] == ("error: env.id=CartPole-v1: an env with a continuous (Box) action space; "
                                 "CartPole-v1 has Discrete(2)")
    advice = lines["too_long"].rsplit("raise it with ", 1)[1].removesuffix(")")
    assert advice == "env.gym_kwargs.max_episode_steps=201"
    started = run_cli("env=gym", "env.episode_length=201", advice, "updates=1", "episodes_per_update=2",
                      "eval_episodes=1", "logger=none", run_dir=tmp_path / "advised")
    assert started.returncode == 0, started.stderr[-2000:]
    assert len(read_rows(tmp_path / "advised")) == 1


def test_checking_a_config_imports_no_torch():
    """The schemas and the allowed values they check import no torch (train.py checks the config
    and takes its run directory's lock before torch loads)."""
    import subprocess
    import sys

    code = ("import sys, sde_torchrl.config.registration, sde_torchrl.config.errors, sde_torchrl.utils.options; "
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)
