"""The non-finite guard: stops a job at the first NaN or infinity, naming where it came from.

A diverging run is the most common SDE failure (DESIGN.md section 5). The guard checks each
update's episode returns, the estimator's scores and gradient, the parameters after the step
and the evaluation returns, and raises :class:`NonFiniteError` naming the update, the runs (global indices) and the
parameter as it is named in the policy's state dict.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn

from sde_torchrl.objectives.estimators import EpisodicEstimator
from sde_torchrl.objectives.pgpe import PGPEEstimator

#: What to try when an episodic estimator's job diverges: the settings that job has.
EPISODIC_REMEDY = "lower lr or set estimator.max_grad_norm"


class NonFiniteError(RuntimeError):
    """A return, score, gradient or parameter became NaN or infinite.

    Attributes:
        update: index of the update (0-based) where it happened.
        what: ``"return"``, ``"score"``, ``"gradient"``, ``"parameter"`` or ``"evaluation return"``.
        parameter: the parameter's name in the policy's state dict, or ``None``.
        runs: global indices of the runs concerned.

    The message shows up to 6 of ``values`` (the offending ones, as the caller chose them) and
    ends with ``remedy``: settings of the job's own kind (an episodic estimator's by default).

    Examples:
        >>> str(NonFiniteError(3, "return", [1])).startswith("non-finite return at update 3 in run 1")
        True
        >>> str(NonFiniteError(0, "gradient norm", [0], values=torch.tensor([float("nan")]),
        ...                    remedy="lower lr or algorithm.max_grad_norm"))  # doctest: +ELLIPSIS
        'non-finite gradient norm at update 0 in run 0: [nan]; ... (lower lr or algorithm.max_grad_norm)'
    """

    def __init__(self, update: int, what: str, runs: list[int], parameter: str | None = None,
                 values: torch.Tensor | None = None, detail: str = "", remedy: str = EPISODIC_REMEDY) -> None:
        self.update, self.what, self.runs, self.parameter = update, what, runs, parameter
        subject = what if parameter is None else (
            f"parameter {parameter}" if what == "parameter" else f"{what} of parameter {parameter}")
        shown = "" if values is None else f" {values.detach().flatten()[:6].tolist()}"
        super().__init__(
            f"non-finite {subject} at update {update} in run{'s' if len(runs) != 1 else ''} "
            f"{', '.join(map(str, runs))}:{shown}{detail}; metrics.csv keeps the updates before it ({remedy})"
        )


def _finite(value: torch.Tensor) -> bool:
    return bool(torch.isfinite(value).all())


def check_finite(update: int, what: str, value: torch.Tensor, runs: int, first_run: int, remedy: str,
                 name: str | None = None) -> None:
    """Raises :class:`NonFiniteError` if ``value`` (``what`` at update ``update``; ``name``: the
    parameter's) is not finite, naming the runs whose slice of it is not (all ``runs`` if it
    has no run dimension) and showing its offending entries.

    Examples:
        >>> check_finite(2, "gradient norm", torch.tensor([1.0]), 1, 0, "lower lr")
        >>> check_finite(2, "gradient norm", torch.tensor([float("inf")]), 1, 0, "lower lr")
        Traceback (most recent call last):
        ...
        sde_torchrl.trainers.guard.NonFiniteError: non-finite gradient norm at update 2 in run 0: [inf]; ...
    """
    if value.is_floating_point() and not _finite(value):
        shown, where = offending_entries(value)
        bad = list(range(runs))
        if value.dim() and value.shape[0] == runs:
            bad = [int(r) for r in (~torch.isfinite(value.detach().reshape(runs, -1)).all(-1)).nonzero().flatten()]
        raise NonFiniteError(update, what, [first_run + r for r in bad], parameter=name, values=shown, detail=where,
                             remedy=remedy)


def offending_entries(value: torch.Tensor) -> tuple[torch.Tensor, str]:
    """The non-finite entries of ``value`` and, for a tensor of several entries, how many there
    are and where the first is.

    Examples:
        >>> offending_entries(torch.tensor([[1.0, float("inf")], [float("nan"), 2.0]]))
        (tensor([inf, nan]), ' (2 of 4 entries, the first at [0, 1])')
        >>> offending_entries(torch.tensor([float("nan")]))
        (tensor([nan]), '')
    """
    bad = ~torch.isfinite(value.detach())
    if value.numel() == 1:
        return value.detach().reshape(1), ""
    first = bad.nonzero()[0].tolist()
    return value.detach()[bad], f" ({int(bad.sum())} of {value.numel()} entries, the first at {first})"


class FiniteGuard:
    """Checks one job's returns, estimates and parameters at every update.

    Args:
        policy: the policy being trained (its state-dict names label the parameters).
        estimator: the estimator over ``policy`` (its ``scores(episodes)`` name a non-finite score).
        runs: number of runs of the job (the leading dimension of every checked tensor).
        first_run: global index of the job's first run.

    Examples:
        See :meth:`sde_torchrl.trainers.trainer.Trainer.update`.
    """

    def __init__(self, policy: nn.Module, estimator: EpisodicEstimator | PGPEEstimator, runs: int,
                 first_run: int = 0) -> None:
        self.policy, self.estimator, self.runs, self.first_run = policy, estimator, runs, first_run
        by_id = {id(p): n for n, p in policy.named_parameters()}
        self._policy_names = {n: by_id.get(id(p), n) for n, p in estimator.learnable_parameters().items()}

    def check_returns(self, update: int, returns: torch.Tensor) -> None:
        """Episode returns ``[runs, N]``; names the largest parameter entry (the usual cause)."""
        if not _finite(returns):
            name, largest = self._largest_parameter()
            raise NonFiniteError(update, "return", self._bad_runs(returns), values=returns,
                                 detail=f"; largest parameter entry: {name} = {largest:.3g}")

    def check_evaluation(self, update: int, returns: torch.Tensor) -> torch.Tensor:
        """Mean evaluation returns ``[runs]`` after update ``update``; returns them if finite."""
        if not _finite(returns):
            name, largest = self._largest_parameter()
            raise NonFiniteError(update, "evaluation return", self._bad_runs(returns), values=returns,
                                 detail=f"; largest parameter entry: {name} = {largest:.3g}")
        return returns

    def check_estimate(self, update: int, out: TensorDictBase, episodes: TensorDictBase,
                       scores: TensorDictBase | None = None) -> None:
        """The estimator's output: per-run score norms and the gradient ``[runs, K]``; ``scores``:
        the episodes' scores as collected, where the estimator was given them."""
        if not _finite(out["score_norm"]):
            if scores is None:
                named = self.estimator.scores(episodes)
            else:  # the episodic estimators' per-parameter scores, or PGPE's draws
                named = dict((scores["episode"] if "episode" in scores.keys() else scores).items())
            self._raise_named(update, "score", named, out["score_norm"])
        if not _finite(out["gradient"]):
            self._raise_named(update, "gradient", self._split(out["gradient"]))

    def check_parameters(self, update: int) -> None:
        """The learnable parameters after the optimiser step."""
        params = self.estimator.learnable_parameters()
        if not all(_finite(p) for p in params.values()):
            self._raise_named(update, "parameter", {n: p.detach() for n, p in params.items()})

    def _split(self, flat: torch.Tensor) -> dict[str, torch.Tensor]:
        """A flat per-run vector ``[runs, K]`` cut into the learnable parameters' pieces."""
        params = self.estimator.learnable_parameters()
        sizes = [p[0].numel() if p.dim() and p.shape[0] == self.runs else p.numel() for p in params.values()]
        return dict(zip(params, flat.split(sizes, dim=-1), strict=True))

    def _bad_runs(self, value: torch.Tensor) -> list[int]:
        """Global indices of the runs whose slice of ``value`` (runs first) is not finite."""
        if value.dim() == 0 or value.shape[0] != self.runs:
            return [self.first_run + r for r in range(self.runs)]
        bad = ~torch.isfinite(value.reshape(self.runs, -1)).all(-1)
        return [self.first_run + int(r) for r in bad.nonzero().flatten()]

    def _largest_parameter(self) -> tuple[str, float]:
        """The policy parameter entry of largest magnitude (what usually made returns blow up)."""
        name, param = max(self.policy.named_parameters(), key=lambda kv: float(kv[1].detach().abs().max()))
        flat = param.detach().flatten()
        return name, float(flat[flat.abs().argmax()])

    def _raise_named(
        self, update: int, what: str, values: dict[str, torch.Tensor], norm: torch.Tensor | None = None,
    ) -> None:
        """Raises for the first non-finite entry of ``values`` (estimator names → tensors). If
        every entry is finite, their per-run ``norm`` overflowed: its non-finite runs are named."""
        for name, value in values.items():
            if not _finite(value):
                raise NonFiniteError(update, what, self._bad_runs(value), self._policy_names.get(name, name), value)
        overflow = torch.full((self.runs,), float("nan")) if norm is None else norm
        raise NonFiniteError(update, f"{what} norm", self._bad_runs(overflow), values=overflow,
                             detail=" (finite entries too large to square in float32)")
