"""Ball catching with ENAC, paper Fig. 6: ``analysis/fig5.py --estimator enac``.

Usage:
    python analysis/fig6.py --out results/fig6 SWEEP_DIR [more shards...]
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

if __name__ == "__main__":
    fig5 = runpy.run_path(str(Path(__file__).with_name("fig5.py")))  # a sibling script, not a module
    sys.exit(fig5["main"](estimator="enac"))
