"""The scripts around the library, by kind; each runs as ``python -m analysis.<kind>.<script>``
from the checkout's root.

- :mod:`analysis.benchmarks`: speed and learning against other libraries (Stable-Baselines3) and
  raw pybullet;
- :mod:`analysis.paper`: the paper's tables and figures, and the ball-catching diagnostics, from
  committed runs;
- :mod:`analysis.selection`: the tools that chose the learners the reproductions run.

What they share: :mod:`analysis.figures` (line styles, saved figures, two-sample statistics) and
:mod:`analysis.runner` (the pool that runs their training jobs).
"""
