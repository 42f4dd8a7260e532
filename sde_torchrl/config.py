"""Config schemas and validation: a typo fails before any work, with one clear line.

Every config group option is backed by a dataclass registered in Hydra's ``ConfigStore``
under ``schema/<group>/<option>`` (the YAML files list it first in their defaults), and the
top-level config by ``schema/config``. Hydra then rejects unknown keys and wrong types while
composing; :func:`validate` checks the values (positive counts, allowed strings, options that
only make sense together) before anything is built. Every failure is turned into one line by
:func:`describe_error`: ``<key>=<value>: <what is allowed>``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, List, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, ListConfig, OmegaConf

# Kept in sync with the modules they describe (imported lazily there would cost the import
# of torch at config time; the tests check the two agree).
SCHEDULES = ("episode", "step", "every_n")
SHARINGS = ("element", "action", "single")
ACTIVATIONS = ("sigmoid", "tanh", "relu")
NORMALIZATIONS = ("bounds", "stats")
REWARD_STATES = ("noise_free", "noisy")
EPISODE_RETURNS = ("sum", "mean")

# ``typing`` generics, not ``list[int]``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP006, UP007


class ConfigError(ValueError):
    """A config value that is not allowed.

    Args:
        key: dotted config key (``explorer.sharing``).
        value: the value given.
        allowed: what would be accepted, in words.

    Examples:
        >>> str(ConfigError("runs", -1, "a positive integer"))
        'runs=-1: a positive integer'
    """

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        self.key, self.value, self.allowed = key, value, allowed
        super().__init__(f"{key}={_show(value)}: {allowed}")


def _show(value: Any) -> str:
    if isinstance(value, (DictConfig, ListConfig)):
        value = OmegaConf.to_container(value)
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


# ------------------------------------------------------------------------------ schemas


@dataclass
class MinimizeEnvConf:
    """``env=minimize``: the function-minimisation task (paper section 4.1)."""

    _target_: str = "sde_torchrl.envs.make_minimize_env"
    episode_length: int = 15
    dim: int = 1
    x0: Any = 2.0  # a scalar or a dim-vector
    x0_spread: float = 0.0
    step_size: float = 0.1
    noise_std: float = 0.5
    reward_state: str = "noise_free"  # noise_free (authors' code) | noisy


@dataclass
class BallCatchEnvConf:
    """``env=ballcatch``: the pybullet ball-catching task (paper section 4.2)."""

    _target_: str = "sde_torchrl.envs.ballcatch_torchrl.make_ballcatch_env"
    episode_length: int = 500
    jitter: float = 0.05


@dataclass
class GymEnvConf:
    """``env=gym``: any gymnasium continuous-control env, through TorchRL's ``GymEnv``."""

    _target_: str = "sde_torchrl.envs.gym.make_gym_env"
    id: str = "Pendulum-v1"
    episode_length: int = 200
    normalize_obs: Optional[str] = None  # null | bounds | stats
    norm_init_steps: int = 1000
    constant_feature: bool = False
    gym_kwargs: Any = field(default_factory=dict)
    reset_options: Any = None  # passed to every reset, e.g. {x_init: 0.3, y_init: 0.3}


@dataclass
class LinearActorConf:
    """``actor=linear``: ``u = Θ x (+ b)``."""

    _target_: str = "sde_torchrl.actors.LinearActor"
    bias: bool = False
    init: Any = -2.0  # a constant or [low, high)


@dataclass
class MLPActorConf:
    """``actor=mlp``: a small multi-layer perceptron."""

    _target_: str = "sde_torchrl.actors.MLPActor"
    hidden: List[int] = field(default_factory=lambda: [3])
    activation: str = "sigmoid"
    bias: bool = True
    init: Any = field(default_factory=lambda: [-1.0, 0.0])


@dataclass
class ExplorerConf:
    """``explorer=sde|rex|every_n|sde_gauss``: the state-dependent explorer."""

    _target_: str = "sde_torchrl.exploration.StateDependentExplorer"
    schedule: str = "episode"
    every_n: Optional[int] = None
    sharing: str = "element"
    init_param: float = -2.0
    gaussian_init_param: Optional[float] = None
    learn_sigma: bool = True
    squash: bool = False


@dataclass
class EstimatorConf:
    """``estimator=reinforce|enac``."""

    _target_: str = "sde_torchrl.estimators.ReinforceEstimator"
    max_grad_norm: Optional[float] = None
    max_grad_entry: Optional[float] = None  # the authors' rescale to a largest entry (1000 in their code)
    episode_return: str = "mean"  # mean (paper's text) | sum (authors' code)
    variance_weighted: bool = False  # the authors' "auto-alpha" scores


@dataclass
class CSVLoggerConf:
    """``logger=csv``: TorchRL's ``CSVLogger``."""

    _target_: str = "torchrl.record.loggers.csv.CSVLogger"
    exp_name: str = "sde_torchrl"


@dataclass
class TensorboardLoggerConf:
    """``logger=tensorboard``: TorchRL's ``TensorboardLogger``."""

    _target_: str = "torchrl.record.loggers.tensorboard.TensorboardLogger"
    exp_name: str = "sde_torchrl"


@dataclass
class WandbLoggerConf:
    """``logger=wandb``: TorchRL's ``WandbLogger``, offline by default."""

    _target_: str = "torchrl.record.loggers.wandb.WandbLogger"
    exp_name: str = "sde_torchrl"
    project: str = "sde_torchrl"
    offline: bool = True


@dataclass
class TrainConf:
    """The top-level config (``conf/config.yaml``); groups are typed by their own schemas."""

    env: Any = None
    actor: Any = None
    explorer: Any = None
    estimator: Any = None
    logger: Any = None
    seed: int = 0
    runs: int = 1
    first_run: int = 0
    updates: int = 200
    episodes_per_update: int = 10
    lr: float = 0.01
    eval_period: int = 20
    eval_episodes: int = 5
    r_lim: Optional[float] = None
    stop_at_threshold: bool = False
    tensor_rollout: bool = True
    episode_queue: int = 0  # > 0: each update uses the last Q episodes per run (ball catching)
    checkpoint_period: int = 25
    progress: Optional[bool] = None  # null: a bar only on a terminal and outside multirun
    threads: int = 1  # torch intra-op threads per job (jobs of a sweep share the cores)


#: ``schema/<name>`` → dataclass; YAML files name these first in their defaults list.
SCHEMAS: dict[str, type] = {
    "config": TrainConf,
    "env/minimize": MinimizeEnvConf,
    "env/gym": GymEnvConf,
    "env/ballcatch": BallCatchEnvConf,
    "actor/linear": LinearActorConf,
    "actor/mlp": MLPActorConf,
    "explorer/sde": ExplorerConf,
    "estimator/episodic": EstimatorConf,
    "logger/csv": CSVLoggerConf,
    "logger/tensorboard": TensorboardLoggerConf,
    "logger/wandb": WandbLoggerConf,
}


def register_configs() -> None:
    """Stores every schema in Hydra's ``ConfigStore`` (idempotent)."""
    store = ConfigStore.instance()
    for path, node in SCHEMAS.items():
        group, _, name = f"schema/{path}".rpartition("/")
        store.store(group=group, name=name, node=node)


# ----------------------------------------------------------------------------- validation


def validate(cfg: DictConfig) -> None:
    """Checks the values of a composed config before anything is built.

    Args:
        cfg: the composed config.

    Raises:
        ConfigError: for the first value that is not allowed.
    """
    _check_top_level(cfg)
    for group, check in (("env", _check_env), ("actor", _check_actor),
                         ("explorer", _check_explorer), ("estimator", _check_estimator)):
        node = cfg.get(group)
        if node is not None:
            check(node, group)


def _check_top_level(cfg: DictConfig) -> None:
    for key in ("runs", "updates", "episodes_per_update", "eval_episodes", "threads"):
        _positive_int(cfg, key, key)
    for key in ("seed", "first_run", "eval_period", "checkpoint_period", "episode_queue"):
        _non_negative_int(cfg, key, key)
    queue, per_update = cfg.get("episode_queue", 0), cfg.get("episodes_per_update")
    if queue and queue % per_update:
        raise ConfigError("episode_queue", queue, f"0 or a multiple of episodes_per_update ({per_update})")
    _positive_float(cfg, "lr", "lr")
    r_lim = cfg.get("r_lim")
    if r_lim is not None and not _is_finite_number(r_lim):
        raise ConfigError("r_lim", r_lim, "a finite number, or null")
    if cfg.get("stop_at_threshold") and r_lim is None:
        raise ConfigError("stop_at_threshold", True, "needs a convergence threshold r_lim (not null)")


def _check_env(env: DictConfig, prefix: str) -> None:
    _positive_int(env, "episode_length", prefix)
    target = str(env.get("_target_", ""))
    if target.endswith("make_minimize_env"):
        _positive_int(env, "dim", prefix)
        for key in ("x0_spread", "noise_std"):
            value = env.get(key)
            if not _is_finite_number(value) or value < 0:
                raise ConfigError(f"{prefix}.{key}", value, "a finite number >= 0")
        if not _is_finite_number(env.get("step_size")):
            raise ConfigError(f"{prefix}.step_size", env.get("step_size"), "a finite number")
        _one_of(env, "reward_state", REWARD_STATES, prefix)
    elif target.endswith("make_ballcatch_env"):
        jitter = env.get("jitter")
        if not _is_finite_number(jitter) or not 0 <= jitter <= 0.4:
            raise ConfigError(f"{prefix}.jitter", jitter, "a number in [0, 0.4]")
    elif target.endswith("make_gym_env"):
        _check_gym_id(env.get("id"), f"{prefix}.id")
        norm = env.get("normalize_obs")
        if norm is not None and norm not in NORMALIZATIONS:
            raise ConfigError(f"{prefix}.normalize_obs", norm, f"null or one of {', '.join(NORMALIZATIONS)}")
        _positive_int(env, "norm_init_steps", prefix)


def _check_gym_id(env_id: Any, key: str) -> None:
    if not isinstance(env_id, str) or not env_id:
        raise ConfigError(key, env_id, "a registered gymnasium env id such as Pendulum-v1")
    if ":" in env_id:  # "module:Env-v0" registers on import: checked when built
        return
    import gymnasium

    if env_id not in gymnasium.envs.registry:
        close = sorted(k for k in gymnasium.envs.registry if k.lower().startswith(env_id.lower()[:4]))
        hint = f" (close: {', '.join(close[:5])})" if close else ""
        raise ConfigError(key, env_id, f"a registered gymnasium env id such as Pendulum-v1{hint}")


def _check_actor(actor: DictConfig, prefix: str) -> None:
    init = actor.get("init")
    if isinstance(init, ListConfig):
        if len(init) != 2 or not all(_is_finite_number(v) for v in init) or not init[0] < init[1]:
            raise ConfigError(f"{prefix}.init", init, "a number, or [low, high] with low < high")
    elif init is not None and not _is_finite_number(init):
        raise ConfigError(f"{prefix}.init", init, "a number, or [low, high] with low < high")
    if str(actor.get("_target_", "")).endswith("MLPActor"):
        hidden = actor.get("hidden")
        if not all(isinstance(h, int) and h >= 1 for h in hidden):
            raise ConfigError(f"{prefix}.hidden", hidden, "a list of positive integers")
        _one_of(actor, "activation", ACTIVATIONS, prefix)


def _check_explorer(explorer: DictConfig, prefix: str) -> None:
    _one_of(explorer, "schedule", SCHEDULES, prefix)
    _one_of(explorer, "sharing", SHARINGS, prefix)
    every_n = explorer.get("every_n")
    if explorer.get("schedule") == "every_n":
        _positive_int(explorer, "every_n", prefix)
    elif every_n is not None:
        raise ConfigError(f"{prefix}.every_n", every_n, "null unless explorer.schedule=every_n")
    for key in ("init_param", "gaussian_init_param"):
        value = explorer.get(key)
        if value is not None and not _is_finite_number(value):
            raise ConfigError(f"{prefix}.{key}", value, "a finite number")


def _check_estimator(estimator: DictConfig, prefix: str) -> None:
    for key in ("max_grad_norm", "max_grad_entry"):
        bound = estimator.get(key)
        if bound is not None and (not _is_finite_number(bound) or bound <= 0):
            raise ConfigError(f"{prefix}.{key}", bound, "a number > 0, or null (no bound)")
    _one_of(estimator, "episode_return", EPISODE_RETURNS, prefix)


def _is_finite_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _positive_int(node: DictConfig, key: str, prefix: str) -> None:
    value = node.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(_join(prefix, key), value, "a positive integer")


def _non_negative_int(node: DictConfig, key: str, prefix: str) -> None:
    value = node.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise ConfigError(_join(prefix, key), value, "an integer >= 0")


def _positive_float(node: DictConfig, key: str, prefix: str) -> None:
    value = node.get(key)
    if not _is_finite_number(value) or value <= 0:
        raise ConfigError(_join(prefix, key), value, "a finite number > 0")


def _one_of(node: DictConfig, key: str, allowed: tuple[str, ...], prefix: str) -> None:
    value = node.get(key)
    if value not in allowed:
        raise ConfigError(_join(prefix, key), value, f"one of {', '.join(allowed)}")


def _join(prefix: str, key: str) -> str:
    return key if prefix == key else f"{prefix}.{key}"


# ------------------------------------------------------------------------ error reporting


def describe_error(error: BaseException) -> str | None:
    """One line ``<key>=<value>: <what is allowed>`` for a config error, else ``None``.

    Understands :class:`ConfigError`, Hydra's unknown group options and override errors and
    OmegaConf's validation errors (wrong type, unknown key), also when wrapped by Hydra.
    """
    from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    for err in _chain(error):
        if isinstance(err, ConfigError):
            return str(err)
        if isinstance(err, MissingConfigException):
            return _missing_option(err)
        if isinstance(err, OmegaConfBaseException) and getattr(err, "full_key", None):
            return _omegaconf_line(err)
    for err in _chain(error):
        if isinstance(err, (ConfigCompositionException, OverrideParseException, OmegaConfBaseException)):
            return " ".join(str(err).split())
    return None


def _chain(error: BaseException) -> list[BaseException]:
    chain, seen = [], set()
    while error is not None and id(error) not in seen:
        chain.append(error)
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return chain


def _missing_option(err: Any) -> str:
    path = err.missing_cfg_file or ""
    group, _, option = path.rpartition("/")
    options = [o for o in (err.options or []) if not o.startswith("schema")]
    if group and options:
        return f"{group}={option}: expected one of {', '.join(sorted(options))}"
    return " ".join(str(err).split())


_TYPE_WORDS = {"Integer": "an integer", "Float": "a number", "Boolean": "true or false",
               "String": "a string"}


def _omegaconf_line(err: Any) -> str:
    key = err.full_key
    value = getattr(err, "value", None)  # not always set by OmegaConf
    msg = str(getattr(err, "msg", "") or err).splitlines()[0]
    if "not in struct" in msg or "Key '" in msg and "not in" in msg:
        return f"{key}: unknown key"
    expected = getattr(err, "ref_type", None) or getattr(err, "object_type_str", None)
    if value is None and "Value '" in msg:
        value = msg.split("Value '", 1)[1].split("'", 1)[0]
    allowed = msg
    if "could not be converted to" in msg:
        type_name = msg.rsplit("could not be converted to", 1)[1].strip().rstrip(".")
        allowed = _TYPE_WORDS.get(type_name, f"a value of type {type_name}")
    elif expected:
        allowed = f"{msg} (expected {expected})"
    return f"{key}={_show(value)}: {allowed}" if value is not None else f"{key}: {allowed}"
