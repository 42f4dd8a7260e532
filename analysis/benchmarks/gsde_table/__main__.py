"""``python -m analysis.benchmarks.gsde_table``: the table's command line (:mod:`.cli`)."""

from __future__ import annotations

import sys

from analysis.benchmarks.gsde_table.cli import main

if __name__ == "__main__":
    sys.exit(main())
