"""Episodic likelihood-ratio gradient estimators as TorchRL loss modules.

The estimators (REINFORCE, ENAC, GPOMDP) work on ``N`` whole episodes (TensorDicts shaped ``[*runs, N, T]``) and on the
per-episode score vectors ``ψ_n = Σ_t ∇_θ log π(u_t | x_t)`` (eq. 9) over every learnable
parameter of the policy, controller and exploration alike, computed for all episodes at once
with ``torch.func``. The returned ``loss_objective`` is the surrogate ``-g·θ`` whose gradient is
``-g``: one step of ``torch.optim.SGD(lr=α)`` is the paper's update ``θ ← θ + α g`` (eq. 1).

The estimators check their input before estimating (:meth:`EpisodicEstimator.check_episodes`):
an empty batch, a missing key, an actor input whose dtype is not the policy's, a row that holds
more than one episode, or NaN/infinity in what they read raise :class:`EpisodesError` naming the
key and the fix, instead of a reshape error or a NaN gradient.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from tensordict.utils import NestedKey
from torch import nn
from torch.func import functional_call, grad, vmap

from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import SDEActor
from sde_torchrl.objectives.base import (
    EpisodesError,
    GradientEstimator,
    MissingEpisodesKeyError,
    NonFiniteEpisodesError,
    check_rewards_runs_and_inputs,
)
from sde_torchrl.objectives.linear_scores import closed_form_refusal, linear_scores
from sde_torchrl.utils.checks import one_of
from sde_torchrl.utils.nonfinite import GUARDED_FIX, check_finite
from sde_torchrl.utils.options import EPISODE_RETURNS, SCORE_METHODS

#: The expected policy, as the errors name it.
POLICY_FORM = "make_sde_actor(actor, SDEParams(...)), an SDEActor"
#: The episode-start flags TorchRL's ``InitTracker`` writes.
IS_INIT_KEY = "is_init"


@dataclass(frozen=True)
class PolicyParts:
    """What the likelihood needs of a policy (:func:`policy_parts`).

    Attributes:
        actor: the modules before the SDE module (they write ``loc``).
        sde: the :class:`~sde_torchrl.modules.sde.SDEParams` holding ``σ̂``.
        sample_key: where the episodes hold the (pre-squash) action the likelihood scores.
        is_init_key: the episode-start flags.
    """

    actor: TensorDictSequential
    sde: SDEParams
    sample_key: NestedKey
    is_init_key: NestedKey


def policy_parts(policy: object) -> PolicyParts:
    """Splits an SDE policy into its actor and its ``σ̂`` module, or raises a ``TypeError``
    naming what was given.

    The policy is the :class:`~sde_torchrl.modules.sde_actor.SDEActor` of
    :func:`~sde_torchrl.modules.sde_actor.make_sde_actor`, squashed or not: the likelihood
    scores its pre-squash sample (``sample_key``).

    Examples:
        >>> from sde_torchrl import SDEParams
        >>> policy_parts(SDEParams(1, 1))
        Traceback (most recent call last):
        ...
        TypeError: policy: got SDEParams; expected make_sde_actor(actor, SDEParams(...)), an SDEActor
    """
    if not isinstance(policy, SDEActor):
        raise TypeError(f"policy: got {type(policy).__name__}; expected {POLICY_FORM}")
    if not policy.actor_modules or not isinstance(policy.sde, SDEParams):
        inner = (*policy.actor_modules, policy.sde)
        raise TypeError(f"policy: an SDEActor over TensorDictSequential({', '.join(type(m).__name__ for m in inner)}); "
                        "expected an actor, then SDEParams: build it with make_sde_actor(actor, sde)")
    return PolicyParts(policy.actor, policy.sde, policy.sample_key, IS_INIT_KEY)


def check_policy(policy: object) -> None:
    """Raises a ``TypeError`` naming what was given unless :func:`policy_parts` accepts ``policy``.

    Examples:
        >>> check_policy("policy")
        Traceback (most recent call last):
        ...
        TypeError: policy: got str; expected make_sde_actor(actor, SDEParams(...)), an SDEActor
    """
    policy_parts(policy)


class EpisodeLogLikelihood(nn.Module):
    """``log p(episode) = Σ_t log π(u_t | x_t)`` up to policy-free terms (eqs. 8, 9, 13, 20).

    Wraps the :class:`~sde_torchrl.modules.sde_actor.SDEActor` of
    :func:`~sde_torchrl.modules.sde_actor.make_sde_actor` (:func:`policy_parts`); the actor's
    output ``loc`` and the ``σ̂`` module's likelihood are recomputed from the stored observations
    and pre-squash actions (the policy's ``sample_key``: ``action_sample`` when squashed, else
    the action). The keys it reads are the policy's until :meth:`set_keys` renames them.

    With ``variance_weighted``, each action element's log-likelihood is multiplied by its own
    variance ``σ_j²`` held constant (detached), the "auto-alpha" scores of the authors' PyBrain
    explorers: the controller receives ``(u_j − μ_j)`` instead of ``(u_j − μ_j)/σ_j²`` (eq. 14
    times ``σ_j²``) and ``σ̂`` the derivative of eq. (21) times ``σ_j²``. A variance-preconditioned
    direction, not the gradient of the likelihood.

    Args:
        policy: the policy that collected the episodes.
        variance_weighted: weight each action element's log-likelihood by its constant ``σ_j²``.

    Raises:
        TypeError: ``policy`` is not of that form (:func:`check_policy`).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from sde_torchrl import LinearActor, SDEParams, make_sde_actor
        >>> log_likelihood = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3)))
        >>> log_likelihood.in_keys
        ['observation', 'action']
        >>> steps = TensorDict({"observation": torch.randn(4, 10, 3), "action": torch.randn(4, 10, 2)}, [4, 10])
        >>> log_likelihood(steps).shape
        torch.Size([4])
    """

    def __init__(self, policy: SDEActor, variance_weighted: bool = False) -> None:
        super().__init__()
        parts = policy_parts(policy)
        self.variance_weighted = variance_weighted
        # No reference to `policy` itself: its parameters would be reachable under two names,
        # which torch.func.functional_call does not restore correctly.
        self.actor, self.sde = parts.actor, parts.sde
        self.sample_key_default, self.is_init_key = parts.sample_key, parts.is_init_key
        self.set_keys(loc=parts.sde.loc_key, features=parts.sde.feature_key, action_sample=parts.sample_key)

    def set_keys(self, *, loc: NestedKey, features: NestedKey, action_sample: NestedKey) -> None:
        """Sets where the actor writes its mean and where the episodes hold the exploration
        features and the pre-squash actions; ``in_keys`` follows."""
        self.loc_key, self.feature_key, self.sample_key = loc, features, action_sample
        self.in_keys = list(dict.fromkeys([*self.actor.in_keys, features, action_sample]))

    def forward(self, steps: TensorDictBase) -> torch.Tensor:
        """Log-likelihood summed over the last batch dimension (time).

        Args:
            steps: TensorDict of shape ``[*batch, T]`` with the actor's inputs, the exploration
                features and the pre-squash actions.

        Returns:
            Tensor of shape ``[*batch]``.
        """
        loc = self.actor(steps.select(*self.actor.in_keys).copy()).get(self.loc_key)
        features = steps.get(self.feature_key).to(loc.dtype)
        sample = steps.get(self.sample_key)
        if not self.variance_weighted:
            return self.sde.log_prob(loc, features, sample).sum(-1)
        scale = self.sde.scale(features)
        per_element = -0.5 * ((sample - loc) / scale).square() - scale.log()  # eq. 13 without constants
        return (scale.detach().square() * per_element).sum((-2, -1))


def episode_scores(
    log_likelihood: EpisodeLogLikelihood, episodes: TensorDictBase
) -> dict[str, torch.Tensor]:
    """Per-episode score vectors ``ψ_n`` for every learnable parameter (eq. 9).

    ``vmap`` over the episode dimension of ``grad`` of the log-likelihood summed over runs: as
    run ``r``'s episodes only depend on run ``r``'s slice of a stacked parameter, the gradient's
    slice ``r`` is exactly that run's score.

    Args:
        log_likelihood: the policy's episode log-likelihood.
        episodes: TensorDict shaped ``[*runs, N, T]``.

    Returns:
        ``{parameter name: ψ}`` with ``ψ`` shaped ``[*runs, N, *parameter_shape[len(runs):]]``.
    """
    if episodes.batch_dims < 2:
        raise ValueError(
            f"episodes must be shaped [*runs, episodes, time], got batch {tuple(episodes.batch_size)}"
        )
    params = {
        name: p.detach() for name, p in log_likelihood.named_parameters() if p.requires_grad
    }
    if not params:
        raise ValueError("the policy has no learnable parameters")
    episode_dim = episodes.batch_dims - 2
    steps = episodes.select(*log_likelihood.in_keys)

    def total_log_likelihood(p: dict[str, torch.Tensor], one_episode: TensorDictBase) -> torch.Tensor:
        return functional_call(log_likelihood, p, (one_episode,)).sum()

    scores = vmap(grad(total_log_likelihood), in_dims=(None, episode_dim))(params, steps)
    return {name: s.movedim(0, episode_dim) for name, s in scores.items()}


def flatten_scores(scores: dict[str, torch.Tensor], run_dims: int) -> torch.Tensor:
    """Concatenates per-parameter scores into ``[*runs, N, K]`` (parameters in dict order)."""
    return torch.cat([s.flatten(run_dims + 1) for s in scores.values()], dim=-1)




def reinforce_gradient(scores: torch.Tensor, returns: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Episodic REINFORCE (eq. 11) with the optimal per-parameter baseline (Peters & Schaal).

    ``b_k = Σ_n ψ_nk² R_n / Σ_n ψ_nk²`` and ``g_k = (1/N) Σ_n ψ_nk (R_n − b_k)``. Where a
    parameter's scores are all zero, its baseline is 0 (and its gradient 0).

    Args:
        scores: ``ψ``, shaped ``[*runs, N, K]``.
        returns: ``R``, shaped ``[*runs, N]``.

    Returns:
        ``(g, b)``, both shaped ``[*runs, K]``.
    """
    squared = scores.square()
    weight = squared.sum(-2)
    baseline = (squared * returns.unsqueeze(-1)).sum(-2) / torch.where(weight > 0, weight, 1.0)
    gradient = (scores * (returns.unsqueeze(-1) - baseline.unsqueeze(-2))).mean(-2)
    return gradient, baseline


def enac_gradient(
    scores: torch.Tensor, returns: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Episodic Natural Actor-Critic: least squares ``[ψ_n, 1] · [w; J] = R_n``; ``w`` is the
    natural gradient (Peters & Schaal).

    Solved with an SVD-based least-squares driver in float64, which returns the minimum-norm
    solution when the system is rank deficient (fewer episodes than parameters, or constant
    scores) instead of failing. That driver (``gelsd``) exists only on the CPU (CUDA's ``gels``
    needs full rank), so the small system ``[*runs, N, K + 1]`` is solved there and the results
    are returned on the scores' device. A run whose scores or returns hold NaN or infinity is
    not handed to the solver (LAPACK fails on them): its ``w``, ``J`` and condition number are
    NaN and its rank 0.

    Args:
        scores: ``ψ``, shaped ``[*runs, N, K]``.
        returns: ``R``, shaped ``[*runs, N]``.

    Returns:
        ``(w, J, rank, condition_number)``: ``w`` ``[*runs, K]``; the fitted average return
        ``J``, the rank of ``[ψ, 1]`` and its condition number (``inf`` with fewer episodes than
        unknowns), ``[*runs]``.
    """
    device = scores.device
    design = torch.cat([scores, torch.ones_like(scores[..., :1])], dim=-1).double().cpu()  # gelsd: CPU only
    target = returns.double().unsqueeze(-1).cpu()
    finite = torch.isfinite(design).all((-2, -1)) & torch.isfinite(target).all((-2, -1))  # [*runs]
    all_finite = bool(finite.all())
    if not all_finite:  # LAPACK fails on NaN/inf (an MKL "INTERNAL ASSERT"): solve zeros instead
        design = torch.where(finite[..., None, None], design, 0.0)
        target = torch.where(finite[..., None, None], target, 0.0)
    solution = torch.linalg.lstsq(design, target, driver="gelsd")
    coefficients = solution.solution.squeeze(-1).to(scores.dtype)
    singular = solution.singular_values
    if singular.shape[-1] < design.shape[-1]:  # fewer episodes than unknowns: singular
        condition = torch.full(singular.shape[:-1], torch.inf, dtype=singular.dtype)
    else:
        condition = singular[..., 0] / singular[..., -1]
    rank = solution.rank
    if not all_finite:
        coefficients = torch.where(finite[..., None], coefficients, torch.nan)
        condition = torch.where(finite, condition, torch.nan)
        rank = torch.where(finite, rank, 0)
    coefficients = coefficients.to(device)
    return coefficients[..., :-1], coefficients[..., -1], rank.to(device), condition.to(device, scores.dtype)


class EpisodicEstimator(GradientEstimator):
    """Base class: scores and returns of a batch of episodes → gradient → surrogate loss.

    Subclasses implement :meth:`estimate`. The forward pass returns a TensorDict with
    ``loss_objective`` (``-Σ g·θ``: its gradient w.r.t. the policy parameters is ``-g``),
    ``return_mean`` (per run), ``gradient`` (``[*runs, K]``) and estimator diagnostics.

    Args:
        policy: the :class:`~sde_torchrl.modules.sde_actor.SDEActor` of
            :func:`~sde_torchrl.modules.sde_actor.make_sde_actor`, the policy being trained.
        max_grad_norm: if set, each run's gradient is rescaled to at most this norm before the
            update (off by default: the paper's update is plain gradient ascent; the authors'
            own code bounded large gradients). ``gradient_norm`` reports the norm before.
        max_grad_entry: if set, each run's gradient whose largest (signed) entry exceeds this is
            rescaled so that this entry equals it (:func:`rescale_largest_entry`; the authors'
            PyBrain learner used 1000).
        episode_return: ``"mean"`` (the paper's text, section 2.1) or ``"sum"`` (the authors'
            PyBrain REINFORCE) of each episode's rewards (:func:`episode_returns`); the trainer
            reports returns, and compares them with ``r_lim``, in the same definition.
        variance_weighted: the authors' "auto-alpha" scores: each action element's
            log-likelihood weighted by its constant variance ``σ_j²`` (see
            :class:`EpisodeLogLikelihood`).
        scores: ``"autograd"``, the scores as autograd differentiates the policy's
            log-likelihood (:func:`episode_scores`, any actor), or ``"closed_form"``, eqs. 16,
            21 and 24 evaluated directly for a linear controller
            (:func:`~sde_torchrl.objectives.linear_scores.linear_scores`: the same scores to
            float rounding, several times faster to compute).

    Input contract (:meth:`check_episodes`, at every forward pass): episodes shaped
    ``[*runs, N, T]`` with ``N, T >= 1``, features ``[*runs, N, T, S]`` and action samples
    ``[*runs, N, T, A]`` for the policy's ``S`` and ``A``, one whole episode per row (``is_init`` only at step 0,
    ``("next", "done")`` only at the last step, where the episodes carry them), the actor's
    floating-point inputs in the dtype of the policy's parameters, and finite values in every key
    the estimator reads (under the non-finite policy ``"raise"``, the default; under ``"guarded"``,
    which the trainer enters because its :class:`~sde_torchrl.trainers.guard.FiniteGuard` checks the
    same values and names the update, NaN or infinity give NaN estimates for the runs concerned:
    :mod:`sde_torchrl.utils.nonfinite`). Rows holding several episodes are refused, not split: split episodes
    have different lengths, which neither the ``[*runs, N, T]`` batch nor the per-run ``N`` of
    the estimates can hold. The actor's inputs are not converted to the policy's dtype (the
    actor that collected the episodes would have refused them too); the exploration features
    are, to the dtype of the actor's ``loc``, as the policy does when it acts.

    Raises:
        TypeError: ``policy`` is not an SDE policy (:func:`policy_parts`).
        ValueError: an option is not allowed.

    Examples:
        >>> import torch
        >>> from sde_torchrl import LinearActor, SDEParams, make_minimize_env, make_sde_actor
        >>> from sde_torchrl.collectors.rollout import collect_episodes
        >>> sde = SDEParams(1, 1)
        >>> env = make_minimize_env(5, episodes=4).append_transform(sde.make_tensordict_primer())
        >>> policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
        >>> episodes = collect_episodes(env, policy, 5)
        >>> episodes["observation"][2, 3] = float("nan")
        >>> ReinforceEstimator(policy)(episodes)
        Traceback (most recent call last):
        ...
        sde_torchrl.objectives.base.NonFiniteEpisodesError: episodes key 'observation': NaN/inf in episode 2; ...
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable keys (``set_keys``): every key the estimator reads.

        Attributes:
            reward: per-step reward. Defaults to ``("next", "reward")``.
            action_sample: the pre-squash action taken, which the likelihood scores (eq. 13).
                Defaults to the policy's ``sample_key``.
            features: the exploration features ``x`` of eq. 20. Defaults to the ``SDEParams``'
                ``feature_key``.
            loc: where the actor writes the controller's mean ``μ``. Defaults to the
                ``SDEParams``' ``loc_key``.
            is_init: episode-start flags; checked where present (a reset inside a row is
                refused). Defaults to ``"is_init"``.
            done: episode-end flags; checked where present (an end before the last step is
                refused). Defaults to ``("next", "done")``.
        """

        reward: NestedKey = ("next", "reward")
        action_sample: NestedKey = "action"
        features: NestedKey = "observation"
        loc: NestedKey = "loc"
        is_init: NestedKey = IS_INIT_KEY
        done: NestedKey = ("next", "done")

    tensor_keys: _AcceptedKeys
    #: whether the estimate reads per-step scores beside the episode scores (GPOMDP's).
    reads_step_scores: ClassVar[bool] = False

    def __init__(
        self, policy: SDEActor, max_grad_norm: float | None = None, *,
        max_grad_entry: float | None = None, episode_return: str = "mean", variance_weighted: bool = False,
        scores: str = "autograd",
    ) -> None:
        super().__init__(max_grad_norm, max_grad_entry, episode_return)
        self.log_likelihood = EpisodeLogLikelihood(policy, variance_weighted)
        one_of("scores", scores, SCORE_METHODS)
        refusal = closed_form_refusal(self.log_likelihood) if scores == "closed_form" else None
        if refusal is not None:
            raise ValueError(f"scores=closed_form needs a linear SDE controller: {refusal}; use scores=autograd")
        self.closed_form = scores == "closed_form"
        self._tensor_keys = self.default_keys()
        self._set_in_keys()

    def default_keys(self) -> _AcceptedKeys:
        """The default keys: the policy's for the likelihood, ``("next", "reward")``."""
        likelihood = self.log_likelihood
        return self._AcceptedKeys(action_sample=likelihood.sample_key_default, features=likelihood.sde.feature_key,
                                  loc=likelihood.sde.loc_key, is_init=likelihood.is_init_key)

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """Called by ``set_keys``: hands the likelihood its keys and refreshes ``in_keys``."""
        keys = self.tensor_keys
        self.log_likelihood.set_keys(loc=keys.loc, features=keys.features, action_sample=keys.action_sample)
        self._set_in_keys()

    def _set_in_keys(self) -> None:
        self.in_keys = list(dict.fromkeys([*self.log_likelihood.in_keys, self.tensor_keys.reward]))
        self.out_keys = ["loss_objective", "return_mean", "gradient"]

    def learnable_parameters(self) -> dict[str, nn.Parameter]:
        """The parameters the scores cover, in the order of the flattened gradient."""
        return {n: p for n, p in self.log_likelihood.named_parameters() if p.requires_grad}

    def scores(self, episodes: TensorDictBase) -> dict[str, torch.Tensor]:
        """Each episode's score ``ψ_n`` per learnable parameter (eq. 9, :func:`episode_scores`, or
        in closed form)."""
        if self.closed_form:
            return linear_scores(self.log_likelihood, episodes)
        return episode_scores(self.log_likelihood, episodes)

    def estimate(self, scores: torch.Tensor, returns: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Gradient ``[*runs, K]`` and diagnostics from scores ``[*runs, N, K]``, returns ``[*runs, N]``."""
        raise NotImplementedError

    def episode_and_step_scores(
        self, episodes: TensorDictBase,
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor] | None]:
        """The episode scores (:meth:`scores`) and, for an estimator that needs them, the
        per-step scores they sum (:func:`step_scores`; ``None`` here)."""
        return self.scores(episodes), None

    def collected_scores(self, episodes: TensorDictBase) -> TensorDict:
        """The scores of ``episodes`` under the current parameters, to be kept with them while
        they wait in an episode queue and handed back to :meth:`forward` (``scores=``): a queued
        episode then keeps the score of the policy that acted, as the authors' PyBrain learners
        store each step's log-likelihood derivative when the action is taken.

        Args:
            episodes: TensorDict shaped ``[*runs, N, T]``, one whole episode per row.

        Returns:
            TensorDict shaped ``[*runs, N]``: ``"episode"``, the episode scores per learnable
            parameter (:meth:`scores`), and for an estimator that reads them (GPOMDP)
            ``"step"``, the per-step scores ``[*runs, N, T, ...]`` they sum.

        Examples:
            >>> import torch
            >>> from sde_torchrl import LinearActor, SDEParams, make_sde_actor
            >>> policy = make_sde_actor(LinearActor(3, 2), SDEParams(2, 3))
            >>> loss = ReinforceEstimator(policy)
            >>> steps = TensorDict({"observation": torch.randn(4, 10, 3), "action": torch.randn(4, 10, 2),
            ...                     ("next", "reward"): torch.randn(4, 10, 1)}, [4, 10])
            >>> kept = loss.collected_scores(steps)
            >>> kept.batch_size, sorted(kept["episode"].keys())
            (torch.Size([4]), ['actor.module.0.module.weight', 'sde.sigma_param'])
            >>> with torch.no_grad():
            ...     _ = policy.module[0].module[0].module.weight.add_(1.0)  # the policy moves on
            >>> bool(loss(steps, scores=kept)["gradient"].ne(loss(steps)["gradient"]).any())
            True
        """
        per_parameter, per_step = self.episode_and_step_scores(episodes)
        batch = episodes.batch_size
        kept = TensorDict({"episode": TensorDict(per_parameter, batch_size=batch[:-1])}, batch_size=batch[:-1])
        if per_step is not None:
            kept["step"] = TensorDict(per_step, batch_size=batch)
        return kept

    def _kept_scores(
        self, scores: TensorDictBase, episodes: TensorDictBase,
    ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor] | None]:
        """The episode and per-step scores of :meth:`collected_scores`, checked against the
        episodes and the learnable parameters."""
        batch = tuple(episodes.batch_size)
        if not isinstance(scores, TensorDictBase) or tuple(scores.batch_size) != batch[:-1]:
            got = tuple(scores.batch_size) if isinstance(scores, TensorDictBase) else type(scores).__name__
            raise EpisodesError(f"scores: got {got}; expected the TensorDict of collected_scores(episodes), "
                                f"shaped {batch[:-1]} ([*runs, N] of episodes shaped {batch})")
        parameters = self.learnable_parameters()
        run_dims = len(batch) - 2
        per_step = None
        parts = [("episode", batch[:-1])] + ([("step", batch)] if self.reads_step_scores else [])
        for part, leading in parts:
            if part not in scores.keys():
                raise EpisodesError(f"scores lack {part!r}: make them with collected_scores(episodes) of this "
                                    f"estimator ({type(self).__name__})")
            given = scores[part]
            if sorted(given.keys()) != sorted(parameters):
                raise EpisodesError(f"scores[{part!r}] cover {sorted(given.keys())}, but the learnable parameters "
                                    f"are {sorted(parameters)}: score the episodes with this estimator's "
                                    "collected_scores(episodes), after any change to which parameters learn")
            for name, p in parameters.items():
                expected = (*leading, *p.shape[run_dims:])
                if tuple(given[name].shape) != expected:
                    raise EpisodesError(f"scores[{part!r}][{name!r}] has shape {tuple(given[name].shape)}, "
                                        f"expected {expected}")
            if part == "step":
                per_step = {name: given[name] for name in parameters}
        return {name: scores["episode"][name] for name in parameters}, per_step

    def estimate_from_episodes(
        self, episodes: TensorDictBase, scores: torch.Tensor, returns: torch.Tensor,
        per_step: dict[str, torch.Tensor] | None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Gradient and diagnostics for the checked ``episodes``; :meth:`estimate` unless the
        estimator needs more than the episode scores and returns (GPOMDP's per-step terms)."""
        return self.estimate(scores, returns)

    def check_episodes(self, episodes: TensorDictBase) -> None:
        """Checks the input contract (see the class docstring); cheap: one fused check per key.

        Raises:
            TypeError: ``episodes`` is not a TensorDict.
            EpisodesError: an empty batch, a missing key (:class:`MissingEpisodesKeyError`),
                a reward that is not one number per step, a leading dimension other than the
                policy's runs, features or action samples not shaped for the policy, an actor
                input that is not floating point or in another dtype than the policy's
                parameters, or a row holding more than one episode.
            NonFiniteEpisodesError: NaN or infinity in a key the estimator reads (under the
                non-finite policy ``"raise"``).
        """
        if not isinstance(episodes, TensorDictBase):
            raise TypeError(f"episodes: got {type(episodes).__name__}; expected a TensorDict shaped [*runs, N, T]")
        shape = tuple(episodes.batch_size)
        if len(shape) < 2 or 0 in shape:
            raise EpisodesError(
                f"episodes have batch shape {shape}; the estimators need [*runs, N, T] with N >= 1 episodes "
                "of T >= 1 steps (sde_torchrl.collectors.rollout.collect_episodes(env, policy, T) gives "
                "[*env.batch_size, T])")
        keys = self.tensor_keys
        for key in self.in_keys:
            if episodes.get(key, None) is None:
                raise MissingEpisodesKeyError(
                    f"episodes lack key {key!r}; the estimator reads {self.in_keys}: collect them with the policy "
                    "being trained, or name the keys they use with set_keys(...)", key)
        sde = self.log_likelihood.sde
        check_rewards_runs_and_inputs(episodes, keys.reward, sde.runs, list(self.log_likelihood.actor.in_keys))
        for key, size, name in ((keys.features, sde.feature_dim, "feature_dim"),
                                (keys.action_sample, sde.action_dim, "action_dim")):
            if tuple(episodes.get(key).shape) != (*shape, size):  # a size-1 dimension would broadcast
                raise EpisodesError(
                    f"episodes key {key!r} has shape {tuple(episodes.get(key).shape)}, expected {(*shape, size)}: "
                    f"the batch [*runs, N, T] then the policy's {name}={size}", key)
        parameter = next(iter(self.learnable_parameters().values()), None)
        for key in self.log_likelihood.actor.in_keys if parameter is not None else ():
            value, dtype = episodes.get(key), parameter.dtype
            if value.is_floating_point() and value.dtype != dtype:
                raise EpisodesError(
                    f"episodes key {key!r} is {value.dtype} but the policy's parameters are {dtype}; convert "
                    f"the episodes: episodes.set({key!r}, episodes.get({key!r}).to({dtype})) (or collect them "
                    f"through TorchRL's DoubleToFloat transform), or the policy: policy.to({value.dtype})", key)
        self._check_one_episode_per_row(episodes, keys.is_init, slice(1, None), "a new episode starts")
        self._check_one_episode_per_row(episodes, keys.done, slice(None, -1), "an episode ends")
        labels = self._labels(episodes.batch_dims - 2)
        for key in self.in_keys:
            check_finite(f"episodes key {key!r}", episodes.get(key), labels,
                         "the estimate would be NaN for those runs. Find what produced it (a diverged env or "
                         "policy: lower the learning rate or bound the gradient with max_grad_norm), drop or "
                         f"re-collect those episodes, {GUARDED_FIX} and get NaN estimates",
                         error=partial(NonFiniteEpisodesError, key=key))

    def _check_one_episode_per_row(self, episodes: TensorDictBase, key: NestedKey, steps: slice, what: str) -> None:
        """Refuses rows where the flags under ``key`` (if present) are set at ``steps``."""
        flags = episodes.get(key, None)
        if flags is None or not bool(flags[(*[slice(None)] * (episodes.batch_dims - 1), steps)].any()):
            return
        inner = flags.reshape(*episodes.batch_size, -1).any(-1).clone()
        inner[..., 0 if steps.start else -1] = False
        first = inner.nonzero()[0].tolist()
        row = " ".join(f"{label} {i}" for label, i in zip(self._labels(episodes.batch_dims - 2), first, strict=False))
        raise EpisodesError(
            f"episodes row {row} holds more than one episode: {what} at step {first[-1]} of "
            f"{episodes.batch_size[-1]} ({key!r} is set there); the estimators take each row of [*runs, N, T] as "
            "one whole episode. Collect whole episodes of T steps: "
            "sde_torchrl.collectors.rollout.collect_episodes(env, "
            "policy, T), or "
            "env.rollout(T, policy, break_when_any_done=False) on an env with StepCounter(T)", key)

    @staticmethod
    def _labels(run_dims: int) -> list[str]:
        """Names of the ``[*runs, N]`` dimensions in messages."""
        return ["run" if run_dims == 1 else f"run[{d}]" for d in range(run_dims)] + ["episode"]

    def _check_finite(self, what: str, values: dict[str, torch.Tensor], run_dims: int, per_episode: bool) -> None:
        """Raises :class:`NonFiniteEpisodesError` for the first parameter whose scores
        (``[*runs, N, ...]``) or gradient (``[*runs, ...]``) hold NaN or infinity, under the
        non-finite policy ``"raise"``."""
        labels = self._labels(run_dims) if per_episode else self._labels(run_dims)[:-1]
        for name, value in values.items():
            check_finite(f"{what} of parameter {name}", value, labels,
                         "the episodes are finite but too large for the policy's dtype (the likelihood overflowed): "
                         "scale the observations or rewards, lower the learning rate or bound the gradient with "
                         f"max_grad_norm, {GUARDED_FIX} and get NaN estimates",
                         error=partial(NonFiniteEpisodesError, key=what))

    def forward(self, episodes: TensorDictBase, scores: TensorDictBase | None = None) -> TensorDictBase:
        """Estimates one gradient per run from the episodes.

        Args:
            episodes: TensorDict shaped ``[*runs, N, T]``, one whole episode per row.
            scores: the episodes' scores as :meth:`collected_scores` kept them (under the
                parameters that collected each episode); ``None``: scored now, under the
                current parameters.

        Returns:
            TensorDict with ``loss_objective``, ``return_mean``, ``gradient``, ``score_norm``,
            ``gradient_norm`` and the estimator's diagnostics.

        Raises:
            EpisodesError: the episodes break the input contract (:meth:`check_episodes`), or
                ``scores`` are not :meth:`collected_scores` of episodes of that shape.
            NonFiniteEpisodesError: NaN or infinity in the episodes, the scores or the gradient
                (under the non-finite policy ``"raise"``).
        """
        self.check_episodes(episodes)
        returns = self.returns(episodes)
        run_dims = episodes.batch_dims - 2
        if scores is None:
            per_parameter, per_step = self.episode_and_step_scores(episodes)
        else:
            per_parameter, per_step = self._kept_scores(scores, episodes)
        scores = flatten_scores(per_parameter, run_dims)
        self._check_finite("scores", per_parameter, run_dims, per_episode=True)
        gradient, diagnostics = self.estimate_from_episodes(episodes, scores, returns, per_step)
        sizes = [s[(0,) * (run_dims + 1)].numel() for s in per_parameter.values()]
        self._check_finite("gradient", dict(zip(per_parameter, gradient.split(sizes, -1), strict=True)),
                           run_dims, per_episode=False)
        return self.surrogate(gradient, returns, run_dims, score_norm=scores.norm(dim=-1).mean(-1), **diagnostics)


class ReinforceEstimator(EpisodicEstimator):
    """Episodic REINFORCE with the optimal per-parameter baseline (eq. 11, Peters & Schaal).

    Examples:
        >>> import torch
        >>> from sde_torchrl import LinearActor, SDEParams, make_minimize_env, make_sde_actor
        >>> sde = SDEParams(1, 1)
        >>> env = make_minimize_env(5, episodes=8).append_transform(sde.make_tensordict_primer())
        >>> policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
        >>> loss = ReinforceEstimator(policy)
        >>> with torch.no_grad():
        ...     episodes = env.rollout(5, policy)
        >>> loss(episodes)["loss_objective"].backward()
    """

    def estimate(self, scores, returns):
        gradient, baseline = reinforce_gradient(scores, returns)
        return gradient, {"baseline": baseline}


class ENACEstimator(EpisodicEstimator):
    """Episodic Natural Actor-Critic (Peters & Schaal), robust to rank deficiency.

    Diagnostics: ``rank`` and ``condition_number`` of the regression ``[ψ, 1]``, and ``J``.
    """

    def estimate(self, scores, returns):
        natural, average_return, rank, condition = enac_gradient(scores, returns)
        return natural, {"rank": rank, "condition_number": condition, "J": average_return}


# ---------------------------------------------------------------------------------- GPOMDP


def step_scores(log_likelihood: EpisodeLogLikelihood, episodes: TensorDictBase) -> dict[str, torch.Tensor]:
    """Per-step score vectors ``∇_θ log π(u_t | x_t)`` for every learnable parameter.

    Each step's log-likelihood depends on that step's stored observation, features and action
    only (eqs. 13, 20), so the ``N`` episodes of ``T`` steps are scored as ``N·T`` one-step
    episodes (:func:`episode_scores`); summed over time they give the episode scores ``ψ_n``
    (eq. 9).

    Args:
        log_likelihood: the policy's episode log-likelihood.
        episodes: TensorDict shaped ``[*runs, N, T]``.

    Returns:
        ``{parameter name: score}`` with each score shaped ``[*runs, N, T, *parameter_shape[len(runs):]]``.

    Examples:
        >>> from sde_torchrl import LinearActor, SDEParams, make_sde_actor
        >>> log_likelihood = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3)))
        >>> from tensordict import TensorDict
        >>> steps = TensorDict({"observation": torch.randn(4, 10, 3), "action": torch.randn(4, 10, 2)}, [4, 10])
        >>> per_step = step_scores(log_likelihood, steps)
        >>> {name: tuple(s.shape) for name, s in per_step.items()}
        {'actor.module.0.module.weight': (4, 10, 2, 3), 'sde.sigma_param': (4, 10, 2, 3)}
        >>> per_episode = episode_scores(log_likelihood, steps)
        >>> all(torch.allclose(per_step[n].sum(1), per_episode[n], rtol=1e-4, atol=1e-5) for n in per_episode)
        True
    """
    shape = tuple(episodes.batch_size)
    if len(shape) < 2:
        raise ValueError(f"episodes must be shaped [*runs, episodes, time], got batch {shape}")
    one_step_episodes = episodes.select(*log_likelihood.in_keys).reshape(*shape[:-2], shape[-2] * shape[-1], 1)
    scores = episode_scores(log_likelihood, one_step_episodes)
    return {name: s.unflatten(len(shape) - 2, shape[-2:]) for name, s in scores.items()}


def step_rewards(
    episodes: TensorDictBase, reward_key: NestedKey = ("next", "reward"), kind: str = "mean",
) -> torch.Tensor:
    """Per-step rewards ``[*runs, N, T]`` that sum to :func:`episode_returns`: ``r_t / T``
    (``mean``) or ``r_t`` (``sum``).

    Examples:
        >>> from tensordict import TensorDict
        >>> td = TensorDict({"next": {"reward": torch.tensor([[[[-1.0], [-3.0]]]])}}, [1, 1, 2])
        >>> step_rewards(td), step_rewards(td, kind="sum")
        (tensor([[[-0.5000, -1.5000]]]), tensor([[[-1., -3.]]]))
    """
    one_of("kind", kind, EPISODE_RETURNS)
    rewards = episodes.get(reward_key).reshape(*episodes.batch_size, -1).sum(-1)
    return rewards / episodes.batch_size[-1] if kind == "mean" else rewards


def gpomdp_gradient(scores: torch.Tensor, rewards: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """GPOMDP (Baxter & Bartlett 2001) with the time-dependent optimal baseline (Peters & Schaal
    2008, "Reinforcement learning of motor skills with policy gradients", section on G(PO)MDP).

    Each reward ``r_k`` is credited only to the actions taken up to step ``k``, through the
    partial score sums ``Ψ_nk = Σ_{t≤k} ∇_θ log π(u_nt | x_nt)``:

    ``g_h = (1/N) Σ_n Σ_k Ψ_nkh (r_nk − b_kh)``, with
    ``b_kh = Σ_n Ψ_nkh² r_nk / Σ_n Ψ_nkh²``

    (``b_kh`` is 0 where the ``Ψ_nkh`` are all 0). A reward cannot depend on a later action, so
    dropping those terms from REINFORCE's ``ψ_n R_n`` (eq. 11) leaves the expectation unchanged
    and removes their variance.

    Args:
        scores: per-step scores ``∇_θ log π``, shaped ``[*runs, N, T, K]``.
        rewards: per-step rewards, shaped ``[*runs, N, T]``.

    Returns:
        ``(g, b)``: ``g`` shaped ``[*runs, K]``, the baseline ``b`` ``[*runs, T, K]``.

    Examples:
        >>> scores = torch.tensor([[[1.0], [0.0]], [[-1.0], [0.0]]])  # 2 episodes, 2 steps, 1 parameter
        >>> rewards = torch.tensor([[5.0, 1.0], [3.0, 2.0]])
        >>> g, b = gpomdp_gradient(scores, rewards)
        >>> g, b.squeeze(-1)
        (tensor([0.5000]), tensor([4.0000, 1.5000]))
    """
    partial = scores.cumsum(-2)
    squared = partial.square()
    weight = squared.sum(-3)
    baseline = (squared * rewards.unsqueeze(-1)).sum(-3) / torch.where(weight > 0, weight, 1.0)
    gradient = (partial * (rewards.unsqueeze(-1) - baseline.unsqueeze(-3))).sum(-2).mean(-2)
    return gradient, baseline


class GPOMDPEstimator(EpisodicEstimator):
    """GPOMDP with the time-dependent optimal baseline (:func:`gpomdp_gradient`), for SDE as for
    REX: with SDE the actions of one episode share one noise matrix, but a reward still cannot
    depend on a later action, so the estimate stays unbiased.

    The options are REINFORCE's (:class:`EpisodicEstimator`): with ``episode_return="mean"``
    the per-step rewards are ``r_t / T`` (:func:`step_rewards`), with ``"sum"`` they are ``r_t``;
    ``variance_weighted`` weights each step's score as it weights the episode's;
    ``max_grad_entry`` and ``max_grad_norm`` bound the result. Diagnostics: ``baseline``
    ``[*runs, T, K]``.

    Examples:
        >>> import torch
        >>> from sde_torchrl import LinearActor, SDEParams, make_minimize_env, make_sde_actor
        >>> sde = SDEParams(1, 1)
        >>> env = make_minimize_env(5, episodes=8).append_transform(sde.make_tensordict_primer())
        >>> policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
        >>> loss = GPOMDPEstimator(policy, episode_return="sum")
        >>> with torch.no_grad():
        ...     episodes = env.rollout(5, policy)
        >>> out = loss(episodes)
        >>> out["gradient"].shape, out["baseline"].shape
        (torch.Size([2]), torch.Size([5, 2]))
        >>> out["loss_objective"].backward()
    """

    reads_step_scores: ClassVar[bool] = True

    def scores(self, episodes):
        """Each episode's score ``ψ_n``: the sum of its per-step scores (eq. 9, :func:`step_scores`)."""
        return self.episode_and_step_scores(episodes)[0]

    def episode_and_step_scores(self, episodes):
        """The per-step scores, computed once, and the episode scores they sum to."""
        if self.closed_form:
            per_step = linear_scores(self.log_likelihood, episodes, per_step=True)
        else:
            per_step = step_scores(self.log_likelihood, episodes)
        time_dim = episodes.batch_dims - 1
        return {name: score.sum(time_dim) for name, score in per_step.items()}, per_step

    def estimate_from_episodes(self, episodes, scores, returns, per_step):
        run_dims = episodes.batch_dims - 2
        rewards = step_rewards(episodes, self.tensor_keys.reward, self.episode_return)
        gradient, baseline = gpomdp_gradient(flatten_scores(per_step, run_dims + 1), rewards)
        return gradient, {"baseline": baseline}
