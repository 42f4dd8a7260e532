"""PGPE's gradient estimates of ``μ`` and ``σ`` (Sehnke et al. 2010), as a TorchRL loss module.

PGPE (Sehnke, Osendorfer, Rückstieß, Graves, Peters, Schmidhuber, Neural Networks 23(4), 2010,
section 2) maximises ``J(μ, σ) = E_{θ ~ N(μ, diag(σ²))}[R(θ)]`` by the likelihood-ratio
gradient of the parameter distribution, estimated from ``N`` episodes run with ``θ_n``:
``∇_ρ J ≈ (1/N) Σ_n ∇_ρ log p(θ_n | ρ) (R_n − b)`` (section 2.2, "sampling with a baseline":
:func:`pgpe_gradient`, the scores :func:`parameter_scores`), or from pairs ``θ± = μ ± ε``
(section 2.3, symmetric sampling: :func:`symmetric_pgpe_gradient`). :class:`PGPEEstimator`
reads the episodes of a :class:`~sde_torchrl.modules.pgpe.ParameterExplorer` and gives what the
other estimators give.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from tensordict.utils import NestedKey
from torch import nn

from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.objectives.base import (
    EpisodesError,
    GradientEstimator,
    MissingEpisodesKeyError,
    NonFiniteEpisodesError,
    check_rewards_runs_and_inputs,
)
from sde_torchrl.utils.nonfinite import GUARDED_FIX, check_finite


def batch_mean_baseline(returns: torch.Tensor) -> torch.Tensor:
    """The baseline ``b``: the mean of ``returns`` ``[*runs, N]`` over the batch, ``[*runs]``.

    Not the moving average of the paper's algorithms: the estimate then depends on the batch
    alone, so that runs stack and jobs resume bit for bit with no estimator state. It includes
    each episode's own return, which scales the expected gradient by ``(N − 1)/N``.
    """
    return returns.mean(-1)


def pgpe_gradient(
    perturbations: torch.Tensor, returns: torch.Tensor, sigma: torch.Tensor, variance_weighted: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PGPE with a baseline (Sehnke et al. 2010, section 2.2) on independent draws.

    ``g_μ = (1/N) Σ_n (R_n − b) (θ_n − μ) / σ²`` and ``g_σ = (1/N) Σ_n (R_n − b) ((θ_n − μ)² −
    σ²) / σ³``, with ``b`` the batch mean (:func:`batch_mean_baseline`); both times ``σ²`` with
    ``variance_weighted``.

    Args:
        perturbations: ``θ_n − μ``, ``[*runs, N, K]``.
        returns: ``R_n``, ``[*runs, N]``.
        sigma: ``σ``, ``[*runs, K]``.
        variance_weighted: the paper's step sizes ``α_i = α σ_i²``.

    Returns:
        ``(g_μ, g_σ, b)``: ``[*runs, K]``, ``[*runs, K]``, ``[*runs]``.

    Examples:
        >>> eps = torch.tensor([[1.0], [-1.0]])
        >>> g_mu, g_sigma, b = pgpe_gradient(eps, torch.tensor([3.0, 1.0]), torch.tensor([0.5]))
        >>> g_mu, g_sigma, b  # (1·1 + (−1)·(−1)) / 2 / 0.25 = 4; (1·0.75 − 1·0.75) / 2 / 0.125 = 0
        (tensor([4.]), tensor([0.]), tensor(2.))
    """
    baseline = batch_mean_baseline(returns)
    advantage = (returns - baseline.unsqueeze(-1)).unsqueeze(-1)
    variance = sigma.unsqueeze(-2).square()
    g_mu = (advantage * perturbations).mean(-2) / variance.squeeze(-2)
    g_sigma = (advantage * (perturbations.square() - variance)).mean(-2) / sigma.pow(3)
    return _weighted(g_mu, g_sigma, sigma, variance_weighted) + (baseline,)


def symmetric_pgpe_gradient(
    perturbations: torch.Tensor, plus: torch.Tensor, minus: torch.Tensor, sigma: torch.Tensor,
    variance_weighted: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PGPE with symmetric sampling (Sehnke et al. 2010, section 2.3) on ``P`` pairs ``μ ± ε``.

    ``g_μ = (1/P) Σ_k ε_k (r+_k − r−_k) / (2 σ²)``; ``g_σ = (1/P) Σ_k (m_k − b) (ε_k² − σ²) / σ³``
    with ``m_k = (r+_k + r−_k)/2`` and ``b`` their mean (:func:`batch_mean_baseline`); both
    times ``σ²`` with ``variance_weighted``.

    Args:
        perturbations: ``ε_k``, ``[*runs, P, K]``.
        plus: returns of ``μ + ε_k``, ``[*runs, P]``.
        minus: returns of ``μ − ε_k``, ``[*runs, P]``.
        sigma: ``σ``, ``[*runs, K]``.
        variance_weighted: the paper's step sizes ``α_i = α σ_i²``.

    Returns:
        ``(g_μ, g_σ, b)``: ``[*runs, K]``, ``[*runs, K]``, ``[*runs]``.

    Examples:
        >>> eps = torch.tensor([[0.5]])
        >>> symmetric_pgpe_gradient(eps, torch.tensor([3.0]), torch.tensor([1.0]), torch.tensor([0.5]))
        (tensor([2.]), tensor([0.]), tensor(2.))
    """
    mid = (plus + minus) / 2
    baseline = batch_mean_baseline(mid)
    variance = sigma.square()
    g_mu = (perturbations * ((plus - minus) / 2).unsqueeze(-1)).mean(-2) / variance
    g_sigma = ((mid - baseline.unsqueeze(-1)).unsqueeze(-1) * (perturbations.square() - variance.unsqueeze(-2))
               ).mean(-2) / sigma.pow(3)
    return _weighted(g_mu, g_sigma, sigma, variance_weighted) + (baseline,)


def kept_pgpe_gradient(
    perturbations: torch.Tensor, sigmas: torch.Tensor, returns: torch.Tensor, sigma: torch.Tensor,
    variance_weighted: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`pgpe_gradient` with each episode scored under the distribution that drew it:
    ``g_μ = (1/N) Σ_n (R_n − b) (θ_n − μ_n) / σ_n²`` and ``g_σ = (1/N) Σ_n (R_n − b) ((θ_n −
    μ_n)² − σ_n²) / σ_n³``, ``μ_n, σ_n`` those of episode ``n``'s draw; with ``variance_weighted``
    both times the current ``σ²`` (the step sizes ``α_i = α σ_i²`` of the update).

    Args:
        perturbations: ``θ_n − μ_n``, ``[*runs, N, K]``.
        sigmas: ``σ_n``, ``[*runs, N, K]``.
        returns: ``R_n``, ``[*runs, N]``.
        sigma: the current ``σ``, ``[*runs, K]``.
        variance_weighted: the paper's step sizes.

    Returns:
        ``(g_μ, g_σ, b)``: ``[*runs, K]``, ``[*runs, K]``, ``[*runs]``.

    Examples:
        >>> eps, sigma = torch.tensor([[1.0], [-1.0]]), torch.tensor([0.5])
        >>> kept = kept_pgpe_gradient(eps, sigma.expand(2, 1), torch.tensor([3.0, 1.0]), sigma)
        >>> all(torch.allclose(a, b) for a, b in zip(kept, pgpe_gradient(eps, torch.tensor([3.0, 1.0]), sigma)))
        True
    """
    baseline = batch_mean_baseline(returns)
    advantage = (returns - baseline.unsqueeze(-1)).unsqueeze(-1)
    mu_score, sigma_score = parameter_scores(perturbations, sigmas)
    g_mu, g_sigma = (advantage * mu_score).mean(-2), (advantage * sigma_score).mean(-2)
    return _weighted(g_mu, g_sigma, sigma, variance_weighted) + (baseline,)


def _weighted(g_mu: torch.Tensor, g_sigma: torch.Tensor, sigma: torch.Tensor,
              variance_weighted: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Both gradients times ``σ²`` (``α_i = α σ_i²``) if ``variance_weighted``: the paper's step
    sizes, which turn the estimates into its update rules ``Δμ_i = α ε_i (r+ − r−)/2`` and
    ``Δσ_i = α ((r+ + r−)/2 − b)(ε_i² − σ_i²)/σ_i`` (``Δμ_i = α (r − b)(θ_i − μ_i)`` without
    symmetry): the counterpart of the authors' variance-weighted SDE scores
    (``EpisodeLogLikelihood``)."""
    if not variance_weighted:
        return g_mu, g_sigma
    variance = sigma.square()
    return g_mu * variance, g_sigma * variance


def parameter_scores(perturbations: torch.Tensor, sigma: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``∂ log p(θ | μ, σ) / ∂μ = (θ − μ)/σ²`` and ``∂/∂σ = ((θ − μ)² − σ²)/σ³``, from
    ``θ − μ`` ``[*runs, N, K]`` and ``σ`` ``[*runs, K]``, or ``[*runs, N, K]`` for each episode's
    own ``σ`` (Sehnke et al. 2010, section 2.2)."""
    if sigma.dim() < perturbations.dim():
        sigma = sigma.unsqueeze(-2)
    variance = sigma.square()
    return perturbations / variance, (perturbations.square() - variance) / sigma.pow(3)


#: The expected policy, as the errors name it.
POLICY_FORM = "TensorDictSequential(actor, ParameterExplorer(actor))"


class PGPEEstimator(GradientEstimator):
    """PGPE's estimate of the gradient of ``μ`` (the actor's parameters) and ``σ`` (the
    explorer's), from whole episodes collected with a :class:`~sde_torchrl.modules.pgpe.ParameterExplorer`.

    Reads each episode's parameters ``θ`` (``pgpe_parameters`` at its first step) and its
    return, and estimates with :func:`pgpe_gradient`, or :func:`symmetric_pgpe_gradient` when
    the explorer samples symmetrically (``ε_k = (θ_2k − θ_2k+1)/2`` from each pair of episodes).
    Plain sampling scores ``θ`` against the current ``μ`` and ``σ``, as the other estimators
    score queued actions with the current policy. The output is the other estimators':
    ``loss_objective`` is ``−Σ g·θ`` over :meth:`learnable_parameters`, so that one
    ``SGD(lr=α)`` step is ``ρ ← ρ + α g``; diagnostics ``baseline`` and ``score_norm`` (the
    mean norm of the episodes' scores ``∇_ρ log p(θ_n | ρ)``).

    Args:
        policy: ``TensorDictSequential(actor, ParameterExplorer(actor))``.
        max_grad_norm: bound on each run's gradient norm (``None``: plain ascent).
        max_grad_entry: rescale a run's gradient whose largest (signed) entry exceeds this.
        episode_return: ``"mean"`` or ``"sum"`` of an episode's rewards.
        variance_weighted: the paper's step sizes ``α_i = α σ_i²``, which give its update rules
            (``Δμ_i = α ε_i (r+ − r−)/2`` with symmetric sampling).

    NaN or infinity in the episodes raise :class:`NonFiniteEpisodesError` under the non-finite
    policy ``"raise"`` (the default) and give NaN estimates for the runs concerned under
    ``"guarded"``, the trainer's (:mod:`sde_torchrl.utils.nonfinite`).

    Raises:
        TypeError: ``policy`` is not of that form.
        ValueError: an option is not allowed.

    Examples:
        >>> import torch
        >>> from tensordict.nn import TensorDictSequential
        >>> from sde_torchrl import LinearActor, make_minimize_env
        >>> from sde_torchrl.modules.pgpe import ParameterExplorer
        >>> from sde_torchrl.collectors.rollout import collect_episodes
        >>> actor = LinearActor(1, 1, init=-2.0)
        >>> explorer = ParameterExplorer(actor)
        >>> env = make_minimize_env(5, episodes=8).append_transform(explorer.make_tensordict_primer())
        >>> policy = TensorDictSequential(actor, explorer)
        >>> out = PGPEEstimator(policy, episode_return="sum")(collect_episodes(env, policy, 5))
        >>> out["gradient"].shape  # μ (one entry) and σ (one entry)
        torch.Size([2])
        >>> out["loss_objective"].backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable keys (``set_keys``).

        Attributes:
            reward: per-step reward. Defaults to ``("next", "reward")``.
            parameters: each step's controller parameters ``θ``. Defaults to the explorer's
                ``parameters_key``.
        """

        reward: NestedKey = ("next", "reward")
        parameters: NestedKey = ParameterExplorer.parameters_key

    tensor_keys: _AcceptedKeys

    def __init__(
        self, policy: TensorDictSequential, max_grad_norm: float | None = None, *,
        max_grad_entry: float | None = None, episode_return: str = "mean", variance_weighted: bool = False,
    ) -> None:
        super().__init__(max_grad_norm, max_grad_entry, episode_return)
        modules = list(policy.module) if isinstance(policy, TensorDictSequential) else []
        if len(modules) != 2 or not isinstance(modules[1], ParameterExplorer):
            raise TypeError(f"policy: got {type(policy).__name__}"
                            f"({', '.join(type(m).__name__ for m in modules)}); expected {POLICY_FORM}")
        if modules[1].network is not modules[0].module:
            raise TypeError(f"policy: the ParameterExplorer explores another actor's parameters; "
                            f"expected {POLICY_FORM}")
        self.variance_weighted = variance_weighted
        self.actor, self.explorer = modules
        self._tensor_keys = self._AcceptedKeys(parameters=self.explorer.parameters_key)
        self._forward_value_estimator_keys()

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """Called by ``set_keys``: refreshes ``in_keys``."""
        self.in_keys = [self.tensor_keys.parameters, self.tensor_keys.reward]
        self.out_keys = ["loss_objective", "return_mean", "gradient"]

    def learnable_parameters(self) -> dict[str, nn.Parameter]:
        """``μ`` (the actor network's learnable parameters, in the explorer's order), then ``σ``
        if it is learned: the order of the flattened gradient."""
        params = dict(self.explorer.network.named_parameters())
        out = {f"actor.module.{n}": params[n] for n in self.explorer.parameter_names}
        if self._learns_sigma():
            out["explorer.sigma"] = self.explorer.sigma
        return out

    def perturbations(self, episodes: TensorDictBase) -> torch.Tensor:
        """``θ_n − μ`` of each episode under the current ``μ``, ``[*runs, N, K]``."""
        theta = episodes.get(self.tensor_keys.parameters)[..., 0, :]
        return theta - self.explorer.mean().detach().unsqueeze(-2)

    def scores(self, episodes: TensorDictBase) -> dict[str, torch.Tensor]:
        """Each episode's score ``∇_ρ log p(θ_n | ρ)`` per learnable parameter (named as in
        :meth:`learnable_parameters`), ``[*runs, N, *shape]``: what the trainer's guard names."""
        flat = self._flat_scores(self.perturbations(episodes), self.explorer.sigma.detach())
        params = self.learnable_parameters()
        run_dims = self.explorer.run_dims
        sizes = [p[(0,) * run_dims].numel() for p in params.values()]
        return {name: chunk.reshape(*chunk.shape[:-1], *p.shape[run_dims:])
                for (name, p), chunk in zip(params.items(), flat.split(sizes, -1), strict=True)}

    def _flat_scores(self, perturbations: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """The scores of :meth:`learnable_parameters`, concatenated, ``[*runs, N, K or 2K]``."""
        mu_score, sigma_score = parameter_scores(perturbations, sigma)
        return torch.cat([mu_score, sigma_score], -1) if self._learns_sigma() else mu_score

    def _learns_sigma(self) -> bool:
        return isinstance(self.explorer.sigma, nn.Parameter)

    def check_episodes(self, episodes: TensorDictBase) -> None:
        """Episodes ``[*runs, N, T]`` holding the keys read, ``θ`` shaped ``[..., K]`` and the
        same at every step of a row (one whole episode per row), an even ``N`` for symmetric
        sampling, finite values (under the non-finite policy ``"raise"``).

        Raises:
            TypeError: ``episodes`` is not a TensorDict.
            EpisodesError: the episodes break that contract.
            NonFiniteEpisodesError: NaN or infinity in a key read (under the non-finite policy ``"raise"``).
        """
        if not isinstance(episodes, TensorDictBase):
            raise TypeError(f"episodes: got {type(episodes).__name__}; expected a TensorDict shaped [*runs, N, T]")
        shape = tuple(episodes.batch_size)
        if len(shape) != self.explorer.run_dims + 2 or 0 in shape:
            raise EpisodesError(f"episodes have batch shape {shape}; PGPE needs [*runs, N, T] with "
                                f"{self.explorer.run_dims} run dimension(s) and N, T >= 1")
        for key in self.in_keys:
            if episodes.get(key, None) is None:
                raise MissingEpisodesKeyError(
                    f"episodes lack key {key!r}; the estimator reads {self.in_keys}: collect them with the policy "
                    "being trained (TensorDictSequential(actor, ParameterExplorer(actor)))", key)
        check_rewards_runs_and_inputs(episodes, self.tensor_keys.reward, self.explorer.runs,
                                      list(self.explorer.actor_in_keys))
        key, size = self.tensor_keys.parameters, self.explorer.num_parameters
        theta = episodes.get(key)
        if tuple(theta.shape) != (*shape, size):
            raise EpisodesError(f"episodes key {key!r} has shape {tuple(theta.shape)}, expected {(*shape, size)}", key)
        if self.explorer.symmetric and shape[-2] % 2:
            raise EpisodesError(f"symmetric sampling pairs episodes 2k and 2k+1, but the batch holds N={shape[-2]}")
        labels = ["run"] * self.explorer.run_dims + ["episode"]
        for name in self.in_keys:
            check_finite(f"episodes key {name!r}", episodes.get(name), labels,
                         f"the estimate would be NaN for those runs; re-collect them, {GUARDED_FIX} and get NaN "
                         "estimates", error=partial(NonFiniteEpisodesError, key=name))
        changes = (theta != theta[..., :1, :]) & torch.isfinite(theta)
        if bool(changes.any()):
            raise EpisodesError(f"episodes key {key!r} changes within a row: each row of [*runs, N, T] must be one "
                                "whole episode of one parameter draw; collect them with "
                                "sde_torchrl.collectors.rollout.collect_episodes(env, policy, T)", key)

    def collected_scores(self, episodes: TensorDictBase) -> TensorDict:
        """What scores each episode under the distribution that drew it, to be kept with it while
        it waits in an episode queue and handed back to :meth:`forward` (``scores=``): its
        ``perturbations`` ``θ_n − μ`` and ``sigma`` ``σ``, both ``[*runs, N, K]``, now.

        Raises:
            ValueError: the explorer samples symmetrically (kept scores are for plain
                sampling; a symmetric pair is scored by the difference of its draws).

        Examples:
            >>> from tensordict.nn import TensorDictSequential
            >>> from sde_torchrl import LinearActor, make_minimize_env
            >>> from sde_torchrl.modules.pgpe import ParameterExplorer
            >>> from sde_torchrl.collectors.rollout import collect_episodes
            >>> actor = LinearActor(1, 1, init=-2.0)
            >>> explorer = ParameterExplorer(actor, symmetric=False)
            >>> env = make_minimize_env(5, episodes=8).append_transform(explorer.make_tensordict_primer())
            >>> policy = TensorDictSequential(actor, explorer)
            >>> estimator = PGPEEstimator(policy, episode_return="sum")
            >>> episodes = collect_episodes(env, policy, 5)
            >>> kept = estimator.collected_scores(episodes)
            >>> kept.batch_size, kept["sigma"].shape
            (torch.Size([8]), torch.Size([8, 1]))
            >>> from_kept = estimator(episodes, scores=kept)["gradient"]
            >>> from_parameters = estimator(episodes)["gradient"]  # θ − μ again: rounded where |μ| ≫ |ε|
            >>> bool((from_kept - from_parameters).norm() <= 1e-4 * from_parameters.norm())
            True
        """
        if self.explorer.symmetric:
            raise ValueError("collected_scores is for plain sampling: this explorer samples symmetrically, and scores "
                             "each pair of episodes by the difference of its draws (use queue_scores=rescored, or "
                             "ParameterExplorer(..., symmetric=False))")
        perturbations = self.perturbations(episodes)
        sigma = torch.broadcast_to(self.explorer.sigma.detach().unsqueeze(-2), perturbations.shape).clone()
        return TensorDict({"perturbations": perturbations, "sigma": sigma}, batch_size=perturbations.shape[:-1])

    def _kept_scores(self, scores: TensorDictBase, episodes: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """``(θ_n − μ_n, σ_n)`` from :meth:`collected_scores`, checked against the episodes."""
        expected = (*episodes.batch_size[:-1], self.explorer.num_parameters)
        if not isinstance(scores, TensorDictBase) or any(
                scores.get(name, None) is None or tuple(scores.get(name).shape) != expected
                for name in ("perturbations", "sigma")):
            raise EpisodesError(f"scores: expected the TensorDict of collected_scores(episodes): perturbations "
                                f"and sigma, each shaped {expected} for episodes shaped {tuple(episodes.batch_size)}")
        return scores["perturbations"], scores["sigma"]

    def forward(self, episodes: TensorDictBase, scores: TensorDictBase | None = None) -> TensorDictBase:
        """Estimates one gradient per run from the episodes: with ``scores`` (from
        :meth:`collected_scores`) each episode scored under the distribution that drew it
        (:func:`kept_pgpe_gradient`), else under the current one.

        Returns:
            TensorDict with ``loss_objective``, ``return_mean``, ``gradient``, ``gradient_norm``,
            ``score_norm`` and ``baseline``.
        """
        self.check_episodes(episodes)
        returns = self.returns(episodes)
        sigma = self.explorer.sigma.detach()
        if scores is not None:
            perturbations, sigmas = self._kept_scores(scores, episodes)
            g_mu, g_sigma, baseline = kept_pgpe_gradient(perturbations, sigmas, returns, sigma, self.variance_weighted)
            gradient = torch.cat([g_mu, g_sigma], -1) if self._learns_sigma() else g_mu
            score_norm = self._flat_scores(perturbations, sigmas).norm(dim=-1).mean(-1)
            return self.surrogate(gradient, returns, self.explorer.run_dims, score_norm=score_norm, baseline=baseline)
        perturbations = self.perturbations(episodes)
        if self.explorer.symmetric:
            theta = episodes.get(self.tensor_keys.parameters)[..., 0, :]
            pairs = (theta[..., 0::2, :] - theta[..., 1::2, :]) / 2
            g_mu, g_sigma, baseline = symmetric_pgpe_gradient(
                pairs, returns[..., 0::2], returns[..., 1::2], sigma, self.variance_weighted)
        else:
            g_mu, g_sigma, baseline = pgpe_gradient(perturbations, returns, sigma, self.variance_weighted)
        gradient = torch.cat([g_mu, g_sigma], -1) if self._learns_sigma() else g_mu
        score_norm = self._flat_scores(perturbations, sigma).norm(dim=-1).mean(-1)
        return self.surrogate(gradient, returns, self.explorer.run_dims, score_norm=score_norm, baseline=baseline)

