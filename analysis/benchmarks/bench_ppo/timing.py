"""Where a PPO iteration's time goes (``phases``): a timer of named phases, off unless ``phases``
switches it on, and Stable-Baselines3's update timed under the same names for the length of a block.

Examples:
    >>> timer = PhaseTimer()
    >>> with timer.timed("update"):  # off: nothing is added
    ...     pass
    >>> with timer.on() as seconds, timer.timed("update"):
    ...     pass
    >>> list(seconds), timer.active
    (['update'], False)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any
from unittest import mock

import torch


class PhaseTimer:
    """Seconds per named phase of training, added up while the timer is on (:meth:`on`); while it
    is off (the benchmark's runs), a timed block costs one check."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] | None = None
        self._mark = 0.0

    @property
    def active(self) -> bool:
        return self.seconds is not None

    @contextmanager
    def on(self) -> Iterator[dict[str, float]]:
        """Time the phases within the block into the dict it yields; off again after it."""
        self.seconds = {}
        try:
            yield self.seconds
        finally:
            self.seconds = None

    def restart(self) -> None:
        """Forget what was timed so far (the first iteration: warm-up, compilation)."""
        if self.seconds is not None:
            self.seconds.clear()

    def add(self, phase: str, seconds: float) -> None:
        if self.seconds is not None:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds

    @contextmanager
    def timed(self, phase: str) -> Iterator[None]:
        """Add the block's wall time to ``phase`` (nothing while the timer is off)."""
        if self.seconds is None:
            yield
            return
        start = time.perf_counter()
        yield
        self.add(phase, time.perf_counter() - start)

    def wrap(self, phase: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function`` with each call timed under ``phase`` (:meth:`timed`).

        Examples:
            >>> timer = PhaseTimer()
            >>> with timer.on() as seconds:
            ...     timer.wrap("update", abs)(-2), list(seconds)
            (2, ['update'])
        """

        def call(*args: Any, **kwargs: Any) -> Any:
            with self.timed(phase):
                return function(*args, **kwargs)

        return call

    def mark(self, phase: str | None) -> None:
        """Add the time since the last mark to ``phase`` (SB3's phases, between its callbacks)."""
        now = time.perf_counter()
        if phase is not None:
            self.add(phase, now - self._mark)
        self._mark = now


#: The benchmark's timer: on while ``phases`` times an iteration.
TIMER = PhaseTimer()


@contextmanager
def sb3_update_timed(model, timer: PhaseTimer = TIMER) -> Iterator[None]:
    """Within the block, time the parts of SB3's PPO update under the names of the TorchRL update's:
    the policy's forward, the gradient clip and the Adam step (backward is what is left of the
    minibatch step).

    SB3 calls ``torch.nn.utils.clip_grad_norm_`` by that name, so the timed clip stands in there;
    the block's end puts back torch's function and the model's own ``evaluate_actions`` and
    ``step``, also when the block raises.

    Args:
        model: an SB3 ``PPO`` (what is read: ``model.policy`` and ``model.policy.optimizer``).
        timer: where the seconds go.

    Examples:
        >>> from types import SimpleNamespace
        >>> optimizer = torch.optim.SGD([torch.zeros(1, requires_grad=True)])
        >>> model = SimpleNamespace(policy=SimpleNamespace(evaluate_actions=len, optimizer=optimizer))
        >>> clip = torch.nn.utils.clip_grad_norm_
        >>> with sb3_update_timed(model):
        ...     torch.nn.utils.clip_grad_norm_ is clip
        False
        >>> torch.nn.utils.clip_grad_norm_ is clip, model.policy.evaluate_actions is len, "step" in vars(optimizer)
        (True, True, False)
    """
    policy, optimizer = model.policy, model.policy.optimizer
    with ExitStack() as patches:
        for owner, name, phase in ((policy, "evaluate_actions", "update: loss forward"),
                                   (optimizer, "step", "update: clip + Adam step"),
                                   (torch.nn.utils, "clip_grad_norm_", "update: clip + Adam step")):
            patches.enter_context(mock.patch.object(owner, name, timer.wrap(phase, getattr(owner, name))))
        yield
