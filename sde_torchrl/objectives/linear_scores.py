"""The scores of a linear SDE controller in closed form (eqs. 16, 21, 24), without autograd.

For the paper's controller ``u = Θ x + Θ̂ x`` (a bias-free linear map of the exploration features,
no Gaussian part) each step's log-likelihood (eqs. 13, 20) has the derivatives

* ``∂ log π / ∂θ_ji = (u_j − μ_j) / σ_j² · x_i`` (eq. 16),
* ``∂ log π / ∂σ̂_ji = ((u_j − μ_j)² − σ_j²) / σ_j⁴ · x_i² σ̂_ji`` (eq. 21), times ``expln'(p)``
  (eq. 24; ``exp(p)`` for ``sigma_transform="exp"``) for ``σ̂``'s parameter ``p``, summed over the
  entries a shared ``p`` stands for,

with ``μ = Θ x`` and ``σ_j² = Σ_i (x_i σ̂_ji)²``. With the authors' variance weighting each
action's log-likelihood is multiplied by its constant ``σ_j²``, which multiplies both by ``σ_j²``.
:func:`linear_scores` evaluates them for whole batches of episodes in a few tensor operations;
:func:`~sde_torchrl.objectives.estimators.episode_scores` differentiates the same likelihood with
``vmap(grad(...))`` for any actor. The two agree to float rounding, not bit for bit: the
estimators take the closed form when built with ``scores="closed_form"`` (the top-level
``scores=closed_form`` of a config).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule

from sde_torchrl.modules.actors import BatchedLinear
from sde_torchrl.modules.distribution import MIN_VARIANCE
from sde_torchrl.utils.shapes import align, stacked_matvec

__all__ = ["closed_form_refusal", "linear_scores"]

def closed_form_refusal(log_likelihood: torch.nn.Module) -> str | None:
    """Why :func:`linear_scores` cannot score ``log_likelihood``'s policy, or ``None`` if it can.

    It needs an actor that is one ``TensorDictModule`` over a bias-free
    :class:`~sde_torchrl.modules.actors.BatchedLinear` reading the exploration features and
    writing the ``loc`` the likelihood reads, stacked over the same runs as ``σ̂``; no Gaussian
    part (eq. 22); and no learnable parameter but ``Θ`` and ``σ̂``'s.

    Args:
        log_likelihood: an :class:`~sde_torchrl.objectives.estimators.EpisodeLogLikelihood`.

    Examples:
        >>> from sde_torchrl import LinearActor, MLPActor, SDEParams, make_sde_actor
        >>> from sde_torchrl.objectives.estimators import EpisodeLogLikelihood
        >>> closed_form_refusal(EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3)))) is None
        True
        >>> closed_form_refusal(EpisodeLogLikelihood(make_sde_actor(MLPActor(3, 2, hidden=(4,)), SDEParams(2, 4))))
        'the actor is not one bias-free linear layer of the exploration features'
    """
    actor, sde = log_likelihood.actor, log_likelihood.sde
    modules = list(actor.module)
    layer = modules[0].module if len(modules) == 1 and isinstance(modules[0], TensorDictModule) else None
    if not (isinstance(layer, BatchedLinear) and layer.bias is None
            and modules[0].in_keys == [log_likelihood.feature_key]):
        return "the actor is not one bias-free linear layer of the exploration features"
    if modules[0].out_keys != [log_likelihood.loc_key]:
        return f"the actor writes {modules[0].out_keys}, the likelihood reads {log_likelihood.loc_key!r}"
    if layer.run_dims != sde.run_dims:
        return "the actor and SDEParams are not stacked over the same runs"
    if sde.has_gaussian:
        return "the exploration has a Gaussian part (eq. 22)"
    known = {id(layer.weight), id(sde.sigma_param)}
    others = [name for name, p in log_likelihood.named_parameters() if p.requires_grad and id(p) not in known]
    if others:
        return f"learnable parameters other than Θ and σ̂: {others}"
    return None


def linear_scores(log_likelihood: torch.nn.Module, episodes: TensorDictBase,
                  per_step: bool = False) -> dict[str, torch.Tensor]:
    """Each episode's (or step's) score per learnable parameter, from eqs. 16, 21 and 24.

    The same result as :func:`~sde_torchrl.objectives.estimators.episode_scores` (and, with
    ``per_step``, :func:`~sde_torchrl.objectives.estimators.step_scores`), to float rounding.

    Args:
        log_likelihood: an :class:`~sde_torchrl.objectives.estimators.EpisodeLogLikelihood`
            that :func:`closed_form_refusal` accepts.
        episodes: TensorDict shaped ``[*runs, N, T]`` with the features and the action samples.
        per_step: the score of every step rather than their sums over each episode.

    Returns:
        ``{parameter name: ψ}`` in the likelihood's parameter order, ``ψ`` shaped ``[*runs, N,
        *parameter_shape[len(runs):]]`` (``[*runs, N, T, ...]`` with ``per_step``).

    Raises:
        ValueError: the policy is not of that form (naming why), or the episodes are not
            shaped ``[*runs, N, T]``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from sde_torchrl import LinearActor, SDEParams, make_sde_actor
        >>> from sde_torchrl.objectives.estimators import EpisodeLogLikelihood, episode_scores
        >>> likelihood = EpisodeLogLikelihood(make_sde_actor(LinearActor(3, 2), SDEParams(2, 3)))
        >>> steps = TensorDict({"observation": torch.randn(4, 10, 3), "action": torch.randn(4, 10, 2)}, [4, 10])
        >>> closed, autograd = linear_scores(likelihood, steps), episode_scores(likelihood, steps)
        >>> all(torch.allclose(closed[n], autograd[n], rtol=1e-4, atol=1e-5) for n in autograd)
        True
    """
    refusal = closed_form_refusal(log_likelihood)
    if refusal is not None:
        raise ValueError(f"closed-form scores need a linear SDE controller: {refusal}; use scores=autograd")
    if episodes.batch_dims < 2:
        raise ValueError(f"episodes must be shaped [*runs, episodes, time], got batch {tuple(episodes.batch_size)}")
    sde, layer = log_likelihood.sde, log_likelihood.actor.module[0].module
    with torch.no_grad():
        weight, sigma_param = layer.weight, sde.sigma_param
        sigma = sde.sde_sigma.to(weight.dtype)  # σ̂ [*runs, A, S]
        features = episodes.get(log_likelihood.feature_key)
        loc = stacked_matvec(weight, features, layer.run_dims)  # μ = Θ x, the actor's own product
        x = features.to(loc.dtype)
        error = episodes.get(log_likelihood.sample_key) - loc  # u − μ
        raw_variance = stacked_matvec(sigma.square(), x.square(), sde.run_dims)  # σ_j² (eq. 20)
        variance = raw_variance.clamp_min(MIN_VARIANCE)
        if log_likelihood.variance_weighted:  # σ_j² times eqs. 16 and 21
            d_loc, d_variance = error, (error.square() - variance) / (2 * variance)
        else:
            d_loc, d_variance = error / variance, (error.square() - variance) / (2 * variance.square())
        d_variance = d_variance * (raw_variance >= MIN_VARIANCE)  # the floor passes no gradient
        pattern = "...ta,...ts->...tas" if per_step else "...ta,...ts->...as"
        batch_dims = episodes.batch_dims - (0 if per_step else 1)
        scores = {}
        for name, param in log_likelihood.named_parameters():
            if not param.requires_grad:
                continue
            if param is weight:  # eq. 16
                scores[name] = torch.einsum(pattern, d_loc, x)
            else:  # eq. 21 (∂σ_j²/∂σ̂_ji = 2 x_i² σ̂_ji), times eq. 24, summed where p is shared
                d_sigma = torch.einsum(pattern, d_variance, x.square()) * 2 * align(sigma, sde.run_dims, batch_dims)
                d_sigma = d_sigma * align(_sigma_derivative(sigma_param, sde.sigma_transform), sde.run_dims,
                                          batch_dims)
                shared = [dim for dim in (-2, -1) if sigma_param.shape[dim] == 1 and d_sigma.shape[dim] != 1]
                scores[name] = d_sigma.sum(shared, keepdim=True) if shared else d_sigma
    return scores


def _sigma_derivative(p: torch.Tensor, transform: str) -> torch.Tensor:
    """``dσ̂/dp``: ``expln'(p)`` (eq. 24: ``exp(p)`` for ``p <= 0``, ``1 / (p + 1)`` above) or ``exp(p)``."""
    if transform == "exp":
        return torch.exp(p)
    return torch.where(p <= 0, torch.exp(p.clamp(max=0)), 1 / (p.clamp(min=0) + 1))
