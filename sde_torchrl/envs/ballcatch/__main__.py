"""``python -m sde_torchrl.envs.ballcatch``: the demo (:mod:`sde_torchrl.envs.ballcatch.demo`)."""

from __future__ import annotations

from sde_torchrl.envs.ballcatch.demo import main

main()
