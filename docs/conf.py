"""Sphinx configuration of the documentation site.

Build (warnings are errors): ``python -m sphinx -W --keep-going -b html docs docs/_build/html``.

Pages are Markdown (MyST). The reproduction pages include the files the analysis scripts write
(``docs/table1/``, ``docs/study/ballcatch/``, ``docs/ppo/``) with ``{include}``: those folders are not
pages of their own. The API reference is generated at build time from ``sde_torchrl.__all__`` by
the local extension ``_ext/public_api.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent))  # document the checkout, not another installed copy
sys.path.insert(0, str(DOCS / "_ext"))

project = "sde_torchrl"
author = "The sde_torchrl developers"
copyright = "the sde_torchrl developers"  # noqa: A001 (Sphinx's name)

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "public_api",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
# the generated files are included by the reproduction pages, not pages of their own
exclude_patterns = ["_build", "table1/**", "study/ballcatch/**", "ppo/**"]

myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "signature"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False

html_theme = "furo"
html_title = "sde_torchrl"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False
