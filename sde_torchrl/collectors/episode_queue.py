"""The episode queue of the paper's ball-catching experiment (section 4.2).

"Fill a queue with 20 exploratory episodes; each update uses the queue, after which the oldest
episode is dropped and a new rollout is added." Generalised to ``N`` new episodes per update:
the queue holds the last ``Q`` episodes of each run (``Q`` a multiple of ``N``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from sde_torchrl.utils.checks import multiple_of


class EpisodeQueue:
    """The last ``size`` episodes of each run, renewed by ``per_update`` episodes per update.

    Only the keys the estimator reads are kept (the queue is checkpointed).

    Args:
        size: ``Q``, episodes per run in the queue.
        per_update: ``N``, new episodes per run and update (``Q`` must be a multiple of it).
        keys: the entries to keep.
        device: where a restored queue (:meth:`load_state_dict`, read from a checkpoint on the
            CPU) is put: the device of the episodes it holds. ``None``: left where it is read.

    Examples:
        >>> queue = EpisodeQueue(4, 2, ["x"])
        >>> new = lambda: TensorDict({"x": torch.rand(1, 2, 3)}, batch_size=[1, 2, 3])
        >>> queue.next_batch(new).batch_size
        torch.Size([1, 4, 3])
    """

    def __init__(self, size: int, per_update: int, keys: Sequence[NestedKey],
                 device: torch.device | str | None = None) -> None:
        multiple_of("episode_queue", size, "episodes_per_update", per_update)
        self.size, self.per_update, self.keys, self.device = size, per_update, list(keys), device
        self.episodes: TensorDictBase | None = None

    def next_batch(self, collect: Callable[[], TensorDictBase]) -> TensorDictBase:
        """The episodes of the next update: at first ``Q / N`` collections, then the queue
        without its oldest ``N`` episodes per run and with ``N`` new ones."""
        if self.episodes is None:
            fill = [self._kept(collect()) for _ in range(self.size // self.per_update)]
            self.episodes = torch.cat(fill, dim=1)
        else:
            self.episodes = torch.cat([self.episodes[:, self.per_update:], self._kept(collect())], dim=1)
        return self.episodes

    def _kept(self, episodes: TensorDictBase) -> TensorDictBase:
        return episodes.select(*self.keys)

    def state_dict(self) -> dict[str, Any] | None:
        """The queued episodes as nested tensors (``None`` before the first batch)."""
        return None if self.episodes is None else self.episodes.to_dict()

    def load_state_dict(self, state: dict[str, Any] | None, batch_size: Sequence[int],
                        nested: Mapping[str, Sequence[int]] | None = None) -> None:
        """Restores :meth:`state_dict`; ``batch_size`` is ``[runs, Q, T]``, or ``[runs, Q]`` for
        entries kept per episode, with ``nested`` giving the batch size of each nested
        TensorDict whose batch is longer where the state holds it (``{"episodes": [runs, Q, T]}``;
        a dotted name for a deeper one)."""
        if state is None:
            self.episodes = None
            return
        self.episodes = TensorDict(state, batch_size=list(batch_size))
        for name, size in (nested or {}).items():
            key = tuple(name.split("."))
            if key not in self.episodes.keys(include_nested=True):
                continue
            self.episodes.set(key, TensorDict(self.episodes.get(key).to_dict(), batch_size=list(size)))
        if self.device is not None:
            self.episodes = self.episodes.to(self.device)
