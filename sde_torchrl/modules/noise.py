"""SDE's noise: the one place the noise matrix ``ξ`` (and eq. 22's ``ε``) is drawn, and its schedule.

The exploration matrix is ``Θ̂ = σ̂ ⊙ ξ`` with ``ξ ~ N(0, I)`` (eq. 18). :class:`SDENoisePrimer`,
an env transform, keeps ``ξ`` in the tensordict and owns its schedule: held for a whole episode
(SDE), redrawn at every step (REX, the paper's random-exploration baseline, section 4.1) or every
``n`` steps of an episode; or counted over a rollout across episode boundaries, as
Stable-Baselines3 counts its ``sde_sample_freq`` (``every_n_steps``, ``rollout``). Its
tensor-level methods (:meth:`~SDENoisePrimer.start`, :meth:`~SDENoisePrimer.advance`) are what
the fast collection paths call, so every way of collecting draws the same numbers;
:func:`draw_noise` is the draw. The schedule's and the keys' defaults (:data:`DEFAULT_SCHEDULE`,
:data:`NOISE_KEY` and the keys after it) are defined here, for
:class:`~sde_torchrl.modules.sde.SDEParams` too.
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
from sde_torchrl.utils.options import ROLLOUT_SCHEDULES
from sde_torchrl.utils.rng import RunStreams, draw_normal

_DETERMINISTIC = (ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN)

#: The default schedule of :class:`SDENoisePrimer` and :class:`~sde_torchrl.modules.sde.SDEParams`:
#: ``ξ`` held for a whole episode, the paper's SDE.
DEFAULT_SCHEDULE = "episode"
#: The tensordict keys of the carried noise, by default: ``ξ``, eq. (22)'s ``ε`` and the schedule's
#: step count (``sde_age``).
NOISE_KEY, GAUSSIAN_NOISE_KEY, AGE_KEY = "sde_noise", "sde_gaussian_noise", "sde_age"

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
    (``"step"``: REX, paper section 4.1) or redrawn once ``n`` steps of the episode have used it
    (``"every_n"``). With ``gaussian``, eq. (22)'s i.i.d. ``ε`` (``[A]`` per env) is redrawn at
    every step. Under deterministic exploration nothing is drawn. Being a ``TensorDictPrimer``,
    TorchRL's ``Collector`` recognises it and does not add it twice.

    The random stream is consumed the same way under every schedule: one ``ξ`` (then one ``ε``
    with eq. 22's part) per step from an episode's start, the first at the reset, each later one
    after a step that some episode of the batch goes on from. The schedule only decides which
    draws are used (SDE keeps the first for the episode, REX uses each), so two learners on the
    same seed see the same numbers whatever their schedule (the SB3-style schedules also draw
    after a step that ends every episode, since their ``ξ`` goes on through the reset).

    SB3's ``sde_sample_freq`` counts collected steps over a rollout, not over an episode; the
    schedules ``"every_n_steps"`` (``sde_sample_freq=n``) and ``"rollout"``
    (``sde_sample_freq=-1``) do the same: ``ξ`` and the count (``sde_age``, steps since the
    rollout began) go on through episode boundaries, and ``ξ`` is redrawn before the rollout's
    steps ``0, n, 2n, ...`` (``"every_n_steps"``) and, with ``rollout_steps=R``, before every
    ``R``-th step (a new rollout: the count restarts). The reset of done envs during a
    collection (TorchRL's ``maybe_reset``) keeps ``ξ`` and the count; an explicit reset
    (``env.reset()``, the start of ``env.rollout`` or of a ``Collector``) starts a new rollout.
    With TorchRL's ``Collector`` set ``rollout_steps = frames_per_batch // num_envs``; in a
    hand-written loop, call :meth:`resample` at the start of each rollout instead (SB3's
    ``reset_noise``).

    Args:
        action_dim: ``A``.
        feature_dim: ``S``.
        schedule: ``"episode"``, ``"step"``, ``"every_n"``, ``"every_n_steps"`` or ``"rollout"``.
        every_n: redraw period for ``"every_n"`` and ``"every_n_steps"``.
        rollout_steps: steps per rollout for ``"every_n_steps"`` and ``"rollout"`` (the count
            restarts and ``ξ`` is redrawn every ``rollout_steps`` steps), or ``None``: one rollout
            until :meth:`resample` or a reset without carried noise.
        gaussian: carry eq. (22)'s i.i.d. Gaussian noise ``ε`` too.
        noise_key: the tensordict key of ``ξ``.
        gaussian_noise_key: the key of ``ε``.
        age_key: steps the current ``ξ`` has been used (``"every_n"``), or steps since the rollout
            began (``"every_n_steps"``, ``"rollout"``); absent otherwise.
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
        >>> sb3 = TransformedEnv(GymEnv("Pendulum-v1"), SDENoisePrimer(1, 3, schedule="every_n_steps", every_n=4))
        >>> td = sb3.rollout(10, break_when_any_done=False)
        >>> td["sde_age"].flatten().tolist()  # steps into the rollout when each action was taken
        [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    """

    def __init__(
        self,
        action_dim: int,
        feature_dim: int,
        *,
        schedule: str = DEFAULT_SCHEDULE,
        every_n: int | None = None,
        rollout_steps: int | None = None,
        gaussian: bool = False,
        noise_key: NestedKey = NOISE_KEY,
        gaussian_noise_key: NestedKey = GAUSSIAN_NOISE_KEY,
        age_key: NestedKey = AGE_KEY,
        dtype: torch.dtype = torch.float32,
        streams: RunStreams | None = None,
        done_key: NestedKey = "done",
    ) -> None:
        noise_schedule(schedule, every_n, rollout_steps=rollout_steps)
        self.action_dim = positive_int("action_dim", action_dim)
        self.feature_dim = positive_int("feature_dim", feature_dim)
        specs = {noise_key: Unbounded(shape=(action_dim, feature_dim), dtype=dtype)}
        if gaussian:
            specs[gaussian_noise_key] = Unbounded(shape=(action_dim,), dtype=dtype)
        if schedule not in ("episode", "step"):
            specs[age_key] = Unbounded(shape=(1,), dtype=torch.int64)
        super().__init__(Composite(specs), default_value=0, expand_specs=True)
        self.schedule, self.every_n, self.gaussian, self.streams = schedule, every_n, gaussian, streams
        self.rollout_steps = rollout_steps
        #: Whether ``ξ`` and the count go on through resets (SB3's counting over a rollout).
        self.counts_rollout = schedule in ROLLOUT_SCHEDULES
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

    def episode_noise(self, batch: Sequence[int], steps: int, device: torch.device | str | None = None
                      ) -> torch.Tensor | None:
        """The ``ξ`` of every step of fresh episodes in one draw, or ``None`` where one draw cannot
        give them.

        :meth:`start` then ``steps - 1`` calls of :meth:`advance` draw ``steps`` times
        ``[*batch, A, S]``; per-run streams serve each run its numbers in order, so one draw of
        ``[runs, steps, *batch[1:], A, S]`` holds the same numbers and leaves the streams where
        the step-by-step draws leave them. That holds for the ``"episode"`` and ``"step"``
        schedules without eq. (22)'s ``ε`` (whose draws would interleave) and with per-run streams
        (torch's global generator gives other numbers for one large draw).

        Args:
            batch: the batch shape, runs first.
            steps: episode length ``T``.
            device: the data's device.

        Returns:
            ``ξ`` for each step, ``[steps, *batch, A, S]`` (contiguous), or ``None``.

        Examples:
            >>> from sde_torchrl.utils.rng import RunStreams
            >>> one = SDENoisePrimer(1, 2, schedule="step", streams=RunStreams(0, runs=3, stream="explore"))
            >>> other = SDENoisePrimer(1, 2, schedule="step", streams=RunStreams(0, runs=3, stream="explore"))
            >>> noise, _, _ = one.start((3, 4))
            >>> steps = [noise] + [one.advance(noise, None, None)[0] for _ in range(4)]
            >>> bool((other.episode_noise((3, 4), 5) == torch.stack(steps)).all())
            True
        """
        if self.gaussian or self.schedule not in ("episode", "step") or self.streams is None:
            return None
        batch = tuple(batch)
        draws = draw_noise((batch[0], steps, *batch[1:], self.action_dim, self.feature_dim), self.streams,
                           dtype=self.noise_dtype, device=device).movedim(1, 0)
        return (draws if self.schedule == "step" else draws[:1].expand_as(draws)).contiguous()

    def start(self, batch: Sequence[int], device: torch.device | str | None = None
              ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The noise of a fresh episode for every batch element (what a full reset writes).

        Returns:
            ``(ξ, ε, age)``; ``ε`` is ``None`` without eq. (22)'s part, ``age`` (zeros,
            ``[*batch, 1]``) is ``None`` for ``"episode"`` and ``"step"``.

        Examples:
            >>> primer = SDENoisePrimer(2, 3, schedule="every_n", every_n=2)
            >>> noise, gaussian, age = primer.start((4,))
            >>> noise.shape, gaussian, age.shape
            (torch.Size([4, 2, 3]), None, torch.Size([4, 1]))
        """
        noise, gaussian = self.draw(batch, device)
        counted = self.schedule not in ("episode", "step")
        age = torch.zeros(*batch, 1, dtype=torch.int64, device=device) if counted else None
        return noise, gaussian, age

    def advance(
        self, noise: torch.Tensor, gaussian: torch.Tensor | None, age: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The noise for the next step of running episodes: one fresh draw, used as the schedule says.

        Args:
            noise: this step's ``ξ``, ``[*batch, A, S]``.
            gaussian: this step's ``ε`` or ``None``.
            age: steps ``ξ`` has been used before this one (``"every_n"``), or steps of the
                rollout before this one (``"every_n_steps"``, ``"rollout"``), else ``None``.

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
        if self.counts_rollout:
            age = self.count(age)
            return torch.where(self.due(age).unsqueeze(-1), fresh, noise), gaussian, age
        age = age + 1
        redraw = age >= self.every_n
        return torch.where(redraw.unsqueeze(-1), fresh, noise), gaussian, torch.where(redraw, 0, age)

    # ------------------------------------------------------------- SB3's counting over a rollout
    def count(self, age: torch.Tensor) -> torch.Tensor:
        """The rollout step count after one more step: ``age + 1``, modulo ``rollout_steps`` if set
        (``"every_n_steps"`` and ``"rollout"``)."""
        age = age + 1
        return age if self.rollout_steps is None else age % self.rollout_steps

    def due(self, age: torch.Tensor) -> torch.Tensor:
        """Where a fresh ``ξ`` is due before the rollout's step ``age`` (``[*batch, 1]`` booleans):
        at a rollout's start (``age = 0``) and, for ``"every_n_steps"``, at every multiple of
        ``n``: SB3's ``n_steps % sde_sample_freq == 0``.

        Examples:
            >>> primer = SDENoisePrimer(1, 1, schedule="every_n_steps", every_n=3, rollout_steps=5)
            >>> primer.due(torch.arange(5)).tolist()
            [True, False, False, True, False]
        """
        due = age == 0
        return due | (age % self.every_n == 0) if self.schedule == "every_n_steps" else due

    def resample(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Redraws ``ξ`` for every batch element and restarts the rollout count, in place: SB3's
        ``policy.reset_noise(n_envs)`` at the start of each ``collect_rollouts``.

        For the SB3-style schedules in a hand-written loop (``schedule="rollout"`` without
        ``rollout_steps`` is SB3's ``sde_sample_freq=-1``); with TorchRL's ``Collector`` give
        ``rollout_steps`` instead. Draws nothing under deterministic exploration.

        Args:
            tensordict: the carried state the next rollout starts from (it holds ``ξ``).

        Returns:
            ``tensordict``, with a fresh ``ξ`` and, where the schedule counts, ``sde_age = 0``.

        Examples:
            >>> from torchrl.envs import GymEnv, TransformedEnv
            >>> primer = SDENoisePrimer(1, 3, schedule="rollout")
            >>> env = TransformedEnv(GymEnv("Pendulum-v1"), primer)
            >>> td = env.rollout(3, break_when_any_done=False)
            >>> bool((td["sde_noise"] == td["sde_noise"][0]).all())  # held: no redraw in a rollout
            True
            >>> carried = td[-1]["next"].clone()
            >>> bool((primer.resample(carried)["sde_noise"] == td["sde_noise"][0]).all())
            False
        """
        noise = tensordict.get(self.noise_key, None)
        if noise is None:
            raise KeyError(f"resample: no {self.noise_key!r} in the tensordict: pass the carried state "
                           "(a reset or step output of the env with this primer)")
        if deterministic_exploration():
            return tensordict
        fresh, _, age = self.start(noise.shape[:-2], noise.device)
        tensordict.set(self.noise_key, fresh)
        if age is not None:
            tensordict.set(self.age_key, age)
        self.hold(tensordict)
        return tensordict

    def reset_noise(
        self, reset: torch.Tensor, noise: torch.Tensor, gaussian: torch.Tensor | None, age: torch.Tensor | None,
        held: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The noise after a reset of the envs where ``reset`` (``[*batch]`` booleans): fresh
        draws there, ``noise``, ``gaussian`` and ``age`` elsewhere (what a reset writes).

        ``held``: the ``(ξ, count)`` that the SB3-style schedules keep through a reset of done
        envs during a collection (the step's), used in place of the fresh ones. The fresh draws
        are made either way, so the random stream does not depend on it.

        Examples:
            >>> primer = SDENoisePrimer(1, 2)
            >>> noise = torch.zeros(3, 1, 2)
            >>> fresh, _, _ = primer.reset_noise(torch.tensor([True, False, False]), noise, None, None)
            >>> bool((fresh[0] != 0).all()), bool((fresh[1:] == 0).all())
            (True, True)
        """
        fresh, fresh_gaussian, fresh_age = self.start(noise.shape[:-2], noise.device)
        if held is not None and self.counts_rollout:  # SB3: a boundary changes neither ξ nor the count
            fresh, fresh_age = held
        noise = torch.where(expand_as_right(reset, fresh), fresh, noise)
        if fresh_gaussian is not None:
            gaussian = torch.where(expand_as_right(reset, fresh_gaussian), fresh_gaussian, gaussian)
        if fresh_age is not None:
            age = torch.where(expand_as_right(reset, fresh_age), fresh_age, age)
        return noise, gaussian, age

    def step_noise(
        self, noise: torch.Tensor, gaussian: torch.Tensor | None, age: torch.Tensor | None,
        done: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None] | None:
        """The noise after a step whose done flags are ``done`` (what a step writes):
        :meth:`advance`, or ``None`` (nothing drawn, the noise left as it is) when every episode
        has ended and the schedule does not count over a rollout (the reset draws then), or when
        exploration is deterministic."""
        all_done = done is not None and bool(done.all()) and not self.counts_rollout
        if deterministic_exploration() or all_done:
            return None
        return self.advance(noise, gaussian, age)

    # --------------------------------------------------------------------- the env transform
    def _reset_func(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset = super()._reset_func(tensordict, tensordict_reset)
        noise = tensordict_reset.get(self.noise_key, None)
        if noise is None or deterministic_exploration():  # absent when no env is reset
            return tensordict_reset
        noise, gaussian, age = self.reset_noise(
            _get_reset(self.reset_key, tensordict), noise, tensordict_reset.get(self.gaussian_noise_key, None),
            tensordict_reset.get(self.age_key, None), self._carried(tensordict, noise.shape))
        self._write(tensordict_reset, noise, gaussian, age)
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = super()._step(tensordict, next_tensordict)  # carries the noise (and age) over
        drawn = self.step_noise(next_tensordict.get(self.noise_key), next_tensordict.get(self.gaussian_noise_key, None),
                                next_tensordict.get(self.age_key, None), next_tensordict.get(self.done_key, None))
        if drawn is not None:
            self._write(next_tensordict, *drawn)
        return next_tensordict

    def _write(self, tensordict: TensorDictBase, noise: torch.Tensor, gaussian: torch.Tensor | None,
               age: torch.Tensor | None) -> None:
        tensordict.set(self.noise_key, noise)
        if gaussian is not None:
            tensordict.set(self.gaussian_noise_key, gaussian)
        if age is not None:
            tensordict.set(self.age_key, age)
        self.hold(tensordict)

    def hold(self, tensordict: TensorDictBase) -> None:
        """Keeps the ``(ξ, count)`` just written (SB3-style schedules): TorchRL resets done envs
        from their reset flags alone (``maybe_reset``), so the reset must find them here."""
        if self.counts_rollout:
            self._held = (tensordict.get(self.noise_key).clone(), tensordict.get(self.age_key).clone())

    def _carried(self, tensordict: TensorDictBase | None, shape: torch.Size
                 ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(ξ, count)`` that the SB3-style schedules keep through a reset of done envs during a
        collection (a reset whose input holds the reset flags, as TorchRL's ``maybe_reset`` passes);
        ``None`` for the other schedules and for an explicit reset (``env.reset()``: a new rollout)."""
        held = getattr(self, "_held", None)
        if not self.counts_rollout or tensordict is None or held is None or held[0].shape != shape:
            return None
        return held if self.reset_key in tensordict.keys(True) else None


__all__ = ["SDENoisePrimer", "deterministic_exploration", "draw_noise"]
