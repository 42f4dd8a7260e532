"""Appends ``analysis/conf/`` to Hydra's config search path, after the library's ``sde_torchrl/conf/``.

The study's selection rounds, probes and sweep shards live there (``analysis/conf/experiment/``) and
still compose as ``+experiment=NAME``; their ``defaults:`` name the library's experiments, which
Hydra finds in the primary tree. The path is this file's clone, not the working directory.
"""

from __future__ import annotations

from pathlib import Path

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin

#: ``analysis/conf/`` of the clone holding this plugin.
STUDY_CONF_DIR = Path(__file__).resolve().parents[2] / "analysis" / "conf"


class StudySearchPathPlugin(SearchPathPlugin):
    """Adds the study's config tree to every composition (``train.py``'s and ``compose()``'s)."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if STUDY_CONF_DIR.is_dir():
            search_path.append(provider="sde_torchrl_study", path=f"file://{STUDY_CONF_DIR}")
