"""The config schemas: the single source of truth for what a config may hold.

Every config group option is backed by a dataclass, registered in Hydra's ``ConfigStore`` under
``schema/<group>/<option>`` (:mod:`sde_torchrl.config.registration`; a YAML file lists it first in
its defaults and holds only what differs from it), the top-level config under ``schema/config``.
Hydra rejects unknown keys and wrong types while composing;
:func:`~sde_torchrl.config.schemas.train.validate` then converts the config once into these
dataclasses, whose ``__post_init__`` checks the values (:mod:`sde_torchrl.utils.checks`), each
failure one line (:mod:`sde_torchrl.config.errors`). Allowed strings (:mod:`sde_torchrl.utils.options`)
are checked strings, not Enums, so that in a multirun a bad value fails its one job, not the sweep.

One module a group or a few that go together: ``envs`` (``env``), ``policy`` (``actor``,
``explorer``), ``estimators``, ``algorithms`` (PPO, A2C, SAC), ``optimizers``, ``loggers``, and
``train``: the top-level :class:`~sde_torchrl.config.schemas.train.TrainConf` and the rules across
its groups.

Examples:
    >>> from sde_torchrl.config.schemas.train import TrainConf
    >>> TrainConf().episodes_per_update
    10
"""
