"""What every gradient estimator shares: the errors on bad episodes, the return of an episode,
the bounds on a gradient, and :class:`GradientEstimator`, the base of the episodic estimators
(REINFORCE, GPOMDP, ENAC: :mod:`sde_torchrl.objectives.estimators`) and of PGPE
(:mod:`sde_torchrl.objectives.pgpe`).

Every estimator returns the same TensorDict: ``loss_objective``, the surrogate ``-Σ g·θ`` whose
gradient is ``-g``, so that one step of ``torch.optim.SGD(lr=α)`` is the paper's update
``θ ← θ + α g`` (eq. 1); ``return_mean`` per run; ``gradient`` ``[*runs, K]`` (after its bounds);
``gradient_norm`` (before them) and the estimator's diagnostics.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.objectives import LossModule

from sde_torchrl.utils.checks import NonFiniteInputError, one_of
from sde_torchrl.utils.options import EPISODE_RETURNS


class EpisodesError(ValueError):
    """Episodes the estimators cannot use: the message names the key (or the shape) and the fix.

    Attributes:
        key: the TensorDict key concerned, or ``None`` for the batch shape.

    Examples:
        >>> str(EpisodesError("episodes lack key 'observation'", "observation"))
        "episodes lack key 'observation'"
    """

    def __init__(self, message: str, key: NestedKey | None = None) -> None:
        self.key = key
        super().__init__(message)


class MissingEpisodesKeyError(EpisodesError, KeyError):
    """Episodes that lack a key the estimator reads (a ``KeyError`` too, as TensorDict's own).

    Examples:
        >>> str(MissingEpisodesKeyError("episodes lack key 'loc'", "loc"))
        "episodes lack key 'loc'"
    """

    def __str__(self) -> str:
        return str(self.args[0])  # as ValueError does: KeyError would quote the message


class NonFiniteEpisodesError(EpisodesError, NonFiniteInputError):
    """Episodes holding NaN or infinity in a key the estimator reads (or scores or a gradient
    that overflowed): the estimate would be NaN.

    Attributes:
        key: the key (``"observation"``, ``("next", "reward")``) or ``"scores"``/``"gradient"``.
        where: the runs and episodes concerned, in words.

    Examples:
        >>> str(NonFiniteEpisodesError("'observation'", "run 1 episode 0", "re-collect them"))
        "'observation': NaN/inf in run 1 episode 0; re-collect them"
    """

    def __init__(self, name: str, where: str, fix: str, key: NestedKey | None = None) -> None:
        NonFiniteInputError.__init__(self, name, where, fix)
        self.key = name if key is None else key


def check_rewards_runs_and_inputs(episodes: TensorDictBase, reward_key: NestedKey, runs: int | None,
                                  input_keys: list[NestedKey]) -> None:
    """What every estimator needs of its episodes beyond their keys: one reward per step, the
    runs the policy's parameters are stacked over in the leading dimension, floating-point
    inputs for the controller (those of ``input_keys`` the episodes hold).

    Raises:
        EpisodesError: naming the key or the shape, and the fix.

    Examples:
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"next": {"reward": torch.zeros(2, 4, 5, 3)}}, [2, 4, 5])
        >>> try:
        ...     check_rewards_runs_and_inputs(td, ("next", "reward"), 2, [])
        ... except EpisodesError as error:
        ...     print(str(error).split(":")[0])
        episodes key ('next', 'reward') has shape (2, 4, 5, 3), expected (2, 4, 5, 1)
    """
    shape = tuple(episodes.batch_size)
    reward = episodes.get(reward_key)
    if tuple(reward.shape) not in (shape, (*shape, 1)):
        raise EpisodesError(f"episodes key {reward_key!r} has shape {tuple(reward.shape)}, expected {(*shape, 1)}: one "
                            "reward per step (sum or select the reward terms into one number first)", reward_key)
    if runs is not None and (len(shape) != 3 or shape[0] != runs):
        raise EpisodesError(f"episodes have batch shape {shape}, but the policy's parameters are stacked over "
                            f"runs={runs}: expected [{runs}, N, T], one row of episodes per run")
    for key in input_keys:
        value = episodes.get(key, None)
        if value is not None and not value.is_floating_point():
            raise EpisodesError(f"episodes key {key!r} is {value.dtype}; the controller needs floating-point inputs: "
                                f"episodes.set({key!r}, episodes.get({key!r}).float()), or collect them through "
                                "TorchRL's DTypeCastTransform", key)


def episode_returns(
    episodes: TensorDictBase, reward_key: NestedKey = ("next", "reward"), kind: str = "mean",
) -> torch.Tensor:
    """``R = (1/T) Σ_t r_t`` (``mean``, the undiscounted average reward of section 2.1) or
    ``R = Σ_t r_t`` (``sum``, what the authors' PyBrain REINFORCE uses:
    ``getSumOverSequences('reward')``) of each episode.

    Args:
        episodes: TensorDict shaped ``[*runs, N, T]``.
        reward_key: where the per-step rewards are.
        kind: ``"mean"`` or ``"sum"``.

    Returns:
        Tensor of shape ``[*runs, N]``.

    Examples:
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"next": {"reward": torch.tensor([[[[-1.0], [-3.0]]]])}}, [1, 1, 2])
        >>> episode_returns(td).item(), episode_returns(td, kind="sum").item()
        (-2.0, -4.0)
    """
    one_of("kind", kind, EPISODE_RETURNS)
    per_step = episodes.get(reward_key).reshape(*episodes.batch_size, -1).sum(-1)
    return per_step.sum(-1) if kind == "sum" else per_step.mean(-1)


def clip_per_run(gradient: torch.Tensor, max_norm: float) -> torch.Tensor:
    """Rescales each run's gradient ``[*runs, K]`` to norm at most ``max_norm``."""
    norm = gradient.norm(dim=-1, keepdim=True)
    return gradient * (max_norm / norm.clamp_min(max_norm))


def rescale_largest_entry(gradient: torch.Tensor, max_entry: float) -> torch.Tensor:
    """Rescales each run's gradient ``[*runs, K]`` whose largest entry exceeds ``max_entry`` so
    that this entry equals ``max_entry``, as the authors' PyBrain policy-gradient learner does
    before its step (with 1000). The largest entry is the signed maximum, not the largest
    magnitude: a gradient whose entries are all negative is never rescaled.

    Examples:
        >>> rescale_largest_entry(torch.tensor([[2000.0, -500.0], [-3000.0, 10.0]]), 1000.0)
        tensor([[ 1000.,  -250.],
                [-3000.,    10.]])
    """
    largest = gradient.max(dim=-1, keepdim=True).values
    return torch.where(largest > max_entry, gradient * (max_entry / largest), gradient)


class GradientEstimator(LossModule):
    """Base of the estimators: their options, the episodes' returns and the surrogate loss.

    Subclasses read their episodes, estimate one gradient per run of
    :meth:`learnable_parameters` and hand it to :meth:`surrogate`, which bounds it and builds the
    output every estimator shares (module docstring).

    Args:
        max_grad_norm: bound on each run's gradient norm (:func:`clip_per_run`); ``None``: plain
            ascent (eq. 1).
        max_grad_entry: rescale a run's gradient whose largest (signed) entry exceeds this
            (:func:`rescale_largest_entry`, the authors' PyBrain learner's 1000); ``None``: off.
        episode_return: ``"mean"`` (the paper's text, section 2.1) or ``"sum"`` (the authors'
            PyBrain REINFORCE) of each episode's rewards (:func:`episode_returns`).

    NaN or infinity in the episodes, scores or gradient raise :class:`NonFiniteEpisodesError`
    under the non-finite policy ``"raise"`` (the default) and give NaN estimates for the runs
    concerned under ``"guarded"`` (the trainer's, whose guard checks them:
    :mod:`sde_torchrl.utils.nonfinite`).

    Raises:
        ValueError: an option is not allowed.
    """

    tensor_keys: object

    def __init__(self, max_grad_norm: float | None = None, max_grad_entry: float | None = None,
                 episode_return: str = "mean") -> None:
        super().__init__()
        for name, bound in (("max_grad_norm", max_grad_norm), ("max_grad_entry", max_grad_entry)):
            if bound is not None and not bound > 0:
                raise ValueError(f"{name} must be > 0 or None, got {bound!r}")
        one_of("episode_return", episode_return, EPISODE_RETURNS)
        self.max_grad_norm, self.max_grad_entry, self.episode_return = max_grad_norm, max_grad_entry, episode_return

    def learnable_parameters(self) -> dict[str, nn.Parameter]:
        """The parameters the gradient covers, in the order of its entries."""
        raise NotImplementedError

    def returns(self, episodes: TensorDictBase) -> torch.Tensor:
        """Each episode's return ``[*runs, N]`` in this estimator's definition (``episode_return``)."""
        return episode_returns(episodes, self.tensor_keys.reward, self.episode_return)

    def surrogate(self, gradient: torch.Tensor, returns: torch.Tensor, run_dims: int,
                  **diagnostics: torch.Tensor) -> TensorDict:
        """The output: ``gradient_norm`` of the estimate, the estimate bounded (``max_grad_entry``,
        then ``max_grad_norm``), and the surrogate ``-Σ g·θ`` over :meth:`learnable_parameters`.

        Args:
            gradient: the estimate ``[*runs, K]``.
            returns: the episodes' returns ``[*runs, N]``.
            run_dims: the number of run dimensions of the parameters.
            **diagnostics: the estimator's own, ``[*runs, ...]``.

        Returns:
            TensorDict with ``loss_objective``, ``return_mean``, ``gradient``, ``gradient_norm`` and
            ``diagnostics``.
        """
        gradient_norm = gradient.norm(dim=-1)
        if self.max_grad_entry is not None:
            gradient = rescale_largest_entry(gradient, self.max_grad_entry)
        if self.max_grad_norm is not None:
            gradient = clip_per_run(gradient, self.max_grad_norm)
        theta = torch.cat([p.flatten(run_dims) for p in self.learnable_parameters().values()], -1)
        return TensorDict({
            "loss_objective": -(gradient.detach() * theta).sum(),
            "return_mean": returns.mean(-1),
            "gradient": gradient.detach(),
            "gradient_norm": gradient_norm,
            **diagnostics,
        }, batch_size=[])
