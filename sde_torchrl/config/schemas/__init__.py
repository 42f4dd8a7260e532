"""The config schemas: the single source of truth for what a config may hold.

Every config group option is backed by a dataclass, registered in Hydra's ``ConfigStore`` under
``schema/<group>/<option>`` (:mod:`sde_torchrl.config.registration`; the YAML files list it first
in their defaults and hold only what differs from it), and the top-level config by
``schema/config``. Hydra then rejects unknown keys and wrong types while composing;
:func:`~sde_torchrl.config.schemas.train.validate` converts the composed config once into these
dataclasses, whose ``__post_init__`` checks the values (positive counts, allowed strings, options
that only make sense together) with :mod:`sde_torchrl.utils.checks`. Every failure becomes one
line (:mod:`sde_torchrl.config.errors`).

The allowed strings live in :mod:`sde_torchrl.utils.options`, beside no torch. They are strings
checked by the schemas, not Enums: Hydra would reject an unknown Enum value while composing,
which in a multirun stops the whole sweep instead of failing that one job (with its
``error.txt``).

One module a group, or a few groups that go together:

- :mod:`~sde_torchrl.config.schemas.envs`: ``env``;
- :mod:`~sde_torchrl.config.schemas.policy`: ``actor`` and ``explorer``;
- :mod:`~sde_torchrl.config.schemas.estimators`: ``estimator``, one schema per estimator;
- :mod:`~sde_torchrl.config.schemas.algorithms`: ``algorithm`` (PPO, A2C, SAC);
- :mod:`~sde_torchrl.config.schemas.optimizers`: ``optimizer``;
- :mod:`~sde_torchrl.config.schemas.loggers`: ``logger``;
- :mod:`~sde_torchrl.config.schemas.train`: the top-level
  :class:`~sde_torchrl.config.schemas.train.TrainConf` and the rules across its groups.

Examples:
    >>> from sde_torchrl.config.schemas.train import TrainConf
    >>> TrainConf().episodes_per_update
    10
"""
