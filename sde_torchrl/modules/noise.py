"""SDE's noise: the one place the noise matrix ``ξ`` (and eq. 22's ``ε``) is drawn, and its schedule.

The exploration matrix is ``Θ̂ = σ̂ ⊙ ξ`` with ``ξ ~ N(0, I)`` (eq. 18), held for a whole
episode (SDE), redrawn at every step (REX, the paper's random-exploration baseline, section 4.1)
or every ``n`` steps (gSDE's sampling frequency). :class:`SDENoisePrimer`, an env transform,
keeps ``ξ`` in the tensordict and owns that schedule; its tensor-level methods
(:meth:`~SDENoisePrimer.start`, :meth:`~SDENoisePrimer.advance`) are what the fast collection
paths call, so every way of collecting draws the same numbers. :func:`draw_noise` is the draw.

The stream is consumed the same way under every schedule: one ``ξ`` (then one ``ε`` with eq.
22's part) per step from an episode's start, the first at the reset, each later one after a
step that some episode of the batch goes on from. The schedule only decides which draws are
used: SDE keeps the first for the episode, REX uses each. Two learners on the same seed thus see
the same numbers whatever their schedule.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, expand_as_right
from torchrl.data import Composite, Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.envs.transforms.utils import _get_reset
from torchrl.envs.utils import ExplorationType, exploration_type

from sde_torchrl.utils.checks import noise_schedule, positive_int
from sde_torchrl.utils.rng import RunStreams, draw_normal

_DETERMINISTIC = (ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN)

#: What to do when a policy finds no noise in its input.
ADD_PRIMER = (
    "append sde.make_tensordict_primer() to the env (TransformedEnv(env, sde.make_tensordict_primer())), "
    "or pass auto_register_policy_transforms=True to torchrl's Collector"
)


def deterministic_exploration() -> bool:
    """Whether TorchRL's exploration type asks for the mean action (``DETERMINISTIC``, ``MODE``
    or ``MEAN``): then no noise is drawn and none is added.

    Examples:
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> with set_exploration_type(ExplorationType.DETERMINISTIC):
        ...     deterministic_exploration()
        True
    """
    return exploration_type() in _DETERMINISTIC


def draw_noise(
    shape: Sequence[int], streams: RunStreams | None = None, *, dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Standard-normal SDE noise of ``shape``: ``ξ`` (``[*batch, A, S]``) or eq. (22)'s ``ε``.

    Args:
        shape: the shape, runs first when ``streams`` is given.
        streams: per-run streams over the leading dimension, or ``None`` for torch's global
            generator.
        dtype: the policy's dtype.
        device: the data's device.

    Returns:
        The draw, on ``device``.

    Examples:
        >>> draw_noise((3, 2, 4), RunStreams(seed=0, runs=3, stream="explore")).shape
        torch.Size([3, 2, 4])
    """
    return draw_normal(shape, streams).to(dtype=dtype, device=device)


class SDENoisePrimer(TensorDictPrimer):
    """Env transform carrying the SDE noise ``ξ`` (``[A, S]`` per env) and its schedule.

    At every full or partial reset the reset envs get a fresh standard-normal ``ξ`` (and
    ``sde_age = 0``); after each step ``ξ`` is held (``"episode"``: the paper's SDE), redrawn
    (``"step"``: REX, paper section 4.1) or redrawn once ``n`` steps have used it (``"every_n"``,
    gSDE's sampling frequency). With ``gaussian``, eq. (22)'s i.i.d. ``ε`` (``[A]`` per env) is
    redrawn at every step. Under deterministic exploration nothing is drawn. Being a
    ``TensorDictPrimer``, TorchRL's ``Collector`` recognises it and does not add it twice.

    Args:
        action_dim: ``A``.
        feature_dim: ``S``.
        schedule: ``"episode"``, ``"step"`` or ``"every_n"``.
        every_n: redraw period for ``"every_n"``.
        gaussian: carry eq. (22)'s i.i.d. Gaussian noise ``ε`` too.
        noise_key: the tensordict key of ``ξ``.
        gaussian_noise_key: the key of ``ε``.
        age_key: steps the current ``ξ`` has been used (``"every_n"`` only).
        dtype: dtype of the noise (the policy's).
        streams: per-run streams over the env's leading batch dimension, or ``None`` for torch's
            global generator.
        done_key: the env's done flags: after a step that ends every episode of the batch
            nothing is drawn (the reset draws).

    Raises:
        ArgumentError: for an option that is not allowed, named.

    Examples:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), SDENoisePrimer(1, 3, schedule="step"))
        >>> env.reset()["sde_noise"].shape
        torch.Size([1, 3])
    """

    def __init__(
        self,
        action_dim: int,
        feature_dim: int,
        *,
        schedule: str = "episode",
        every_n: int | None = None,
        gaussian: bool = False,
        noise_key: NestedKey = "sde_noise",
        gaussian_noise_key: NestedKey = "sde_gaussian_noise",
        age_key: NestedKey = "sde_age",
        dtype: torch.dtype = torch.float32,
        streams: RunStreams | None = None,
        done_key: NestedKey = "done",
    ) -> None:
        noise_schedule(schedule, every_n)
        self.action_dim = positive_int("action_dim", action_dim)
        self.feature_dim = positive_int("feature_dim", feature_dim)
        specs = {noise_key: Unbounded(shape=(action_dim, feature_dim), dtype=dtype)}
        if gaussian:
            specs[gaussian_noise_key] = Unbounded(shape=(action_dim,), dtype=dtype)
        if schedule == "every_n":
            specs[age_key] = Unbounded(shape=(1,), dtype=torch.int64)
        super().__init__(Composite(specs), default_value=0, expand_specs=True)
        self.schedule, self.every_n, self.gaussian, self.streams = schedule, every_n, gaussian, streams
        self.noise_key, self.gaussian_noise_key, self.age_key = noise_key, gaussian_noise_key, age_key
        self.noise_dtype, self.done_key = dtype, done_key

    # ------------------------------------------------------------------ the draws, on tensors
    def draw(self, batch: Sequence[int], device: torch.device | str | None = None
             ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One step's fresh draws for a batch: ``ξ [*batch, A, S]``, then ``ε [*batch, A]`` (or
        ``None`` without eq. 22's part)."""
        batch = tuple(batch)
        noise = draw_noise((*batch, self.action_dim, self.feature_dim), self.streams, dtype=self.noise_dtype,
                           device=device)
        gaussian = (draw_noise((*batch, self.action_dim), self.streams, dtype=self.noise_dtype, device=device)
                    if self.gaussian else None)
        return noise, gaussian

    def start(self, batch: Sequence[int], device: torch.device | str | None = None
              ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The noise of a fresh episode for every batch element (what a full reset writes).

        Returns:
            ``(ξ, ε, age)``; ``ε`` is ``None`` without eq. (22)'s part, ``age`` (zeros,
            ``[*batch, 1]``) is ``None`` unless ``"every_n"``.

        Examples:
            >>> primer = SDENoisePrimer(2, 3, schedule="every_n", every_n=2)
            >>> noise, gaussian, age = primer.start((4,))
            >>> noise.shape, gaussian, age.shape
            (torch.Size([4, 2, 3]), None, torch.Size([4, 1]))
        """
        noise, gaussian = self.draw(batch, device)
        age = torch.zeros(*batch, 1, dtype=torch.int64, device=device) if self.schedule == "every_n" else None
        return noise, gaussian, age

    def advance(
        self, noise: torch.Tensor, gaussian: torch.Tensor | None, age: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The noise for the next step of running episodes: one fresh draw, used as the schedule says.

        Args:
            noise: this step's ``ξ``, ``[*batch, A, S]``.
            gaussian: this step's ``ε`` or ``None``.
            age: steps ``ξ`` has been used before this one (``"every_n"``), else ``None``.

        Returns:
            ``(ξ, ε, age)`` for the next step.

        Examples:
            >>> primer = SDENoisePrimer(1, 1, schedule="every_n", every_n=2)
            >>> noise, gaussian, age = primer.start((1,))
            >>> second = primer.advance(noise, gaussian, age)
            >>> third = primer.advance(*second)
            >>> bool(second[0] == noise), bool(third[0] == noise), third[2].item()
            (True, False, 0)
        """
        fresh, gaussian = self.draw(noise.shape[:-2], noise.device)
        if self.schedule == "step":
            return fresh, gaussian, age
        if self.schedule == "episode":
            return noise, gaussian, age
        age = age + 1
        redraw = age >= self.every_n
        return torch.where(redraw.unsqueeze(-1), fresh, noise), gaussian, torch.where(redraw, 0, age)

    # --------------------------------------------------------------------- the env transform
    def _reset_func(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset = super()._reset_func(tensordict, tensordict_reset)
        noise = tensordict_reset.get(self.noise_key, None)
        if noise is None or deterministic_exploration():  # absent when no env is reset
            return tensordict_reset
        reset = _get_reset(self.reset_key, tensordict)
        fresh, gaussian, age = self.start(noise.shape[:-2], noise.device)
        tensordict_reset.set(self.noise_key, torch.where(expand_as_right(reset, fresh), fresh, noise))
        if gaussian is not None:
            old = tensordict_reset.get(self.gaussian_noise_key)
            tensordict_reset.set(self.gaussian_noise_key, torch.where(expand_as_right(reset, gaussian), gaussian, old))
        if age is not None:
            tensordict_reset.set(self.age_key, torch.where(expand_as_right(reset, age), age,
                                                           tensordict_reset.get(self.age_key)))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = super()._step(tensordict, next_tensordict)  # carries the noise (and age) over
        done = next_tensordict.get(self.done_key, None)
        if deterministic_exploration() or (done is not None and bool(done.all())):
            return next_tensordict
        noise, gaussian, age = self.advance(next_tensordict.get(self.noise_key),
                                            next_tensordict.get(self.gaussian_noise_key, None),
                                            next_tensordict.get(self.age_key, None))
        next_tensordict.set(self.noise_key, noise)
        if gaussian is not None:
            next_tensordict.set(self.gaussian_noise_key, gaussian)
        if age is not None:
            next_tensordict.set(self.age_key, age)
        return next_tensordict


__all__ = ["SDENoisePrimer", "deterministic_exploration", "draw_noise"]
