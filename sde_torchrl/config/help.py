"""What ``python train.py --help`` shows: the groups a user chooses from, each with its options
as ``conf/`` holds them, and every top-level setting with its default and what it does (read
from :class:`~sde_torchrl.config.schemas.train.TrainConf`'s docstring, so the two cannot drift).

The internal ``schema/*`` groups (the typed schemas behind the options) are left out; Hydra's own
listing stays one flag away (``--hydra-help``).
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import textwrap
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from sde_torchrl.config.schemas.train import TrainConf

#: The groups a user chooses from, in the order a job is put together, and what each chooses.
GROUPS = {
    "experiment": "a whole job at once (add it with +experiment=NAME): the paper's experiments (run a sweep "
                  "with -m), PPO, A2C and SAC on the PyBullet tasks",
    "env": "the task",
    "actor": "the controller that gives the action's mean",
    "explorer": "how the policy explores: SDE, REX, PGPE, gSDE or plain Gaussian noise",
    "estimator": "the paper's episodic gradient estimator",
    "algorithm": "PPO, A2C or SAC in place of the episodic estimators (default: none)",
    "optimizer": "the step rule (lr=... sets its rate)",
    "logger": "where the curves go besides metrics.csv",
}

USAGE = """\
Train policy gradients with state-dependent exploration (SDE).

  python train.py +experiment=NAME               a whole job: NAME, one of the experiment options below
  python train.py +experiment=NAME runs=30       30 independent runs of it side by side
  python train.py -m +experiment=NAME seed=0,1   a sweep: one job per seed, compared at the end
  python train.py +experiment=NAME --help        this help with that experiment's whole config
"""


def option_names(conf_dir: str | Path, group: str) -> list[str]:
    """The options of a group: the YAML files in ``conf_dir/group``, sorted.

    Examples:
        >>> from sde_torchrl.config.compose import CONF_DIR
        >>> option_names(CONF_DIR, "actor")
        ['linear', 'mlp']
    """
    return sorted(path.stem for path in Path(conf_dir, group).glob("*.yaml"))


def setting_lines() -> list[tuple[str, str]]:
    """Each top-level setting that is not a group, with its default and what it does.

    Examples:
        >>> dict(setting_lines())["runs"]
        'runs=1: independent learners trained side by side in this process.'
    """
    defaults = {field.name: field.default for field in dataclasses.fields(TrainConf)}
    return [(name, f"{name}={_yaml(defaults[name])}: {text}")
            for name, text in _attributes(TrainConf.__doc__).items() if name not in GROUPS]


def help_text(conf_dir: str | Path) -> str:
    """The whole help, a template for Hydra: ``$CONFIG`` becomes the composed config.

    Args:
        conf_dir: the config tree ``train.py`` composes from.

    Examples:
        >>> from sde_torchrl.config.compose import CONF_DIR
        >>> text = help_text(CONF_DIR)
        >>> "schema" in text, "explorer: how the policy explores" in text
        (False, True)
    """
    groups = [f"{group}: {what}\n" + textwrap.fill(", ".join(option_names(conf_dir, group)), 100,
                                                  initial_indent="    ", subsequent_indent="    ")
              for group, what in GROUPS.items()]
    settings = [f"  {line}" for _, line in setting_lines()]
    return "\n".join([
        USAGE, "== What you choose (group=option) ==", *groups, "",
        "== Settings (name=default: what it does; a group's own settings as group.name=value) ==", *settings, "",
        "== The config these choices compose ==", "$CONFIG",
        "Hydra's own flags (multirun, launchers, output directories): --hydra-help",
    ])


def _attributes(docstring: str | None) -> dict[str, str]:
    """The ``Attributes:`` section of a Google-style docstring, as plain text per name."""
    text = inspect.cleandoc(docstring or "")
    section = text.split("Attributes:\n", 1)[1].split("\n\n", 1)[0]
    entries = re.findall(r"^    (\w+): (.*?)(?=^    \w+: |\Z)", section, flags=re.M | re.S)
    return {name: _plain(" ".join(body.split())) for name, body in entries}


def _plain(text: str) -> str:
    """Docstring markup as a terminal shows it: roles by their last name, code without quotes.

    Examples:
        >>> _plain("the ``ppo`` schema (:class:`~a.b.PPOConf`)")
        'the ppo schema (PPOConf)'
        >>> _plain("the memory (:mod:`a.resources`) or ``cuda`` (:mod:`a.devices`; refused)")
        'the memory or cuda (refused)'
    """
    text = re.sub(r" ?\(:mod:`[^`]*`\)|:mod:`[^`]*`; ", "", text)  # where the code lives: not for the terminal
    text = re.sub(r":\w+:`~?(?:[\w.]*\.)?(\w+)`", r"\1", text)
    return text.replace("``", "").replace("$", "$$")


def _yaml(value: object) -> str:
    """A default as it is written on the command line (``null``, ``true``)."""
    if value is None:
        return "null"
    return str(value).lower() if isinstance(value, bool) else str(value)


def register_help_resolver() -> None:
    """Registers ``${sde_help:}`` (``conf/config.yaml``'s ``hydra.help.template``): :func:`help_text`
    for the config tree the application composes from (its ``main`` config source)."""
    OmegaConf.register_new_resolver("sde_help", _help_for, replace=True)


def _help_for(_root_: DictConfig) -> str:
    main = next(source for source in _root_.hydra.runtime.config_sources if source.provider == "main")
    return help_text(main.path.removeprefix("file://"))
