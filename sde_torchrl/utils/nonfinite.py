"""The one non-finite policy: what every layer does with a NaN or an infinity it is handed.

Two policies (:data:`~sde_torchrl.utils.options.NONFINITE_POLICIES`):

- ``"raise"``, the default: a layer called directly (an estimator on episodes, ``MinimizeEnv`` on
  actions) raises :class:`~sde_torchrl.utils.checks.NonFiniteInputError` (or a subclass) at the
  first NaN or infinity, naming the tensor, the batch entries concerned and the fix;
- ``"guarded"``: the layers let them through (the estimate is then NaN for the runs concerned),
  because a guard that knows more checks the results itself. The trainer enters it around its
  rollouts and updates: its :class:`~sde_torchrl.trainers.guard.FiniteGuard` names the update,
  the runs and the parameter, and stops the job with the updates before it kept.

The policy is set in one place, :func:`nonfinite_policy`, and read by :func:`check_finite`, which
the layers call; no layer takes an option for it. It lives in a :class:`contextvars.ContextVar`:
it holds for the code inside the ``with`` block (and what it calls) in this thread or task, is
restored when the block is left, also on an exception, and does not reach other threads or
worker processes (a ``ParallelEnv``'s workers follow their own, the default).

Standard library only: the tensor check calls the tensor's own methods.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

from sde_torchrl.utils.checks import ArgumentError, NonFiniteInputError, batch_entries
from sde_torchrl.utils.options import NONFINITE_POLICIES

_POLICY: ContextVar[str] = ContextVar("sde_torchrl_nonfinite_policy", default="raise")

#: The end of every ``"raise"`` message's fix: how to let the values through instead.
GUARDED_FIX = 'or call it inside `with sde_torchrl.nonfinite_policy("guarded"):` to let them through'


def current_nonfinite_policy() -> str:
    """The policy in force here: ``"raise"`` (the default) or ``"guarded"``.

    Examples:
        >>> current_nonfinite_policy()
        'raise'
        >>> with nonfinite_policy("guarded"):
        ...     current_nonfinite_policy()
        'guarded'
    """
    return _POLICY.get()


@contextmanager
def nonfinite_policy(policy: str) -> Iterator[None]:
    """Sets the non-finite policy for the code inside the block; the previous one comes back after it.

    Args:
        policy: ``"raise"`` (every layer raises at the first NaN or infinity, naming it) or
            ``"guarded"`` (the layers let them through: a guard of the caller's checks the results,
            as the trainer's does).

    Yields:
        Nothing; the block runs under ``policy``.

    Raises:
        ArgumentError: ``policy`` is not one of those two (before the block runs).

    Examples:
        >>> import torch
        >>> with nonfinite_policy("guarded"):
        ...     check_finite("action", torch.tensor([float("nan")]))  # passes: the caller guards
        >>> current_nonfinite_policy()
        'raise'
        >>> with nonfinite_policy("ignore"):
        ...     pass
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: nonfinite_policy=ignore: one of raise (stop at the first NaN/inf, ...
    """
    if not isinstance(policy, str) or policy not in NONFINITE_POLICIES:
        raise ArgumentError("nonfinite_policy", policy, "one of raise (stop at the first NaN/inf, naming it), "
                                                        "guarded (let them through to a guard of your own)")
    token = _POLICY.set(policy)
    try:
        yield
    finally:
        _POLICY.reset(token)


def check_finite(
    name: str, value: Any, labels: Sequence[str] = (), fix: str = "", *,
    error: Callable[[str, str, str], Exception] = NonFiniteInputError,
) -> None:
    """Raises if ``value`` holds NaN or infinity, unless the policy is ``"guarded"``.

    One fused check over the whole tensor; the entries are located only on failure. A tensor that
    is neither floating point nor complex is finite by its type and is not read.

    Args:
        name: the tensor, as the message names it (``action``, ``episodes key 'observation'``).
        value: the tensor; its leading dimensions are the batch, one per label.
        labels: the name of each leading batch dimension (``("run", "episode")``); none: the
            message says ``the batch``.
        fix: what to do about it; :data:`GUARDED_FIX` is the usual end.
        error: builds the exception from ``(name, where, fix)``:
            :class:`~sde_torchrl.utils.checks.NonFiniteInputError` or a subclass (a
            ``functools.partial`` for one that takes more).

    Raises:
        NonFiniteInputError: (``error``'s type) naming ``name``, the batch entries and ``fix``,
            under the policy ``"raise"``.

    Examples:
        >>> import torch
        >>> check_finite("action", torch.tensor([[0.0], [float("nan")]]), ("episode",), "check the policy")
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.NonFiniteInputError: action: NaN/inf in episode 1; check the policy
    """
    if _POLICY.get() == "guarded" or not (value.is_floating_point() or value.is_complex()):
        return
    finite = value.isfinite()
    if bool(finite.all()):
        return
    kept = len(labels)
    where = batch_entries(~finite.reshape(*value.shape[:kept], -1).all(-1), labels) if kept else "the batch"
    raise error(name, where, fix)
