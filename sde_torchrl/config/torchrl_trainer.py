"""SDE as a policy of TorchRL's own trainers: ``model@models.policy_model: sde`` in their Hydra configs.

TorchRL's trainer configs (``torchrl.trainers.algorithms.configs``: ``PPOTrainerConfig``,
``A2CTrainerConfig``, ...) build their policy from the config group ``model``; its
``tanh_normal`` option is a ``ProbabilisticTensorDictSequential`` over ``TanhNormal``.
:func:`register_torchrl_configs` adds the option ``sde`` beside it (:class:`SDEModelConfig`):
the squashed SDE policy of :func:`~sde_torchrl.modules.sde_actor.make_sde_actor`, built by
:func:`make_sde_model` from the same fields, so a ``tanh_normal`` block (network, keys, bounds)
works unchanged. :func:`check_sde_models` checks every ``sde`` model of a composed config before
anything is built, naming each refused one by its key.

The noise matrix is drawn in the env by the policy's own
:class:`~sde_torchrl.modules.noise.SDENoisePrimer` (``sde.make_tensordict_primer()``), which
TorchRL's collectors append with ``auto_register_policy_transforms: true`` (their default from
TorchRL 0.15 on); no separate ``transform`` option: the primer must match the policy's
dimensions, schedule and keys, which the policy already knows.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn
from torchrl.trainers.algorithms.configs.common import _normalize_hydra_key
from torchrl.trainers.algorithms.configs.modules import ModelConfig

from sde_torchrl.modules.noise import DEFAULT_SCHEDULE
from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import SDEActor, make_sde_actor
from sde_torchrl.utils.checks import ArgumentError, float32_number, is_int, noise_schedule, one_of
from sde_torchrl.utils.options import SHARINGS, SIGMA_TRANSFORMS

#: ``_target_`` of :class:`SDEModelConfig`.
TARGET = f"{__name__}.make_sde_model"

#: TanhNormal's bound on a squashed mean (``tanh_loc``): ``loc ← upscale · tanh(loc / upscale)``.
TANH_LOC_UPSCALE = 5.0


@dataclass
class SDEModelConfig(ModelConfig):
    """Config of the SDE policy in TorchRL's ``model`` group (option ``sde``), for :func:`make_sde_model`.

    Carries every field of TorchRL's ``TanhNormalModelConfig`` (``network``, ``in_keys``,
    ``out_keys``, ``param_keys``, ``extract_normal_params``, ``low``, ``high``, ``tanh_loc``,
    ``scale_mapping``, ``scale_lb``, ``return_log_prob``, ``exploration_type``, ``eval_mode``,
    ``shared``), so that a ``tanh_normal`` block merges as it is, and SDE's own options
    (:class:`~sde_torchrl.modules.sde.SDEParams`'): ``action_dim``, ``feature_dim``,
    ``feature_key``, ``schedule``, ``every_n``, ``rollout_steps``, ``sharing``,
    ``sigma_transform``, ``init_param``, ``gaussian_init_param``, ``learn_sigma``. What each
    field does: :func:`make_sde_model`.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from torchrl.trainers.algorithms.configs import MLPConfig
        >>> cfg = SDEModelConfig(network=MLPConfig(in_features=3, out_features=2, num_cells=[16]), low=-2.0, high=2.0)
        >>> policy = instantiate(cfg)
        >>> type(policy).__name__, policy.sde.action_dim, policy.sde.feature_dim
        ('SDEActor', 1, 3)
    """

    network: Any = MISSING
    eval_mode: bool = False
    extract_normal_params: bool = True
    scale_mapping: str = "biased_softplus_1.0"
    scale_lb: float = 1e-4
    low: Any = None
    high: Any = None
    tanh_loc: bool = False
    param_keys: Any = None
    exploration_type: Any = "RANDOM"
    return_log_prob: bool = True
    action_dim: int | None = None
    feature_dim: int | None = None
    feature_key: Any = None
    schedule: str = DEFAULT_SCHEDULE
    every_n: int | None = None
    rollout_steps: int | None = None
    sharing: str = "element"
    sigma_transform: str = "expln"
    init_param: float = -2.0
    gaussian_init_param: float | None = None
    learn_sigma: bool = True
    _target_: str = TARGET

    def __post_init__(self) -> None:
        """TanhNormal's default keys: the observation in, ``loc`` (and ``scale``) between, the action out."""
        super().__post_init__()
        if self.in_keys is None:
            self.in_keys = ["observation"]
        if self.param_keys is None:
            self.param_keys = ["loc", "scale"] if self.extract_normal_params else ["loc"]
        if self.out_keys is None:
            self.out_keys = ["action"]


class MeanHead(nn.Module):
    """The controller's mean from a network's output: its first ``action_dim`` entries, bounded
    as TanhNormal's ``tanh_loc`` bounds its location if ``upscale`` is given.

    Args:
        action_dim: ``A``.
        upscale: ``loc ← upscale · tanh(loc / upscale)``, or ``None`` for the raw output.

    Examples:
        >>> MeanHead(1, upscale=5.0)(torch.tensor([[100.0, 3.0]]))
        tensor([[5.]])
    """

    def __init__(self, action_dim: int, upscale: float | None = None) -> None:
        super().__init__()
        self.action_dim, self.upscale = action_dim, upscale

    def forward(self, output: torch.Tensor) -> torch.Tensor:
        loc = output[..., : self.action_dim]
        return loc if self.upscale is None else self.upscale * torch.tanh(loc / self.upscale)


def make_sde_model(
    network: nn.Module | DictConfig | Callable[[], nn.Module],
    *,
    in_keys: Sequence[Any] = ("observation",),
    out_keys: Sequence[Any] = ("action",),
    param_keys: Sequence[Any] = ("loc", "scale"),
    extract_normal_params: bool = True,
    low: Any = None,
    high: Any = None,
    tanh_loc: bool = False,
    scale_mapping: str | None = None,
    scale_lb: float | None = None,
    return_log_prob: bool = True,
    exploration_type: Any = "RANDOM",
    eval_mode: bool = False,
    shared: bool = False,
    action_dim: int | None = None,
    feature_dim: int | None = None,
    feature_key: Any = None,
    **sde_options: Any,
) -> SDEActor:
    """The squashed SDE policy from a ``tanh_normal`` model config's fields (:class:`SDEModelConfig`'s ``_target_``).

    ``network`` reads ``in_keys`` and gives the controller's mean; the policy is
    ``make_sde_actor(TensorDictModule(network, in_keys, [loc]), SDEParams(...), squash=True)``:
    actions in ``[low, high]``, the mean ``loc`` plus ``(σ̂ ⊙ ξ) x`` before the tanh, ``ξ`` carried
    by the env (the policy's primer; TorchRL's collector appends it with
    ``auto_register_policy_transforms=True``).

    Args:
        network: the mean's network (an ``nn.Module``, its Hydra config, or a partial).
        in_keys: the network's inputs.
        out_keys: where the action is written (one key).
        param_keys: the keys of the network's outputs; the first is the mean's (``loc``).
        extract_normal_params: the network writes ``2·A`` numbers, mean then scale, as
            TanhNormal's ``NormalParamExtractor`` splits them: the mean is the first ``A``. SDE's
            exploration scale is ``σ̂`` times the features, not a network output, so the second
            half is not used (``false`` and ``out_features: A`` do not compute it).
        low: the actions' lower bound (a number or one per action; TanhNormal's default -1).
        high: the upper bound (default 1).
        tanh_loc: bound the mean as TanhNormal does: ``loc ← 5 · tanh(loc / 5)``.
        scale_mapping: TanhNormal's map of the network's scale output: not used (see
            ``extract_normal_params``).
        scale_lb: TanhNormal's floor on that scale: not used either.
        return_log_prob: the policy writes ``action_log_prob`` whatever this says (PPO's ratio
            and A2C read it).
        exploration_type: ``"RANDOM"``: the policy samples unless TorchRL's exploration context
            (``set_exploration_type``, a collector's ``exploration_type``) asks for the mean.
        eval_mode: return the policy in eval mode.
        shared: put the parameters in shared memory (multi-process collectors).
        action_dim: ``A``; default: the network's ``out_features`` (halved with
            ``extract_normal_params``).
        feature_dim: ``S``, the size of what the noise matrix multiplies; default: the network's
            ``in_features`` when the features are its input.
        feature_key: the features ``x`` of ``(σ̂ ⊙ ξ) x``; default: the single key of ``in_keys``.
        **sde_options: :class:`~sde_torchrl.modules.sde.SDEParams`' own options, with its
            defaults: ``schedule`` (when the noise is redrawn: ``"episode"``, SDE, at every reset;
            ``"step"``, REX; ``"every_n"``; SB3's ``"every_n_steps"``, ``"rollout"``), ``every_n``,
            ``rollout_steps`` (``frames_per_batch // num_envs`` with TorchRL's collectors),
            ``sharing``, ``sigma_transform`` (``expln``, eq. 23, or ``exp``), ``init_param``
            (-2: ``σ̂ ≈ 0.135``), ``gaussian_init_param`` (eq. 22) and ``learn_sigma``.

    Returns:
        The :class:`~sde_torchrl.modules.sde_actor.SDEActor`.

    Raises:
        ArgumentError: a setting :func:`check_sde_settings` refuses (a non-finite ``init_param``,
            bound, ...).
        ValueError: an ``exploration_type`` other than ``"RANDOM"``, more than one output key,
            dimensions that cannot be inferred from the network, an odd ``out_features`` with
            ``extract_normal_params``, or several input keys and no ``feature_key``.

    Examples:
        >>> from torchrl.envs import GymEnv
        >>> from torchrl.modules import MLP
        >>> policy = make_sde_model(MLP(in_features=3, out_features=2, num_cells=[16]), low=-2.0, high=2.0)
        >>> env = GymEnv("Pendulum-v1").append_transform(policy.sde.make_tensordict_primer())
        >>> td = env.rollout(4, policy)
        >>> bool((td["action"].abs() <= 2).all()), bool((td["sde_noise"] == td["sde_noise"][0]).all())
        (True, True)
    """
    check_sde_settings({"low": low, "high": high, "action_dim": action_dim, "feature_dim": feature_dim,
                        **sde_options})
    if str(exploration_type).upper() not in ("RANDOM", "INTERACTIONTYPE.RANDOM"):
        raise ValueError(
            f"exploration_type={exploration_type!r}: the SDE policy samples (RANDOM) unless TorchRL's exploration "
            "context asks for the mean; set the collector's exploration_type, or use set_exploration_type"
        )
    in_keys = [_normalize_hydra_key(key) for key in in_keys]
    out_keys = [_normalize_hydra_key(key) for key in out_keys]
    if len(out_keys) != 1:
        raise ValueError(f"out_keys={out_keys}: the SDE policy writes one action; give one key, e.g. ['action']")
    network = _built(network)
    action_dim = action_dim or _action_dim(network, extract_normal_params)
    feature_key = _feature_key(feature_key, in_keys)
    if feature_dim is None:
        feature_dim = _feature_dim(network, feature_key, in_keys)
    loc_key = _normalize_hydra_key(param_keys[0])
    head = MeanHead(action_dim, TANH_LOC_UPSCALE if tanh_loc else None)
    actor = TensorDictModule(nn.Sequential(network, head), in_keys=in_keys, out_keys=[loc_key])
    sde = SDEParams(action_dim, feature_dim, **sde_options, loc_key=loc_key, feature_key=feature_key)
    policy = make_sde_actor(actor, sde, squash=True, low=_bound(low, -1.0), high=_bound(high, 1.0),
                            action_key=out_keys[0])
    if shared:
        policy.share_memory()
    return policy.eval() if eval_mode else policy


def register_torchrl_configs() -> None:
    """Adds the option ``sde`` (:class:`SDEModelConfig`) to the ``model`` group of TorchRL's trainer
    configs, in Hydra's ``ConfigStore`` (idempotent). Call it before Hydra composes a config that
    chooses ``model@...: sde``, as ``examples/torchrl_trainer/train.py`` does.

    Importing this module registers TorchRL's own configs (``torchrl.trainers.algorithms.configs``
    registers them when imported). Their group options ``env/gym``, ``optimizer/adam``,
    ``logger/csv``, ... share their paths with this repository's ``conf/`` files;
    :func:`~sde_torchrl.config.compose.compose` composes ``conf/`` without them.

    Examples:
        >>> register_torchrl_configs()
        >>> ConfigStore.instance().load("model/sde.yaml").node._target_
        'sde_torchrl.config.torchrl_trainer.make_sde_model'
    """
    ConfigStore.instance().store(group="model", name="sde", node=SDEModelConfig)


#: The settings of an ``sde`` model that :func:`check_sde_settings` checks.
CHECKED_SETTINGS = ("init_param", "gaussian_init_param", "low", "high", "action_dim", "feature_dim", "schedule",
                    "every_n", "rollout_steps", "sharing", "sigma_transform")


def check_sde_settings(settings: Mapping[str, Any], prefix: str = "") -> None:
    """Refuses the settings of an ``sde`` model that would build a policy acting on NaN, or none.

    Checks those of ``settings`` that :func:`make_sde_model` reads (absent ones are not checked):
    ``init_param`` and ``gaussian_init_param`` (a number a float32 ``σ̂`` parameter holds; ``null``
    for the latter), ``low`` and ``high`` (``null``, a finite number or a list of them),
    ``action_dim`` and ``feature_dim`` (``null`` or a positive integer), ``schedule`` with
    ``every_n`` and ``rollout_steps``, ``sharing`` and ``sigma_transform``.

    Args:
        settings: the model's fields (a config node or keyword arguments).
        prefix: the model's key in the config, with a trailing dot (``"models.policy_model."``).

    Raises:
        ArgumentError: ``<prefix><field>=<value>: <what is allowed>``.

    Examples:
        >>> check_sde_settings({"init_param": -1.0, "low": [-2.0], "high": 2})
        >>> check_sde_settings({"init_param": float("nan")}, "models.policy_model.")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: models.policy_model.init_param=nan: a finite number within ...
    """
    if "init_param" in settings:
        float32_number(prefix + "init_param", settings["init_param"])
    if settings.get("gaussian_init_param") is not None:
        float32_number(prefix + "gaussian_init_param", settings["gaussian_init_param"])
    for name in ("low", "high"):
        value = settings.get(name)
        if value is not None and not _finite_numbers(value):
            raise ArgumentError(prefix + name, value,
                                "null, a finite number, or a list of finite numbers (one per action)")
    for name in ("action_dim", "feature_dim"):
        value = settings.get(name)
        if value is not None and not (is_int(value) and value >= 1):
            raise ArgumentError(prefix + name, value, "null (read from the network) or a positive integer")
    if any(name in settings for name in ("schedule", "every_n", "rollout_steps")):
        noise_schedule(settings.get("schedule", DEFAULT_SCHEDULE), settings.get("every_n"), prefix,
                       rollout_steps=settings.get("rollout_steps"))
    for name, allowed in (("sharing", SHARINGS), ("sigma_transform", SIGMA_TRANSFORMS)):
        if name in settings:
            one_of(prefix + name, settings[name], allowed)


def check_sde_models(cfg: DictConfig) -> None:
    """Checks every ``sde`` model of a composed TorchRL trainer config (each node whose
    ``_target_`` is :func:`make_sde_model`) with :func:`check_sde_settings`, before anything is
    built: a refused setting is named by its key in ``cfg``. A node that only interpolates
    another (``loss.actor_network: ${models.policy_model}``) is checked where it is defined.

    Raises:
        ArgumentError: ``<key>=<value>: <what is allowed>``, e.g. ``models.policy_model.init_param=nan: ...``.

    Examples:
        >>> cfg = OmegaConf.create({"models": {"policy_model": {"_target_": TARGET, "high": float("inf")}},
        ...                         "loss": {"actor_network": "${models.policy_model}"}})
        >>> check_sde_models(cfg)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: models.policy_model.high=inf: null, a finite number, ...
    """

    def visit(node: DictConfig | ListConfig, path: str) -> None:
        keys = node.keys() if isinstance(node, DictConfig) else range(len(node))
        for key in keys:
            if OmegaConf.is_interpolation(node, key) or OmegaConf.is_missing(node, key):
                continue
            child = node[key]
            if isinstance(child, (DictConfig, ListConfig)):
                visit(child, f"{path}{key}.")
        if isinstance(node, DictConfig) and node.get("_target_") == TARGET:
            check_sde_settings({key: node[key] for key in CHECKED_SETTINGS
                                if key in node and not OmegaConf.is_missing(node, key)}, path)

    visit(cfg, "")


def _finite_numbers(value: Any) -> bool:
    """``value`` is a finite number, or a non-empty list (or tensor) of them; not a bool."""
    items = list(value) if isinstance(value, (ListConfig, list, tuple)) else [value]
    if any(isinstance(item, bool) for item in items):
        return False
    try:
        numbers = torch.as_tensor(items if isinstance(value, (ListConfig, list, tuple)) else value,
                                  dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        return False
    return numbers.numel() > 0 and bool(torch.isfinite(numbers).all())


def _built(network: nn.Module | DictConfig | Callable[[], nn.Module]) -> nn.Module:
    """The network module, from a module, its Hydra config or a partial."""
    if isinstance(network, nn.Module):
        return network
    if isinstance(network, DictConfig) and "_target_" in network:
        from hydra.utils import instantiate

        return instantiate(network)
    if callable(network):
        return network()
    raise ValueError(f"network={network!r}: give an nn.Module, a Hydra config with _target_, or a partial")


def _action_dim(network: nn.Module, extract_normal_params: bool) -> int:
    """``A`` from the network's ``out_features``: all of it, or half with ``extract_normal_params``."""
    out_features = getattr(network, "out_features", None)
    if not isinstance(out_features, int):
        raise ValueError(
            f"the network ({type(network).__name__}) has no integer out_features to infer the action size "
            "from: give action_dim="
        )
    if not extract_normal_params:
        return out_features
    if out_features % 2:
        raise ValueError(
            f"network out_features={out_features} with extract_normal_params=true: the network writes the mean "
            "then a scale, so out_features is 2 × the action size; or set extract_normal_params=false, "
            "out_features=A"
        )
    return out_features // 2


def _feature_key(feature_key: Any, in_keys: list[NestedKey]) -> NestedKey:
    """The features of ``(σ̂ ⊙ ξ) x``: ``feature_key``, or the network's single input."""
    if feature_key is not None:
        return _normalize_hydra_key(feature_key)
    if len(in_keys) != 1:
        raise ValueError(f"in_keys={in_keys}: with several inputs, say which the noise multiplies: feature_key=")
    return in_keys[0]


def _feature_dim(network: nn.Module, feature_key: NestedKey, in_keys: list[NestedKey]) -> int:
    """``S`` from the network's ``in_features`` when the features are its input."""
    in_features = getattr(network, "in_features", None)
    if in_keys != [feature_key] or not isinstance(in_features, int) or in_features < 1:  # lazy: 0
        raise ValueError(
            f"cannot infer the size of the features {feature_key!r} from the network ({type(network).__name__}, "
            f"in_features={in_features}, in_keys={in_keys}): give feature_dim="
        )
    return in_features


def _bound(value: Any, default: float) -> torch.Tensor | float:
    """An action bound as a number or a tensor (a YAML list is a ``ListConfig``)."""
    if value is None:
        return default
    if isinstance(value, (ListConfig, list, tuple)):
        return torch.as_tensor(list(value), dtype=torch.get_default_dtype())
    return float(value)


__all__ = ["MeanHead", "SDEModelConfig", "check_sde_models", "check_sde_settings", "make_sde_model",
           "register_torchrl_configs"]
