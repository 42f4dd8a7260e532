"""Ball catching with ENAC, paper Fig. 6: ``analysis/fig5.py --estimator enac``.

Usage:
    python analysis/fig6.py --out results/fig6 SWEEP_DIR [more shards...]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fig5 import main  # noqa: E402 - the analysis scripts are run as files, not installed

if __name__ == "__main__":
    sys.exit(main(estimator="enac"))
