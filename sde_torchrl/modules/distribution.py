"""The maths of state-dependent exploration (paper eqs. 13, 17-22), once, and the distribution built on it.

The functions here are the single home of SDE's per-step maths: the exploration matrix
``Θ̂ = σ̂ ⊙ ξ`` (:func:`noise_matrix`, eq. 18), the action ``u = loc + Θ̂ x [+ σ_gauss ε]``
(:func:`sde_sample`, eqs. 17-19, 22), its per-action variance (:func:`sde_variance`, eqs. 20, 22)
and the Gaussian log-likelihood (:func:`gaussian_log_prob`, eq. 13).
The episodic estimators and the fast collection paths call them as :class:`SDENormal` does.

TorchRL's PPO, A2C and SAC losses rebuild the policy's distribution from stored tensordict
entries and score the stored action (``get_dist`` then ``log_prob``). :class:`SDENormal` needs
only stored entries for that: the controller's mean ``loc``, the exploration standard deviations
``σ̂`` and the features ``x`` give the per-step Gaussian of eq. (20); the noise matrix ``ξ``
carried in the tensordict makes ``rsample()`` reproduce the action the policy took,
``u = loc + (σ̂ ⊙ ξ) x`` (eqs. 17-19). :class:`TanhSDENormal` squashes that action into
``[low, high]`` and scores it with the tanh transform's log-determinant.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch.distributions import Distribution, constraints

from sde_torchrl.modules.noise import draw_noise
from sde_torchrl.utils.shapes import compact_broadcast, stacked_matvec

#: Floor on the action variance, so that a zero state (no SDE noise) gives a finite likelihood.
MIN_VARIANCE = 1e-12
_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)
_HALF_LOG_2PI_E = 0.5 * math.log(2 * math.pi * math.e)
_LOG_2 = math.log(2.0)


def gaussian_log_prob(sample: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """``Σ_j log N(sample_j; loc_j, scale_j²)`` over the last dimension (eq. 13).

    Args:
        sample: the action, ``[*, A]``.
        loc: the mean, ``[*, A]``.
        scale: the per-action standard deviation, ``[*, A]``.

    Returns:
        The log-density, shape ``[*]``.

    Examples:
        >>> gaussian_log_prob(torch.zeros(2), torch.zeros(2), torch.ones(2))  # 2 · log N(0; 0, 1)
        tensor(-1.8379)
    """
    return (-0.5 * ((sample - loc) / scale).square() - scale.log() - _HALF_LOG_2PI).sum(-1)


def noise_matrix(sigma_hat: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """The exploration matrix ``Θ̂ = σ̂ ⊙ ξ``, ``Θ̂_ji ~ N(0, σ̂_ji²)`` (eq. 18).

    Args:
        sigma_hat: ``σ̂``, ``[*, A, S]`` or broadcastable to ``noise``.
        noise: the standard-normal matrix ``ξ``, ``[*, A, S]``.

    Returns:
        ``Θ̂``, the broadcast shape of both.

    Examples:
        >>> noise_matrix(torch.full((2, 1), 0.5), torch.ones(4, 2, 3)).shape
        torch.Size([4, 2, 3])
    """
    return sigma_hat * noise


def explore(loc: torch.Tensor, exploration: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
    """The SDE action for a given exploration matrix: ``u = loc + Θ̂ x`` (eq. 17).

    :func:`sde_sample` computes ``Θ̂ = σ̂ ⊙ ξ`` first; a caller that knows ``Θ̂`` for every step
    of an episode before it starts (the fast collection paths) forms it once and calls this.

    Args:
        loc: the controller's mean ``f(x; θ)``, ``[*, A]``.
        exploration: ``Θ̂``, ``[*, A, S]``.
        features: ``x``, ``[*, S]``.

    Returns:
        ``u``, ``[*, A]``.

    Examples:
        >>> explore(torch.zeros(2), torch.full((2, 3), 0.1), torch.ones(3))
        tensor([0.3000, 0.3000])
    """
    return loc + (exploration @ features.unsqueeze(-1)).squeeze(-1)


def sde_sample(
    loc: torch.Tensor,
    sigma_hat: torch.Tensor,
    noise: torch.Tensor,
    features: torch.Tensor,
    gaussian_scale: torch.Tensor | None = None,
    gaussian_noise: torch.Tensor | None = None,
) -> torch.Tensor:
    """The SDE action ``u = loc + Θ̂ x [+ σ_gauss ε]`` with ``Θ̂ = σ̂ ⊙ ξ`` (eqs. 17-19, 22).

    Differentiable in ``loc``, ``σ̂`` and ``σ_gauss`` (the reparameterisation); the draws ``ξ``
    and ``ε`` are the caller's.

    Args:
        loc: the controller's mean ``f(x; θ)``, ``[*, A]``.
        sigma_hat: ``σ̂``, broadcastable to ``noise``.
        noise: ``ξ``, ``[*, A, S]``.
        features: ``x``, ``[*, S]``.
        gaussian_scale: ``σ_gauss`` of eq. (22), broadcastable to ``[*, A]``, or ``None``.
        gaussian_noise: the standard-normal ``ε``, ``[*, A]``; needed with ``gaussian_scale``.

    Returns:
        ``u``, ``[*, A]`` (before any squashing).

    Examples:
        >>> sde_sample(torch.zeros(2), torch.full((2, 3), 0.1), torch.ones(2, 3), torch.ones(3))
        tensor([0.3000, 0.3000])
    """
    sample = explore(loc, noise_matrix(sigma_hat, noise), features)
    if gaussian_scale is not None:
        sample = sample + gaussian_scale * gaussian_noise
    return sample


def sde_sample_and_log_prob(
    loc: torch.Tensor,
    sigma_hat: torch.Tensor,
    features: torch.Tensor,
    noise: torch.Tensor,
    gaussian_scale: torch.Tensor | None = None,
    gaussian_noise: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """One exploring step's action and its log-density, without building a distribution: the
    sample ``u = loc + (σ̂ ⊙ ξ) x [+ σ_gauss ε]`` (eqs. 17-19, 22) and ``log N(u; loc, σ²)`` with
    ``σ² = Σ_i (x_i σ̂_ji)² [+ σ_gauss²]`` (eqs. 13, 20): the numbers
    ``SDENormal(...).rsample()`` and its ``log_prob`` give, bit for bit, which is all a collection
    step writes.

    Args:
        loc: the controller's mean, ``[*, A]``.
        sigma_hat: ``σ̂``, ``[*, A, S]`` or broadcastable.
        features: ``x``, ``[*, S]`` (cast to ``loc``'s dtype).
        noise: the carried ``ξ``, ``[*, A, S]``.
        gaussian_scale: ``σ_gauss`` of eq. (22), or ``None``.
        gaussian_noise: the carried ``ε`` of eq. (22), with ``gaussian_scale``.

    Returns:
        ``(u, log p(u))``, shapes ``[*, A]`` and ``[*]``.

    Raises:
        ValueError: if ``sigma_hat`` or ``noise`` is not ``[..., A, S]``.

    Examples:
        >>> loc, x, sigma = torch.zeros(4, 2), torch.ones(4, 3), torch.full((2, 3), 0.1)
        >>> sample, log_prob = sde_sample_and_log_prob(loc, sigma, x, torch.ones(4, 2, 3))
        >>> dist = SDENormal(loc, sigma, x, noise=torch.ones(4, 2, 3))
        >>> torch.equal(sample, dist.rsample()), torch.equal(log_prob, dist.log_prob(sample))
        (True, True)
    """
    sample, scale = _sample_and_scale(loc, sigma_hat, features, noise, gaussian_scale, gaussian_noise)
    return sample, gaussian_log_prob(sample, loc, scale)


def tanh_sde_sample_and_log_prob(
    loc: torch.Tensor,
    sigma_hat: torch.Tensor,
    features: torch.Tensor,
    noise: torch.Tensor,
    bounds: tuple[torch.Tensor, torch.Tensor],
    gaussian_scale: torch.Tensor | None = None,
    gaussian_noise: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One exploring step of the squashed policy without building a distribution: the pre-squash
    sample ``u`` (eqs. 17-19, 22), the action ``a = mid + half · tanh(u)`` and ``log p(a)``
    through the clamped inverse of the squash (eq. 20 and the change of variables): the numbers
    :class:`TanhSDENormal`'s ``SDENormal.rsample``, ``squash`` and ``log_prob`` give, bit for bit.

    Args:
        loc, sigma_hat, features, noise, gaussian_scale, gaussian_noise: as
            :func:`sde_sample_and_log_prob` takes them.
        bounds: ``(mid, half)`` of the action bounds (:func:`tanh_bounds`), in ``loc``'s dtype.

    Returns:
        ``(u, a, log p(a))``, shapes ``[*, A]``, ``[*, A]`` and ``[*]``.

    Examples:
        >>> loc, x, sigma, xi = torch.zeros(4, 2), torch.ones(4, 3), torch.full((2, 3), 0.4), torch.randn(4, 2, 3)
        >>> u, a, log_prob = tanh_sde_sample_and_log_prob(loc, sigma, x, xi, tanh_bounds(-2.0, 2.0, loc.dtype))
        >>> dist = TanhSDENormal(loc, sigma, x, noise=xi, low=-2.0, high=2.0)
        >>> [torch.equal(*pair) for pair in ((u, SDENormal.rsample(dist)), (a, dist.squash(u)),
        ...                                   (log_prob, dist.log_prob(a)))]
        [True, True, True]
    """
    mid, half = bounds
    sample, scale = _sample_and_scale(loc, sigma_hat, features, noise, gaussian_scale, gaussian_noise)
    action = squash(sample, mid, half)
    pre_squash = unsquash(action, mid, half)
    return sample, action, gaussian_log_prob(pre_squash, loc, scale) - tanh_log_det(pre_squash, half)


def _sample_and_scale(
    loc: torch.Tensor, sigma_hat: torch.Tensor, features: torch.Tensor, noise: torch.Tensor,
    gaussian_scale: torch.Tensor | None, gaussian_noise: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The SDE sample with the carried noise and the per-action standard deviation (eq. 20), as
    :class:`SDENormal` computes them."""
    features = features.to(loc.dtype)
    action_dim, feature_dim = loc.shape[-1], features.shape[-1]
    _check_matrix("sigma_hat", sigma_hat, action_dim, feature_dim)
    _check_matrix("noise", noise, action_dim, feature_dim)
    sigma_hat, noise = sigma_hat.to(loc.dtype), noise.to(loc.dtype)
    scale = sde_variance(sigma_hat, features, gaussian_scale).sqrt()
    return sde_sample(loc, sigma_hat, noise, features, gaussian_scale, gaussian_noise), scale


def tanh_bounds(low: torch.Tensor | float, high: torch.Tensor | float,
                dtype: torch.dtype | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(mid, half) = ((high + low) / 2, (high - low) / 2)``: the squash ``mid + half · tanh(u)``
    maps the real line onto ``(low, high)``.

    Examples:
        >>> tanh_bounds(-1.0, 3.0)
        (tensor(1.), tensor(2.))
    """
    low, high = torch.as_tensor(low, dtype=dtype), torch.as_tensor(high, dtype=dtype)
    return (high + low) / 2, (high - low) / 2


def squash(pre_squash: torch.Tensor, mid: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """``mid + half · tanh(u)``.

    Examples:
        >>> squash(torch.tensor([0.0, 100.0]), *tanh_bounds(-1.0, 3.0))
        tensor([1., 3.])
    """
    return mid + half * torch.tanh(pre_squash)


def unsquash(action: torch.Tensor, mid: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """``atanh((a - mid) / half)``, the inverse of :func:`squash`, clamped to
    ``|tanh u| <= 1 - eps(dtype)`` (``|u| <= 8.3`` in float32).

    Examples:
        >>> unsquash(torch.tensor([1.0, 3.0]), *tanh_bounds(-1.0, 3.0))
        tensor([0.0000, 8.3178])
    """
    unit = (action - mid) / half
    max_abs_tanh = 1.0 - torch.finfo(unit.dtype).eps
    return torch.atanh(unit.clamp(-max_abs_tanh, max_abs_tanh))


def tanh_log_det(pre_squash: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """``Σ_j log |da_j / du_j| = Σ_j log(half_j (1 - tanh² u_j))``, in the stable form
    ``log(1 - tanh² u) = 2 (log 2 - u - softplus(-2u))``.

    Examples:
        >>> tanh_log_det(torch.zeros(2), torch.ones(2))  # the squash's slope at 0 is 1
        tensor(0.)
    """
    log_one_minus_tanh_sq = 2 * (_LOG_2 - pre_squash - F.softplus(-2 * pre_squash))
    return (half.log() + log_one_minus_tanh_sq).sum(-1)


def sde_variance(
    sigma_hat: torch.Tensor,
    features: torch.Tensor,
    gaussian_scale: torch.Tensor | None = None,
    run_dims: int | None = None,
) -> torch.Tensor:
    """Per-action variance of the SDE action: ``σ_j² = Σ_i (x_i σ̂_ji)² [+ σ_gauss_j²]`` (eqs. 20, 22).

    Args:
        sigma_hat: ``σ̂``, ``[*, A, S]`` (or broadcastable to it); with ``run_dims``, one matrix
            per run, ``[*runs, A, S]``, shared by all of that run's rows.
        features: ``x``, ``[*, S]`` (runs first with ``run_dims``).
        gaussian_scale: standard deviation of eq. (22)'s i.i.d. Gaussian part, broadcastable to
            ``[*, A]``, or ``None`` for pure SDE.
        run_dims: ``None`` for broadcasting; else the number of leading run dimensions of
            ``sigma_hat`` (0 or 1), computed as one matrix product per run
            (:func:`~sde_torchrl.utils.shapes.stacked_matvec`) over whole episodes.

    Returns:
        ``σ²`` of shape ``[*, A]``, floored at :data:`MIN_VARIANCE` (at ``x = 0`` SDE adds no
        noise and the likelihood would be infinite).

    Examples:
        >>> sde_variance(torch.full((2, 3), 0.5), torch.tensor([1.0, 2.0, 0.0]))
        tensor([1.2500, 1.2500])
        >>> sde_variance(torch.full((4, 2, 3), 0.5), torch.ones(4, 10, 3), run_dims=1).shape
        torch.Size([4, 10, 2])
    """
    if run_dims is None:  # one contraction over S, without squaring a σ̂ expanded to the batch
        variance = torch.einsum("...as,...s->...a", compact_broadcast(sigma_hat, 2).square(), features.square())
    else:
        variance = stacked_matvec(sigma_hat.square(), features.square(), run_dims)
    if gaussian_scale is not None:
        variance = variance + gaussian_scale.square()
    return variance.clamp_min(MIN_VARIANCE)


class SDENormal(Distribution):
    """The action distribution of state-dependent exploration, one step at a time (eqs. 17-22).

    The action is ``u = loc + Θ̂ x [+ σ_gauss ε]`` with ``Θ̂ = σ̂ ⊙ ξ``, ``ξ ~ N(0, I)`` (eqs.
    17-19, 22). Given the state, ``u_j ~ N(loc_j, σ_j²)`` with ``σ_j² = Σ_i (x_i σ̂_ji)² +
    σ_gauss_j²`` (eq. 20): that per-step Gaussian is what :meth:`log_prob` scores (summed over the
    action dimension, TorchRL's ``IndependentNormal`` convention) and what :meth:`entropy`
    measures.

    Sampling: :meth:`rsample` with an empty ``sample_shape`` uses the carried ``noise`` ``ξ``
    (the matrix held for the episode, or for ``n`` steps) and the carried ``gaussian_noise``
    ``ε``, so it returns the very action the policy took; it is reparameterised in ``loc`` and
    ``σ̂`` (and ``gaussian_scale``). With a non-empty ``sample_shape``, or where they are not
    given, fresh ``ξ`` and ``ε`` are drawn (:func:`~sde_torchrl.modules.noise.draw_noise`):
    independent samples of the same per-step Gaussian.
    ``mean``, ``mode`` and ``deterministic_sample`` are ``loc``.

    Args:
        loc: the controller's mean ``f(x; θ)``, ``[*, A]``.
        sigma_hat: ``σ̂``, ``[*, A, S]`` or broadcastable (``[A, S]``, ``[*, A, 1]``, ...).
        features: the exploration features ``x``, ``[*, S]`` (cast to ``loc``'s dtype).
        noise: the carried standard-normal matrix ``ξ``, ``[*, A, S]``, or ``None``.
        gaussian_scale: ``σ_gauss`` of eq. (22), ``[*, A]`` (or broadcastable), or ``None``.
        gaussian_noise: the carried standard-normal ``ε`` of eq. (22), ``[*, A]``, or ``None``.
        validate_args: passed to :class:`torch.distributions.Distribution`.

    Raises:
        ValueError: if the shapes do not fit ``[*, A]``, ``[*, A, S]``, ``[*, S]``.

    Examples:
        >>> loc, x = torch.zeros(4, 2), torch.ones(4, 3)
        >>> dist = SDENormal(loc, torch.full((2, 3), 0.1), x, noise=torch.ones(4, 2, 3))
        >>> dist.rsample()  # loc + (σ̂ ⊙ ξ) x = 0.1 * 3
        tensor([[0.3000, 0.3000],
                [0.3000, 0.3000],
                [0.3000, 0.3000],
                [0.3000, 0.3000]])
        >>> dist.log_prob(loc).shape, dist.batch_shape, dist.event_shape
        (torch.Size([4]), torch.Size([4]), torch.Size([2]))
    """

    arg_constraints: dict = {}
    support = constraints.real_vector
    has_rsample = True

    def __init__(
        self,
        loc: torch.Tensor,
        sigma_hat: torch.Tensor,
        features: torch.Tensor,
        noise: torch.Tensor | None = None,
        gaussian_scale: torch.Tensor | None = None,
        gaussian_noise: torch.Tensor | None = None,
        validate_args: bool | None = False,
    ) -> None:
        features = features.to(loc.dtype)
        action_dim, feature_dim = loc.shape[-1], features.shape[-1]
        _check_matrix("sigma_hat", sigma_hat, action_dim, feature_dim)
        if noise is not None:
            _check_matrix("noise", noise, action_dim, feature_dim)
        self.loc, self.sigma_hat, self.features = loc, sigma_hat.to(loc.dtype), features
        self.noise = None if noise is None else noise.to(loc.dtype)
        self.gaussian_scale, self.gaussian_noise = gaussian_scale, gaussian_noise
        shapes = [loc.shape[:-1], features.shape[:-1], sigma_hat.shape[:-2]]
        if gaussian_scale is not None:
            shapes.append(gaussian_scale.shape[:-1])
        if noise is not None:
            shapes.append(noise.shape[:-2])
        try:
            batch_shape = torch.broadcast_shapes(*shapes)
        except RuntimeError as err:
            raise ValueError(
                f"batch shapes do not broadcast: loc {tuple(loc.shape)}, sigma_hat {tuple(sigma_hat.shape)}, "
                f"features {tuple(features.shape)}, noise {None if noise is None else tuple(noise.shape)}, "
                f"gaussian_scale {None if gaussian_scale is None else tuple(gaussian_scale.shape)}"
            ) from err
        self.scale = sde_variance(self.sigma_hat, features, gaussian_scale).sqrt()
        self.action_dim, self.feature_dim = action_dim, feature_dim
        super().__init__(batch_shape, torch.Size([action_dim]), validate_args=validate_args)

    @property
    def mean(self) -> torch.Tensor:
        """``loc``: SDE noise has zero mean."""
        return self.loc.expand(self._extended_shape())

    @property
    def mode(self) -> torch.Tensor:
        """``loc``."""
        return self.mean

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """``loc``: what TorchRL acts with under ``ExplorationType.DETERMINISTIC``."""
        return self.mean

    @property
    def stddev(self) -> torch.Tensor:
        """``σ_j = sqrt(Σ_i (x_i σ̂_ji)² [+ σ_gauss_j²])`` (eq. 20)."""
        return self.scale.expand(self._extended_shape())

    @property
    def variance(self) -> torch.Tensor:
        """``σ_j²`` (eq. 20)."""
        return self.stddev.square()

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        """``loc + (σ̂ ⊙ ξ) x [+ σ_gauss ε]`` (eqs. 17-19, 22), differentiable in the parameters.

        Args:
            sample_shape: leading sample dimensions; empty uses the carried ``noise`` (if any).

        Returns:
            A sample of shape ``sample_shape + batch_shape + [A]``.
        """
        sample_shape = torch.Size(sample_shape)
        like = {"dtype": self.loc.dtype, "device": self.loc.device}
        noise, gaussian_noise = self.noise, self.gaussian_noise
        if noise is None or len(sample_shape) > 0:
            noise = draw_noise(sample_shape + self.batch_shape + (self.action_dim, self.feature_dim), **like)
        if self.gaussian_scale is not None and (gaussian_noise is None or len(sample_shape) > 0):
            gaussian_noise = draw_noise(self._extended_shape(sample_shape), **like)
        sample = sde_sample(self.loc, self.sigma_hat, noise, self.features, self.gaussian_scale, gaussian_noise)
        return sample.expand(self._extended_shape(sample_shape))

    def sample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        """:meth:`rsample` without gradients."""
        with torch.no_grad():
            return self.rsample(sample_shape)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        """``Σ_j log N(value_j; loc_j, σ_j²)`` (eqs. 13, 20): needs no noise, only stored entries.

        Autograd of this through ``loc`` and ``σ̂`` gives the paper's scores (14), (16), (21).

        Args:
            value: an action ``[*sample, *batch, A]``.

        Returns:
            The log-density, shape ``[*sample, *batch]``.
        """
        return gaussian_log_prob(value, self.loc, self.scale)

    def entropy(self) -> torch.Tensor:
        """Entropy of the per-step Gaussian, ``Σ_j (½ log(2πe) + log σ_j)``, shape ``batch_shape``."""
        return (_HALF_LOG_2PI_E + self.scale.log()).sum(-1).expand(self.batch_shape)


class TanhSDENormal(SDENormal):
    """:class:`SDENormal` squashed into ``[low, high]``: ``a = mid + half · tanh(u)``.

    ``mid = (high + low) / 2``, ``half = (high - low) / 2``. The density is the change of
    variables of the pre-squash Gaussian (eq. 20):
    ``log p(a) = log N(u; loc, σ²) - Σ_j log(half_j (1 - tanh² u_j))`` with
    ``u = atanh((a - mid) / half)``; the log-determinant is evaluated in the stable form
    ``log(1 - tanh² u) = 2 (log 2 - u - softplus(-2u))``.

    :meth:`rsample_and_log_prob` (what TorchRL's SAC calls) scores the exact pre-squash sample.
    :meth:`log_prob` of a stored action inverts the squash; the inverse is clamped to
    ``|tanh u| <= 1 - eps(dtype)`` (``|u| <= 8.3`` in float32, 18.7 in float64): beyond that the
    stored action has lost the digits that would tell ``u`` apart, and the score is that of
    ``u`` at the clamp. The collection-time log-prob uses the same inverse, so PPO's ratio
    stays exactly 1 on unchanged parameters either way. ``mean`` and ``entropy`` have no closed
    form (TorchRL's losses estimate the entropy by sampling); ``mode`` and
    ``deterministic_sample`` are ``mid + half · tanh(loc)``.

    Args:
        loc: pre-squash mean, ``[*, A]``.
        sigma_hat: ``σ̂``, ``[*, A, S]`` or broadcastable.
        features: ``x``, ``[*, S]``.
        noise: the carried ``ξ`` ``[*, A, S]``, or ``None``.
        gaussian_scale: ``σ_gauss`` of eq. (22), or ``None``.
        gaussian_noise: the carried ``ε`` of eq. (22), or ``None``.
        low: lower action bound(s), a number or a tensor broadcastable to ``[A]``.
        high: upper action bound(s), strictly above ``low``.
        validate_args: passed to :class:`torch.distributions.Distribution`.

    Raises:
        ValueError: if ``high <= low`` anywhere.

    Examples:
        >>> dist = TanhSDENormal(torch.zeros(3, 1), torch.full((1, 2), 0.5), torch.ones(3, 2),
        ...                      low=-2.0, high=2.0)
        >>> action = dist.sample()
        >>> bool(((action > -2) & (action < 2)).all())
        True
        >>> dist.deterministic_sample
        tensor([[0.],
                [0.],
                [0.]])
    """

    support = constraints.real_vector  # the interval [low, high] per action; args are not validated
    entropy = Distribution.entropy  # no closed form: TorchRL's losses fall back to sampling

    def __init__(
        self,
        loc: torch.Tensor,
        sigma_hat: torch.Tensor,
        features: torch.Tensor,
        noise: torch.Tensor | None = None,
        gaussian_scale: torch.Tensor | None = None,
        gaussian_noise: torch.Tensor | None = None,
        low: torch.Tensor | float = -1.0,
        high: torch.Tensor | float = 1.0,
        validate_args: bool | None = False,
    ) -> None:
        super().__init__(loc, sigma_hat, features, noise, gaussian_scale, gaussian_noise, validate_args=validate_args)
        low, high = torch.as_tensor(low, dtype=loc.dtype), torch.as_tensor(high, dtype=loc.dtype)
        # checked where the bounds were given (the policy's CPU bounds: no device sync), then moved
        checkable = not torch.compiler.is_compiling() and "meta" not in (low.device.type, high.device.type)
        if checkable and bool((high <= low).any()):
            raise ValueError(f"TanhSDENormal needs high > low everywhere, got low={low}, high={high}")
        low, high = low.to(loc.device), high.to(loc.device)
        self.low, self.high = low, high
        self._mid, self._half = tanh_bounds(low, high)

    def squash(self, pre_squash: torch.Tensor) -> torch.Tensor:
        """``mid + half · tanh(u)`` (:func:`squash`)."""
        return squash(pre_squash, self._mid, self._half)

    def unsquash(self, action: torch.Tensor) -> torch.Tensor:
        """``atanh((a - mid) / half)``, clamped to ``|tanh u| <= 1 - eps`` (:func:`unsquash`)."""
        return unsquash(action, self._mid, self._half)

    def _pre_squash_log_prob(self, pre_squash: torch.Tensor) -> torch.Tensor:
        return super().log_prob(pre_squash) - tanh_log_det(pre_squash, self._half)

    @property
    def mean(self) -> torch.Tensor:
        raise NotImplementedError("the mean of a tanh-squashed Gaussian has no closed form")

    @property
    def mode(self) -> torch.Tensor:
        """``mid + half · tanh(loc)``."""
        return self.squash(self.loc).expand(self._extended_shape())

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """``mid + half · tanh(loc)``: the squashed controller output."""
        return self.mode

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        """The squashed :meth:`SDENormal.rsample`."""
        return self.squash(super().rsample(sample_shape))

    def rsample_and_log_prob(
        self, sample_shape: torch.Size | tuple[int, ...] = ()
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action and the log-density of its exact pre-squash sample.

        Args:
            sample_shape: leading sample dimensions (empty: the carried noise).

        Returns:
            ``(action, log_prob)``.
        """
        pre_squash = SDENormal.rsample(self, sample_shape)
        return self.squash(pre_squash), self._pre_squash_log_prob(pre_squash)

    def sample_and_log_prob(
        self, sample_shape: torch.Size | tuple[int, ...] = ()
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Like :meth:`rsample_and_log_prob` with the action detached (score-function gradients)."""
        with torch.no_grad():
            pre_squash = SDENormal.rsample(self, sample_shape)
        return self.squash(pre_squash), self._pre_squash_log_prob(pre_squash)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        """Log-density of a squashed action (change of variables through the clamped inverse)."""
        return self._pre_squash_log_prob(self.unsquash(value))


def _check_matrix(name: str, matrix: torch.Tensor, action_dim: int, feature_dim: int) -> None:
    if matrix.dim() < 2 or matrix.shape[-2] not in (1, action_dim) or matrix.shape[-1] not in (1, feature_dim):
        raise ValueError(
            f"{name} has shape {tuple(matrix.shape)}; expected [..., A, S] = [..., {action_dim}, "
            f"{feature_dim}] (A from loc, S from features), or 1 where shared"
        )
