"""The Stable-Baselines3 side of a cell: its settings read off the config ``train.py`` composes for
the cell (:func:`sb3_settings`, so that the two sides cannot drift), and one SB3 training with the
table's evaluation schedule (:func:`train_sb3`).

The settings are a plain, JSON-able dict in rl-baselines3-zoo's notation (``"lin_0.00096"`` for a
rate decaying linearly to 0, activation names as ``torch.nn`` spells them), so that a run's record
holds them and a test can set them beside the zoo's ``hyperparams/*.yml`` entries. A setting of
ours that SB3 cannot run (a cosine schedule, SDE redrawn at every reset, a custom initialisation,
...) raises :class:`UnmappableSetting` naming it, rather than training something else.

Examples:
    >>> lr_setting(3e-5, "constant"), lr_setting(9.6e-4, "linear")
    (3e-05, 'lin_0.00096')
"""

from __future__ import annotations

import copy
import time
from typing import Any

from analysis.benchmarks.gsde_table.cells import steps_per_update

#: Our actor's activation names → ``torch.nn``'s class names.
ACTIVATIONS = {"relu": "ReLU", "tanh": "Tanh", "sigmoid": "Sigmoid"}
#: Seeds of the SB3 evaluation envs: the run's seed plus this.
EVAL_SEED_OFFSET = 10_000


class UnmappableSetting(ValueError):
    """A setting of our config that Stable-Baselines3 has no counterpart for."""

    def __init__(self, key: str, value: Any, why: str) -> None:
        super().__init__(f"{key}={value!r}: {why}; the SB3 side would train something else, so the cell is "
                         "refused (drop the override, or compare this cell without SB3)")


def lr_setting(value: float, schedule: str, final_fraction: float = 0.0, key: str = "optimizer.lr_schedule"):
    """A rate and its schedule in the zoo's notation: the number, or ``lin_<value>`` for a linear
    decay to 0 over the run (SB3's ``progress_remaining × value``)."""
    if schedule == "constant":
        return value
    if schedule == "linear" and final_fraction == 0:
        return f"lin_{value}"
    raise UnmappableSetting(key, f"{schedule} to {final_fraction}",
                            "SB3 (and the zoo) decay linearly to 0 or not at all")


def schedule_function(setting):
    """The callable SB3 takes for ``lin_<value>``, or the number itself.

    Examples:
        >>> schedule_function("lin_0.5")(0.25), schedule_function(3e-5)
        (0.125, 3e-05)
    """
    if isinstance(setting, str):
        value = float(setting.removeprefix("lin_"))
        return lambda progress_remaining: progress_remaining * value
    return setting


def _sde_settings(conf, algorithm: str) -> dict[str, Any]:
    """``use_sde`` and its options from our explorer (``explorer=gaussian``: ``use_sde=False``)."""
    from sde_torchrl.config.schemas.policy import ExplorerConf, GaussianExplorerConf

    explorer = conf.explorer
    if explorer.squash != (algorithm == "sac"):
        raise UnmappableSetting("explorer.squash", explorer.squash,
                                "SB3 squashes SAC's actions and not PPO's or A2C's")
    if not explorer.learn_sigma:
        raise UnmappableSetting("explorer.learn_sigma", False, "SB3 always learns the noise scale")
    if isinstance(explorer, GaussianExplorerConf):  # PPO's and A2C's log σ₀; SAC's comes from its own head
        return {"use_sde": False, "policy_kwargs": {} if algorithm == "sac" else {"log_std_init": explorer.init_param}}
    if not isinstance(explorer, ExplorerConf):
        raise UnmappableSetting("explorer", type(explorer).__name__, "not an SDE or Gaussian explorer")
    if explorer.gaussian_init_param is not None:
        raise UnmappableSetting("explorer.gaussian_init_param", explorer.gaussian_init_param,
                                "gSDE has no extra i.i.d. Gaussian noise")
    if explorer.schedule == "rollout":
        frequency = -1  # one matrix per rollout (PPO, A2C) or per round of collection (SAC)
    elif explorer.schedule == "every_n_steps":
        frequency = explorer.every_n
    else:
        raise UnmappableSetting("explorer.schedule", explorer.schedule,
                                "SB3's sde_sample_freq counts steps through resets (rollout or every_n_steps)")
    sharing = {"element": True, "feature": False}
    if explorer.sharing not in sharing or (algorithm == "sac" and explorer.sharing != "element"):
        raise UnmappableSetting("explorer.sharing", explorer.sharing,
                                "SB3 has one σ̂ per matrix element (full_std=True) or per feature (False, not SAC)")
    settings: dict[str, Any] = {"use_sde": True, "sde_sample_freq": frequency}
    policy: dict[str, Any] = {"log_std_init": explorer.init_param, "use_expln": explorer.sigma_transform == "expln"}
    if algorithm != "sac":
        policy["full_std"] = sharing[explorer.sharing]
    return {**settings, "policy_kwargs": policy}


def _optimizer_settings(conf, algorithm: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The optimiser: the algorithm's keyword arguments and the policy's."""
    optimizer = conf.optimizer
    name = optimizer._target_.rsplit(".", 1)[-1]
    if algorithm == "a2c" and name == "RMSprop":
        if optimizer.alpha != 0.99:
            raise UnmappableSetting("optimizer.alpha", optimizer.alpha, "SB3's A2C runs RMSprop with alpha 0.99")
        return {"use_rms_prop": True, "rms_prop_eps": optimizer.eps}, {}
    if name != "Adam":
        raise UnmappableSetting("optimizer", name, f"SB3's {algorithm.upper()} runs Adam"
                                + (" or RMSprop" if algorithm == "a2c" else ""))
    policy = {"optimizer_kwargs": {"eps": optimizer.eps, "betas": list(optimizer.betas)}}
    return ({"use_rms_prop": False} if algorithm == "a2c" else {}), policy


def sb3_settings(conf) -> dict[str, Any]:
    """The SB3 side of a cell, read off the checked config that ``train.py`` runs for it.

    Args:
        conf: the :class:`~sde_torchrl.config.schemas.train.TrainConf` of the cell
            (:func:`.cells.compose_cell`), ``algorithm=ppo``, ``a2c`` or ``sac`` on ``env=gym``.

    Returns:
        ``{"algorithm", "kwargs", "env", "total_timesteps", "eval"}``: the SB3 class name, its
        keyword arguments in the zoo's notation (``policy_kwargs`` among them), the env
        (``id``, ``gym_kwargs``, ``episode_length``, ``n_envs``, ``time_feature``: sb3-contrib's
        ``TimeFeatureWrapper``; ``normalize``: ``VecNormalize`` with the discount ``gamma``), the
        budget (our updates × their env steps) and the evaluation schedule (``period_steps``
        env steps, and after the last; ``episodes`` deterministic episodes).

    Raises:
        UnmappableSetting: for a setting SB3 cannot run.
    """
    from sde_torchrl.config.schemas.algorithms import A2CConf, PPOConf, SACConf

    alg, actor = conf.algorithm, conf.actor
    algorithm = "sac" if isinstance(alg, SACConf) else "a2c" if isinstance(alg, A2CConf) else "ppo"
    if conf.env.reset_options:
        raise UnmappableSetting("env.reset_options", conf.env.reset_options, "SB3's VecEnv resets without options")
    if actor.init is not None:
        raise UnmappableSetting("actor.init", actor.init, "SB3 initialises with torch's default (ortho_init=False) "
                                "or orthogonally, not otherwise")
    if actor.activation not in ACTIVATIONS or not actor.bias:
        raise UnmappableSetting("actor", f"{actor.activation}, bias={actor.bias}", "SB3's MLPs have biases")
    sde = _sde_settings(conf, algorithm)
    sde_policy = sde.pop("policy_kwargs", {})
    optimizer_kwargs, optimizer_policy = _optimizer_settings(conf, algorithm)
    kwargs: dict[str, Any] = {"gamma": alg.gamma, "ent_coef": alg.ent_coef,
                              "learning_rate": lr_setting(conf.lr, conf.optimizer.lr_schedule,
                                                          conf.optimizer.final_lr_fraction)}
    policy: dict[str, Any] = {"activation_fn": ACTIVATIONS[actor.activation]}
    if algorithm == "sac":
        kwargs.update(buffer_size=alg.buffer_size, batch_size=alg.batch_size, learning_starts=alg.learning_starts,
                      train_freq=alg.train_freq, gradient_steps=alg.gradient_steps, tau=alg.tau)
        policy["net_arch"] = list(actor.hidden)  # actor and both critics
        n_envs, normalize = 1, False
    else:
        critic = alg.critic_hidden if alg.critic_hidden is not None else actor.hidden
        kwargs.update(n_steps=alg.n_steps, gae_lambda=alg.gae_lambda, vf_coef=alg.vf_coef,
                      max_grad_norm=alg.max_grad_norm, normalize_advantage=alg.normalize_advantage)
        if alg.max_grad_norm is None:
            raise UnmappableSetting("algorithm.max_grad_norm", None, "SB3 always clips the gradient norm")
        if isinstance(alg, PPOConf):
            kwargs.update(batch_size=alg.batch_size, n_epochs=alg.n_epochs,
                          clip_range=lr_setting(alg.clip_range, alg.clip_range_schedule, key="algorithm.clip_range"))
        policy.update(net_arch={"pi": list(actor.hidden), "vf": list(critic)}, ortho_init=False)
        n_envs, normalize = alg.n_envs, alg.normalize
    kwargs.update(sde)
    kwargs.update(optimizer_kwargs)
    kwargs["policy_kwargs"] = {**policy, **sde_policy, **optimizer_policy}
    update_steps = steps_per_update(conf)
    return {
        "algorithm": algorithm.upper(),
        "kwargs": kwargs,
        "env": {"id": conf.env.id, "gym_kwargs": dict(conf.env.gym_kwargs or {}),
                "episode_length": conf.env.episode_length, "n_envs": n_envs,
                "time_feature": bool(alg.time_feature), "normalize": bool(normalize),
                "gamma": alg.gamma},
        "total_timesteps": conf.updates * update_steps,
        "eval": {"period_steps": conf.eval_period * update_steps, "episodes": conf.eval_episodes},
    }


def make_vec_env(env: dict[str, Any], n_envs: int, seed: int):
    """The SB3 vectorised env of a cell's settings: ``n_envs`` ``Monitor``-wrapped envs (raw
    returns), with the time feature (sb3-contrib's ``TimeFeatureWrapper``, outside ``Monitor`` as
    the zoo wraps) if the settings ask for it."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from analysis.benchmarks.common import gym_make

    gym_kwargs = {k: v for k, v in env["gym_kwargs"].items() if v is not None}
    wrapper, wrapper_kwargs = None, None
    if env["time_feature"]:
        from sb3_contrib.common.wrappers import TimeFeatureWrapper

        wrapper, wrapper_kwargs = TimeFeatureWrapper, {"max_steps": env["episode_length"]}
    return sb3_make_vec_env(lambda: gym_make(env["id"], **gym_kwargs), n_envs=n_envs, seed=seed,
                            wrapper_class=wrapper, wrapper_kwargs=wrapper_kwargs)


def build_model(settings: dict[str, Any], seed: int):
    """The SB3 model and its training env for ``settings`` (:func:`sb3_settings`), on the CPU."""
    import stable_baselines3
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    env_settings = settings["env"]
    env = make_vec_env(env_settings, env_settings["n_envs"], seed)
    if env_settings["normalize"]:
        env = VecNormalize(env, gamma=env_settings["gamma"])
    kwargs = copy.deepcopy(settings["kwargs"])
    for key in ("learning_rate", "clip_range"):
        if key in kwargs:
            kwargs[key] = schedule_function(kwargs[key])
    policy = kwargs.pop("policy_kwargs")
    policy["activation_fn"] = getattr(torch.nn, policy["activation_fn"])
    if "optimizer_kwargs" in policy and "betas" in policy["optimizer_kwargs"]:
        policy["optimizer_kwargs"]["betas"] = tuple(policy["optimizer_kwargs"]["betas"])
    model = getattr(stable_baselines3, settings["algorithm"])("MlpPolicy", env, seed=seed, device="cpu",
                                                              policy_kwargs=policy, **kwargs)
    return model, env


def model_from_config(conf, benchmark: str):
    """Stable-Baselines3's model and its training env with the settings of a job's checked config
    (:func:`sb3_settings`, :func:`build_model`), seed 0, for the benchmarks that time
    both sides.

    Raises:
        SystemExit: Stable-Baselines3 is not installed (naming the extra that installs it).

    Returns:
        ``(settings, model, env)``.
    """
    try:
        import stable_baselines3  # noqa: F401
    except ImportError as err:
        raise SystemExit(f"{benchmark}: the sb3 variants need Stable-Baselines3: pip install -e '.[bench]' ({err})") \
            from err
    settings = sb3_settings(conf)
    return (settings, *build_model(settings, seed=0))


def train_sb3(settings: dict[str, Any], seed: int) -> dict[str, Any]:
    """One SB3 training of a cell: ``total_timesteps`` env steps, evaluated every ``period_steps``
    (after the update that reaches them, as ours) and after the last update on ``episodes``
    deterministic episodes, one per env of an evaluation ``VecEnv`` (observation statistics copied
    from training and frozen, raw rewards).

    Returns:
        The record: ``env_steps``, ``wall_s`` (training and its evaluations, as our
        ``summary.json``'s), ``env_steps_per_s``, ``evals`` (``[env steps, mean return]``),
        ``final_eval_return``, ``eval_returns`` (the last evaluation's episodes) and ``curve`` (the
        training episodes' raw returns, ``[env steps, return]``).
    """
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize, sync_envs_normalization

    model, env = build_model(settings, seed)
    episodes, period = settings["eval"]["episodes"], settings["eval"]["period_steps"]
    eval_env = make_vec_env(settings["env"], episodes, seed + EVAL_SEED_OFFSET)
    if settings["env"]["normalize"]:
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False, gamma=settings["env"]["gamma"])
    evals: list[list[float]] = []
    curve: list[list[float]] = []
    last: list[float] = []

    def evaluate(steps: int) -> None:
        sync_envs_normalization(env, eval_env)
        returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=episodes, deterministic=True,
                                     return_episode_rewards=True)
        last[:] = [float(r) for r in returns]
        evals.append([steps, sum(last) / len(last)])

    class Schedule(BaseCallback):
        """Evaluates as a rollout starts, i.e. after the previous update, once ``period`` steps are passed."""

        def _on_rollout_start(self) -> None:
            if period and self.num_timesteps and self.num_timesteps % period == 0:
                evaluate(self.num_timesteps)

        def _on_step(self) -> bool:
            curve.extend([self.num_timesteps, float(i["episode"]["r"])] for i in self.locals["infos"] if "episode" in i)
            return True

    start = time.perf_counter()
    model.learn(total_timesteps=settings["total_timesteps"], callback=Schedule())
    evaluate(int(model.num_timesteps))
    wall = time.perf_counter() - start
    env.close()
    eval_env.close()
    steps = int(model.num_timesteps)
    return {"env_steps": steps, "wall_s": wall, "env_steps_per_s": steps / wall, "evals": evals,
            "final_eval_return": evals[-1][1], "eval_returns": last, "curve": curve}
