"""The check at a job's end: its final policy and its best one (by the periodic evaluations,
:class:`~sde_torchrl.trainers.best.BestPolicy`) each run on the same fresh deterministic
episodes, drawn from the runs' own ``final_eval`` streams, apart from training and from the
periodic evaluations. The best policy was chosen by a few noisy evaluations; these episodes are
what says how good it is.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from sde_torchrl.trainers.best import BestPolicy

#: The policies checked, in the order they are run.
CHECKED = ("final", "best")


def run_final_check(
    make_env: Callable[[int], EnvBase], episodes: int, chunk: int, best: BestPolicy,
    rollout: Callable[[EnvBase], TensorDictBase], returns: Callable[[TensorDictBase], torch.Tensor],
) -> dict[str, Any]:
    """Each run's final and best policies on the same ``episodes`` fresh episodes.

    Args:
        make_env: builds the check env with a ``[runs, n]`` batch on the ``final_eval``
            streams; built anew for each policy, so that both meet the same episodes.
        episodes: fresh episodes per run and policy.
        chunk: the most episodes per run simulated at once (the env is rolled until ``episodes``
            are collected: memory stays that of the periodic evaluation).
        best: the runs' best policies; the module it keeps is the policy ``rollout`` runs.
        rollout: whole deterministic episodes of the policy on an env, ``[runs, n, T]``.
        returns: an episode's return in the job's definition, ``[runs, n]`` from episodes.

    Returns:
        ``{"episodes": E, "final": [runs][E] returns, "best": [runs][E]}``, and where the env
        reports what its episodes did (``episode_outcomes``), ``"outcomes"``: per policy, each
        outcome ``[runs][E]``.
    """
    per_roll = min(chunk, episodes)
    check: dict[str, Any] = {"episodes": episodes}
    for name in CHECKED:
        env = make_env(per_roll)
        try:
            if name == "best":
                with best.loaded():
                    collected = _collect(env, rollout, episodes, per_roll)
            else:
                collected = _collect(env, rollout, episodes, per_roll)
            check[name] = returns(collected).cpu().tolist()
            describe = getattr(getattr(env, "base_env", env), "episode_outcomes", None)
            if describe is not None:
                outcomes = describe(collected)
                check.setdefault("outcomes", {})[name] = {key: value.cpu().tolist() for key, value in outcomes.items()}
        finally:
            env.close(raise_if_closed=False)
    return check


def _collect(env: EnvBase, rollout: Callable[[EnvBase], TensorDictBase], episodes: int,
             per_roll: int) -> TensorDictBase:
    parts = [rollout(env) for _ in range(math.ceil(episodes / per_roll))]
    return torch.cat(parts, dim=1)[:, :episodes]


__all__ = ["CHECKED", "run_final_check"]
