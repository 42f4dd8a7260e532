"""Ball catching with ENAC, paper Fig. 6: ``analysis/paper/fig5.py --estimator enac``.

Usage:
    python -m analysis.paper.fig6 --out results/fig6 SWEEP_DIR [more shards...]
"""

from __future__ import annotations

import sys

from analysis.paper import fig5


def main(argv: list[str] | None = None) -> int:
    """:func:`fig5.main` with ENAC's runs: ``fig6.json``, ``fig6.md`` and ``fig6.png``."""
    return fig5.main(argv, estimator="enac", prog=f"python -m {__spec__.name}")


if __name__ == "__main__":
    sys.exit(main())
