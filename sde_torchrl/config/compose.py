"""The repository's Hydra config composed in Python, as ``train.py`` composes it.

For tests and the ``analysis/`` scripts, which build trainers or read sweep parameters without
going through ``train.py``'s command line.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig

from sde_torchrl.config.schemas import register_resolvers

#: ``conf/`` beside the package: where a clone installed in editable mode keeps its config tree.
CONF_DIR = Path(__file__).resolve().parents[2] / "conf"


def compose(
    overrides: Sequence[str] = (),
    config_dir: str | Path | None = None,
    *,
    return_hydra_config: bool = False,
) -> DictConfig:
    """The config ``train.py overrides...`` would run, with the config resolvers registered.

    Args:
        overrides: Hydra overrides, as on the command line (``"+experiment=minimize"``, ``"runs=2"``).
        config_dir: the config tree holding ``config.yaml``; default: the repository's ``conf/``
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
            f"config_dir={directory}: no config.yaml there; pass config_dir= the repository's conf/ "
            "(found by default only when sde_torchrl is installed from a clone in editable mode)"
        )
    register_resolvers()
    with initialize_config_dir(config_dir=str(directory), version_base="1.3"), store_entries_hidden(directory):
        return hydra_compose(config_name="config", overrides=list(overrides),
                             return_hydra_config=return_hydra_config)


@contextmanager
def store_entries_hidden(directory: Path) -> Iterator[None]:
    """Hides, while composing ``directory``'s tree, the ``ConfigStore`` entries that have the path of
    one of its YAML files.

    Hydra (1.3 still) merges a ``ConfigStore`` entry into the YAML file of the same path as its
    schema (its deprecated "automatic schema matching"). Our files name their schemas themselves
    (``/schema/<group>/<option>``); entries that other libraries store under the same paths, such
    as TorchRL's trainer configs (``env/gym``, ``optimizer/adam``, ``logger/csv``, ...), would
    otherwise be merged into ours and fail the composition. They are back in the store afterwards.

    Args:
        directory: the config tree being composed.

    Examples:
        >>> import torchrl.trainers.algorithms.configs  # stores env/gym, optimizer/adam, logger/csv, ...
        >>> env_options = ConfigStore.instance().repo["env"]
        >>> with store_entries_hidden(CONF_DIR):
        ...     "gym.yaml" in env_options
        False
        >>> "gym.yaml" in env_options
        True
    """
    repo, hidden = ConfigStore.instance().repo, []
    for path in directory.rglob("*.yaml"):
        *groups, name = path.relative_to(directory).parts
        node = repo
        for group in groups:
            node = node.get(group) if isinstance(node, dict) else None
        if isinstance(node, dict) and name in node:
            hidden.append((node, name, node.pop(name)))
    try:
        yield
    finally:
        for node, name, entry in hidden:
            node[name] = entry
