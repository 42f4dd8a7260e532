"""The library's Hydra config composed in Python, as ``train.py`` and ``sde-train`` compose it.

For tests and scripts that build trainers or read sweep parameters without going through the
command line. The config tree ships inside the package (``sde_torchrl/conf/``; a clone's top-level
``conf/`` links to it); trees of one's own join it through Hydra's search path (a
``SearchPathPlugin``), as the paper's reproduction adds its sweeps.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig

from sde_torchrl.config.registration import register_resolvers

#: The package's own config tree, ``sde_torchrl/conf/``: installed with it, and ``conf/`` in a clone.
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def compose(
    overrides: Sequence[str] = (),
    config_dir: str | Path | None = None,
    *,
    return_hydra_config: bool = False,
) -> DictConfig:
    """The config ``train.py overrides...`` would run, with the config resolvers registered.

    Args:
        overrides: Hydra overrides, as on the command line (``"+experiment=minimize"``, ``"runs=2"``).
        config_dir: the config tree holding ``config.yaml``; default: the package's own
            (:data:`CONF_DIR`).
        return_hydra_config: also return the ``hydra`` node (sweeper params, runtime choices).

    Returns:
        The composed config.

    Raises:
        FileNotFoundError: if ``config_dir`` (or, by default, :data:`CONF_DIR`) holds no
            ``config.yaml``.

    Examples:
        >>> cfg = compose(["+experiment=minimize", "runs=2"])
        >>> cfg.runs
        2
    """
    directory = Path(CONF_DIR if config_dir is None else config_dir).resolve()
    if not (directory / "config.yaml").is_file():
        raise FileNotFoundError(
            f"config_dir={directory}: no config.yaml there; pass config_dir= a config tree such as "
            f"the package's own ({CONF_DIR})"
        )
    register_resolvers()
    with initialize_config_dir(config_dir=str(directory), version_base="1.3"), store_entries_hidden(directory):
        return hydra_compose(config_name="config", overrides=list(overrides),
                             return_hydra_config=return_hydra_config)


@contextmanager
def store_entries_hidden(directory: Path) -> Iterator[None]:
    """Hides, while composing ``directory``'s tree, the ``ConfigStore`` groups that are also groups
    of its own (``env``, ``optimizer``, ``logger``, ...; Hydra's own ``hydra`` group stays).

    Other libraries store options under the same group names, such as TorchRL's trainer configs
    (``env/gym``, ``optimizer/adam``, ``optimizer/lbfgs``, ``logger/trackio``, ...). Hydra (1.3
    still) would merge an entry of the same path into our YAML file as its schema (its deprecated
    "automatic schema matching") and fail the composition, and would offer the others as options
    of our groups, which our schemas do not check. Our files name their schemas themselves
    (``/schema/<group>/<option>``). The groups are back in the store afterwards.

    Args:
        directory: the config tree being composed.

    Examples:
        >>> import torchrl.trainers.algorithms.configs  # stores env/gym, optimizer/lbfgs, logger/csv, ...
        >>> store = ConfigStore.instance().repo
        >>> with store_entries_hidden(CONF_DIR):
        ...     "optimizer" in store, "schema" in store
        (False, True)
        >>> "lbfgs.yaml" in store["optimizer"]
        True
    """
    repo = ConfigStore.instance().repo
    own = {path.name for path in directory.iterdir() if path.is_dir() and path.name != "hydra"}
    hidden = {group: repo.pop(group) for group in own & set(repo)}
    try:
        yield
    finally:
        repo.update(hidden)
