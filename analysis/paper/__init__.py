"""The paper's reproductions from committed runs: Table 1 and Figs. 2, 3 (``table1``), Figs. 5
and 6 (``fig5``, ``fig6``) and the ball-catching diagnostics (``ballcatch_*``); each runs as
``python -m analysis.paper.<name>``."""
