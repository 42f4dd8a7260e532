"""PGPE's exploration: the controller's parameters drawn once per episode (Sehnke et al. 2010).

Parameter-exploring policy gradients (PGPE; Sehnke, Osendorfer, Rückstieß, Graves, Peters,
Schmidhuber, "Parameter-exploring policy gradients", Neural Networks 23(4), 2010, section 2)
explore in the controller's parameter space: at the start of every episode the parameters are
drawn from ``θ ~ N(μ, diag(σ²))`` and the controller ``u = f(x; θ)`` then runs deterministically
for the whole episode. ``μ`` are the actor's own parameters; :class:`ParameterExplorer` holds
``σ`` and draws ``θ``. Its estimator is :class:`~sde_torchrl.objectives.pgpe.PGPEEstimator`.

The draw travels in the tensordict as SDE's noise matrix does: the standard-normal ``ξ`` under
``pgpe_noise`` (``[*batch, K]`` for ``K`` controller parameters, redrawn where ``is_init`` is
set), and the episode's parameters ``θ = μ + σ ⊙ ξ`` under ``pgpe_parameters``, which the
estimator reads. With symmetric sampling (Sehnke et al. 2010, section 2.3) the episodes of a
batch come in pairs ``θ± = μ ± ε`` along the last batch dimension (episodes ``2k`` and ``2k+1``).

On a linear controller ``u = Θ x`` the draw is ``(Θ + σ ⊙ ξ) x``: SDE's action with the noise
matrix held for the episode (Rückstieß et al. eqs. 17-19 with ``σ̂ = σ``): the two methods then
explore alike and differ only in their gradient estimates.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from torch import nn
from torch.func import functional_call, vmap
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, TensorDictPrimer

from sde_torchrl.modules.actors import BatchedLinear
from sde_torchrl.modules.noise import deterministic_exploration
from sde_torchrl.modules.sde import expln
from sde_torchrl.utils.checks import finite, positive_int
from sde_torchrl.utils.rng import RunStreams, draw_normal
from sde_torchrl.utils.shapes import align


class ParameterExplorer(TensorDictModuleBase):
    """Draws the controller's parameters ``θ ~ N(μ, diag(σ²))`` once per episode (PGPE).

    Follows the actor in ``TensorDictSequential(actor, explorer)``: it reads the actor's inputs,
    evaluates the actor's network with the episode's ``θ`` in place of ``μ`` (``torch.func``,
    one parameter vector per batch element) and writes:

    * ``action``: ``squash(f(x; θ))``; ``tanh`` if ``squash`` is set;
    * ``action_sample``: the same before squashing;
    * ``pgpe_noise``: the standard-normal ``ξ`` ``[*batch, K]``, carried from step to step and
      redrawn where ``is_init`` is set (drawn where the input carries none);
    * ``pgpe_parameters``: ``θ = μ + σ ⊙ ξ`` ``[*batch, K]``, what the estimator scores.

    The ``K`` entries of ``θ`` are the actor network's learnable parameters flattened in
    ``named_parameters`` order (per run). With ``symmetric``, the last batch dimension (the
    episodes) must be even: episodes ``2k`` and ``2k+1`` get ``ξ`` and ``-ξ`` (Sehnke et al.
    2010, section 2.3). Under ``ExplorationType.DETERMINISTIC`` (or ``MODE``/``MEAN``) nothing
    is drawn and the action is ``squash(loc)``, the controller at ``μ``.

    ``σ`` is the learned parameter itself (``sigma``, ``[*runs, K]``), as in PGPE's update of
    ``σ``; its start value is ``expln(init_param)`` (Rückstieß et al. eq. 23), the start value
    SDE's ``σ̂`` has for the same ``init_param``. The distribution depends on ``σ²`` only: a step
    may change the sign of an entry, and the scores stay those of ``|σ|``.

    Args:
        actor: the policy's actor, a ``TensorDictModule`` whose ``module`` is the controller
            network (held, not registered: it is the policy's first module).
        symmetric: symmetric sampling ``θ± = μ ± ε`` over pairs of episodes.
        init_param: ``σ`` starts at ``expln(init_param)`` for every parameter (-2: ≈ 0.135).
        learn_sigma: ``σ`` is a learnable parameter (else a fixed buffer).
        squash: apply ``tanh`` to the action.
        runs: number of independent runs stacked along the actor's leading parameter dimension,
            or ``None`` for an unstacked actor.

    Raises:
        ArgumentError: ``runs`` or ``init_param`` is not allowed.
        ValueError: the actor has no learnable parameter, or its parameters are not stacked
            over ``runs``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from sde_torchrl import LinearActor
        >>> actor = LinearActor(3, 2, init=0.0)
        >>> explorer = ParameterExplorer(actor)
        >>> td = actor(TensorDict({"observation": torch.randn(6, 3)}, [6]))
        >>> out = explorer(td)
        >>> out["action"].shape, out["pgpe_parameters"].shape
        (torch.Size([6, 2]), torch.Size([6, 6]))
        >>> torch.equal(out["pgpe_parameters"][0], -out["pgpe_parameters"][1])  # μ = 0: θ± = ±ε
        True
    """

    #: The tensordict keys it reads and writes (besides the actor's inputs).
    loc_key, noise_key, parameters_key, is_init_key = "loc", "pgpe_noise", "pgpe_parameters", "is_init"
    sample_key, action_key = "action_sample", "action"

    def __init__(
        self, actor: TensorDictModule, *, symmetric: bool = True, init_param: float = -2.0,
        learn_sigma: bool = True, squash: bool = False, runs: int | None = None,
    ) -> None:
        super().__init__()
        if runs is not None:
            positive_int("runs", runs)
        finite("init_param", init_param)
        # A plain tuple: the network stays the actor's (registering it here too would list its
        # parameters twice in the policy's state dict).
        self._network: tuple[nn.Module] = (actor.module,)
        self.actor_in_keys = list(actor.in_keys)
        self.symmetric, self.squash, self.runs = symmetric, squash, runs
        self.run_dims = 0 if runs is None else 1
        self.streams: RunStreams | None = None
        self.parameter_names = [n for n, p in actor.module.named_parameters() if p.requires_grad]
        if not self.parameter_names:
            raise ValueError("ParameterExplorer: the actor has no learnable parameter to explore")
        shapes = [p.shape for n, p in actor.module.named_parameters() if p.requires_grad]
        if runs is not None and any(len(s) == 0 or s[0] != runs for s in shapes):
            raise ValueError(f"ParameterExplorer: the actor's parameters {[tuple(s) for s in shapes]} are not "
                             f"stacked over runs={runs} (build the actor with runs={runs})")
        self.parameter_shapes = [s[self.run_dims:] for s in shapes]
        self.num_parameters = sum(math.prod(s) for s in self.parameter_shapes)
        sigma = expln(torch.full((*([runs] if runs else []), self.num_parameters), float(init_param)))
        if learn_sigma:
            self.sigma = nn.Parameter(sigma)
        else:
            self.register_buffer("sigma", sigma)
        self.in_keys = [self.loc_key, *self.actor_in_keys, self.noise_key, self.is_init_key]
        self.out_keys = [self.action_key, self.sample_key, self.noise_key, self.parameters_key]

    @property
    def network(self) -> nn.Module:
        """The actor's network, whose parameters are ``μ``."""
        return self._network[0]

    def mean(self) -> torch.Tensor:
        """``μ``: the actor network's learnable parameters flattened per run, ``[*runs, K]``."""
        params = dict(self.network.named_parameters())
        lead = self.sigma.shape[:-1]
        return torch.cat([params[n].reshape(*lead, -1) for n in self.parameter_names], -1)

    def exploration_scale(self) -> torch.Tensor:
        """``|σ|`` per run and parameter, ``[*runs, K]`` (the density is even in ``σ``): what
        ``metrics.csv`` reports as ``sigma_min`` / ``sigma_max``."""
        return self.sigma.detach().abs()

    def make_tensordict_primer(self) -> Compose:
        """Primer that gives every (partially) reset env a ``pgpe_noise`` entry (redrawn by the
        explorer where ``is_init`` is set; append it with ``InitTracker`` to the env)."""
        return Compose(TensorDictPrimer(
            Composite({self.noise_key: Unbounded(shape=(self.num_parameters,))}), random=True, expand_specs=True))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc = tensordict.get(self.loc_key)
        inputs = [tensordict.get(key) for key in self.actor_in_keys]
        batch = loc.shape[:-1]
        noise = tensordict.get(self.noise_key, None)
        if deterministic_exploration():  # nothing drawn: evaluation does not shift the streams
            sample, parameters = loc, align(self.mean(), self.run_dims, len(batch)).expand(*batch, self.num_parameters)
        else:
            noise = self.next_noise(noise, tensordict.get(self.is_init_key, None), batch)
            parameters = self.perturbed(noise)
            sample = self.controller(parameters, inputs)
        if noise is not None:
            tensordict.set(self.noise_key, noise)
        tensordict.set(self.parameters_key, parameters)
        tensordict.set(self.sample_key, sample)
        tensordict.set(self.action_key, torch.tanh(sample) if self.squash else sample)
        return tensordict

    def perturbed(self, noise: torch.Tensor) -> torch.Tensor:
        """The episodes' parameters ``θ = μ + σ ⊙ ξ ~ N(μ, diag(σ²))`` from the standard-normal
        draws ``ξ`` (Sehnke et al. 2010, section 2): what :meth:`forward` acts with.

        Args:
            noise: ``ξ`` ``[*runs, *B, K]``.

        Returns:
            ``θ`` ``[*runs, *B, K]``.

        Examples:
            >>> from sde_torchrl import LinearActor
            >>> explorer = ParameterExplorer(LinearActor(1, 1, init=-2.0), init_param=0.0)  # σ = 1
            >>> explorer.perturbed(torch.tensor([[0.5], [-0.5]]))
            tensor([[-1.5000],
                    [-2.5000]], grad_fn=<AddBackward0>)
        """
        batch_dims = noise.dim() - 1
        return align(self.mean(), self.run_dims, batch_dims) + align(self.sigma, self.run_dims, batch_dims) * noise

    def episode_controller(self, parameters: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        """``x ↦ f(x; θ)`` under parameters ``θ`` held for whole episodes: :meth:`controller`
        as a function of the input alone, for a caller that steps episodes with tensors.

        For a bias-free :class:`~sde_torchrl.modules.actors.BatchedLinear` network ``θ`` is
        reshaped once into the maps ``Θ`` ``[*runs, *B, A, S]`` and every call is the batched
        product ``Θ x`` that :meth:`controller` computes for each row (the same product, so
        the same numbers); any other network is evaluated by :meth:`controller` at every call.

        Args:
            parameters: ``θ`` ``[*runs, *B, K]``.

        Returns:
            A function of the input ``[*runs, *B, S]`` giving the output ``[*runs, *B, A]``.

        Examples:
            >>> from sde_torchrl import LinearActor
            >>> explorer = ParameterExplorer(LinearActor(2, 1, bias=False, init=0.0))
            >>> f = explorer.episode_controller(torch.tensor([[1.0, 2.0], [3.0, 4.0]]))
            >>> f(torch.tensor([[1.0, 1.0], [1.0, 0.0]]))
            tensor([[3.],
                    [3.]])
        """
        network = self.network
        if isinstance(network, BatchedLinear) and network.bias is None and self.parameter_names == ["weight"]:
            maps = parameters.reshape(*parameters.shape[:-1], network.out_features, network.in_features)
            transposed = maps.transpose(-1, -2)
            return lambda x: (x.unsqueeze(-2) @ transposed).squeeze(-2)
        return lambda x: self.controller(parameters, [x])

    def next_noise(self, previous: torch.Tensor | None, is_init: torch.Tensor | None,
                   batch: torch.Size) -> torch.Tensor:
        """``ξ`` for this step: the previous one, or a fresh draw where an episode starts
        (``is_init``; without it, only where no previous ``ξ`` is carried).

        Fresh draws are ``N(0, 1)`` per batch element, or with ``symmetric`` ``ξ`` for the even
        episodes and ``-ξ`` for the odd ones (the last batch dimension). They come from the
        per-run ``streams`` (runs first) when set, else from torch's global generator.

        Raises:
            ValueError: ``symmetric`` with an odd number of episodes.
        """
        if previous is not None and (is_init is None or not bool(is_init.any())):
            return previous
        if self.symmetric:
            if not batch or batch[-1] % 2:
                raise ValueError(f"ParameterExplorer(symmetric=True) pairs the episodes of the last batch dimension: "
                                 f"it needs an even number of them, got batch {tuple(batch)}")
            half = draw_normal((*batch[:-1], batch[-1] // 2, self.num_parameters), self.streams)
            fresh = torch.stack([half, -half], dim=-2).reshape(*batch, self.num_parameters)
        else:
            fresh = draw_normal((*batch, self.num_parameters), self.streams)
        fresh = fresh.to(self.sigma.device)  # drawn on the CPU (the streams'), used on the parameters' device
        if previous is None:
            return fresh
        return torch.where(is_init.reshape(*batch, 1), fresh, previous)

    def controller(self, parameters: torch.Tensor, inputs: list[torch.Tensor]) -> torch.Tensor:
        """``f(x; θ)`` with one parameter vector ``θ`` per batch element.

        Args:
            parameters: ``θ`` ``[*runs, *B, K]``.
            inputs: the actor's inputs, each ``[*runs, *B, ...]``.

        Returns:
            The controller's output ``[*runs, *B, A]``.
        """
        lead, rows = parameters.shape[:self.run_dims], parameters.shape[self.run_dims:-1]
        flat = parameters.reshape(*lead, -1, self.num_parameters)
        sizes = [math.prod(s) for s in self.parameter_shapes]
        params = {name: chunk.reshape(*chunk.shape[:-1], *shape) for name, chunk, shape in
                  zip(self.parameter_names, flat.split(sizes, -1), self.parameter_shapes, strict=True)}
        xs = [x.reshape(*lead, flat.shape[self.run_dims], *x.shape[len(lead) + len(rows):]) for x in inputs]

        def one_row(p: dict[str, torch.Tensor], *x: torch.Tensor) -> torch.Tensor:
            return functional_call(self.network, p, x)

        out = vmap(one_row, in_dims=self.run_dims, out_dims=self.run_dims)(params, *xs)
        return out.reshape(*lead, *rows, out.shape[-1])
