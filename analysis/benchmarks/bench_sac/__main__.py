"""``python -m analysis.benchmarks.bench_sac``: the benchmark's command line (:mod:`.cli`)."""

from __future__ import annotations

import sys

from analysis.benchmarks.bench_sac.cli import main

if __name__ == "__main__":
    sys.exit(main())
