"""Sphinx extension: the API page lists every name of ``sde_torchrl.__all__``, read at build time.

The page ``api/index.md`` holds the line ``<!-- public-api -->``; when Sphinx reads that page this
extension replaces the line with a summary table and one autodoc entry per public name, grouped by
the subpackage that defines it. A name added to, renamed in or removed from ``__all__`` changes the
page with no edit to the docs (``tests/test_docs.py`` checks that every name has its entry).
"""

from __future__ import annotations

import importlib
import inspect

PLACEHOLDER = "<!-- public-api -->"
PAGE = "api/index"
# the layers of docs/ARCHITECTURE.md, in its order; a subpackage missing here goes last
LAYERS = {
    "modules": "Policies and exploration (`sde_torchrl.modules`)",
    "objectives": "Gradient estimators (`sde_torchrl.objectives`)",
    "envs": "Environments (`sde_torchrl.envs`)",
    "collectors": "Collecting episodes (`sde_torchrl.collectors`)",
    "trainers": "Training (`sde_torchrl.trainers`)",
    "jobs": "Jobs and run directories (`sde_torchrl.jobs`)",
    "config": "Configuration (`sde_torchrl.config`)",
    "utils": "Utilities (`sde_torchrl.utils`)",
}


def public_names(package: str = "sde_torchrl") -> list[str]:
    """The names of ``package.__all__``, in its order."""
    return list(importlib.import_module(package).__all__)


def _layer(obj: object) -> str:
    parts = (getattr(obj, "__module__", None) or "").split(".")
    return parts[1] if len(parts) > 2 else "other"


def summary_line(obj: object) -> str:
    """The first paragraph of ``obj``'s docstring, on one line (the table's description)."""
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n")[0].split())


def _signature(app, what, name, obj, options, signature, return_annotation):
    """A class whose base defines ``__new__(cls, *args, **kwargs)`` (tensordict's modules) shows its
    ``__init__``'s parameters instead of ``(*args, **kwargs)``; annotations stay in the docstring's Args."""
    if what != "class" or signature != "(*args, **kwargs)":
        return None
    try:
        parameters = list(inspect.signature(obj.__init__).parameters.values())[1:]
    except (TypeError, ValueError):
        return None
    bare = [p.replace(annotation=inspect.Parameter.empty) for p in parameters]
    return str(inspect.Signature(bare)), None


def api_markdown(package: str = "sde_torchrl") -> str:
    """The MyST text that replaces the placeholder: a summary table, then the entries by layer."""
    module = importlib.import_module(package)
    groups: dict[str, list[str]] = {}
    for name in public_names(package):
        groups.setdefault(_layer(getattr(module, name)), []).append(name)
    order = [layer for layer in LAYERS if layer in groups] + sorted(set(groups) - set(LAYERS))
    lines = ["```{eval-rst}", ".. list-table::", "   :header-rows: 1", "   :widths: 30 70", "",
             "   * - name", "     - what it is"]
    for layer in order:
        for name in groups[layer]:
            lines += [f"   * - :py:obj:`{package}.{name}`", f"     - {summary_line(getattr(module, name))}"]
    lines += ["```", ""]
    for layer in order:
        lines += [f"## {LAYERS.get(layer, f'`{package}.{layer}`')}", ""]
        for name in groups[layer]:
            kind = "autoclass" if inspect.isclass(getattr(module, name)) else "autofunction"
            lines += ["```{eval-rst}", f".. {kind}:: {package}.{name}", "```", ""]
    return "\n".join(lines)


def _source_read(app, docname: str, source: list[str]) -> None:
    if docname == PAGE:
        if PLACEHOLDER not in source[0]:
            raise ValueError(f"{PAGE}.md lost its placeholder line {PLACEHOLDER}")
        source[0] = source[0].replace(PLACEHOLDER, api_markdown())


def setup(app):
    app.connect("source-read", _source_read)
    app.connect("autodoc-process-signature", _signature)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
