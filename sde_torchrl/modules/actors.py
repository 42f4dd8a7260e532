"""Deterministic controllers ``μ = f(x; θ)`` (paper eqs. 12, 17) as TorchRL actor modules.

Every controller can hold ``runs`` independent copies of its parameters along a leading
dimension, so that independent learners are evaluated in one batched call on inputs shaped
``[runs, ...]``. Gradients with respect to all parameters come from autograd (eq. 14).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn

from sde_torchrl.utils.checks import one_of, positive_int
from sde_torchrl.utils.options import ACTIVATIONS
from sde_torchrl.utils.rng import RunStreams, draw_uniform
from sde_torchrl.utils.shapes import align, stacked_matvec

#: The activation functions by name (:data:`~sde_torchrl.utils.options.ACTIVATIONS`).
ACTIVATION_FUNCTIONS = {name: getattr(torch, name) for name in ACTIVATIONS}

#: An initialisation: a constant, or ``[low, high)`` for a uniform draw.
Init = float | Sequence[float] | None


class BatchedLinear(nn.Module):
    """``y = W x (+ b)`` with optionally stacked run copies of ``W`` and ``b``.

    Args:
        in_features: size of ``x``.
        out_features: size of ``y``.
        bias: whether to learn ``b``.
        runs: number of stacked independent copies, or ``None`` for one.
        init: a constant for every entry, ``[low, high)`` for uniform draws, or ``None`` for
            ``U(-1/sqrt(in), 1/sqrt(in))``.

    Examples:
        >>> layer = BatchedLinear(3, 2, runs=4, init=-2.0)
        >>> layer(torch.ones(4, 10, 3)).shape
        torch.Size([4, 10, 2])
    """

    def __init__(
        self, in_features: int, out_features: int, *, bias: bool = True,
        runs: int | None = None, init: Init = None,
    ) -> None:
        super().__init__()
        positive_int("in_features", in_features)
        positive_int("out_features", out_features)
        self.in_features, self.out_features, self.runs = in_features, out_features, runs
        self.run_dims = 0 if runs is None else 1
        self.init = init
        run_shape = () if runs is None else (runs,)
        self.weight = nn.Parameter(torch.empty(*run_shape, out_features, in_features))
        self.bias = nn.Parameter(torch.empty(*run_shape, out_features)) if bias else None
        self.reset_parameters()

    def reset_parameters(self, streams: RunStreams | None = None) -> None:
        """Draws the parameters from ``init``, from per-run ``streams`` if given."""
        bound = 1 / math.sqrt(self.in_features)
        low_high = (-bound, bound) if self.init is None else self.init
        with torch.no_grad():
            for param in (self.weight, self.bias):
                if param is not None:
                    param.copy_(_initial_values(param.shape, low_high, streams))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != self.in_features:
            raise ValueError(f"input has {x.shape[-1]} features, expected {self.in_features}")
        if self.runs is None and x.dim() >= 2:  # the product stacked_matvec forms, without its reshapes
            y = x @ self.weight.T
            return y if self.bias is None else y + self.bias
        y = stacked_matvec(self.weight, x, self.run_dims)
        if self.bias is not None:
            y = y + align(self.bias, self.run_dims, x.dim() - 1)
        return y


def _initial_values(
    shape: torch.Size, init: float | Sequence[float], streams: RunStreams | None
) -> torch.Tensor:
    if isinstance(init, (int, float)):
        return torch.full(shape, float(init))
    low, high = (float(v) for v in init)
    if not low < high:
        raise ValueError(f"uniform init needs low < high, got [{low}, {high})")
    return low + (high - low) * draw_uniform(shape, streams)


class MLP(nn.Module):
    """Multilayer perceptron of :class:`BatchedLinear` layers; linear output layer.

    Args:
        in_features: input size.
        out_features: output size.
        hidden: sizes of the hidden layers.
        activation: ``"sigmoid"``, ``"tanh"`` or ``"relu"`` for the hidden layers.
        bias: bias units into every layer.
        runs: number of stacked independent copies, or ``None``.
        init: see :class:`BatchedLinear`.
    """

    def __init__(
        self, in_features: int, out_features: int, hidden: Sequence[int] = (3,), *,
        activation: str = "sigmoid", bias: bool = True, runs: int | None = None, init: Init = None,
    ) -> None:
        super().__init__()
        self.activation = ACTIVATION_FUNCTIONS[one_of("activation", activation, ACTIVATIONS)]
        sizes = [in_features, *hidden, out_features]
        self.layers = nn.ModuleList(
            BatchedLinear(n_in, n_out, bias=bias, runs=runs, init=init)
            for n_in, n_out in zip(sizes[:-1], sizes[1:], strict=True)
        )

    def reset_parameters(self, streams: RunStreams | None = None) -> None:
        """Redraws every layer's parameters (see :meth:`BatchedLinear.reset_parameters`)."""
        for layer in self.layers:
            layer.reset_parameters(streams)

    def hidden_and_output(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The last hidden layer's activations (``x`` itself without hidden layers) and the output."""
        *hidden, output = self.layers  # unpacked, not sliced: a slice builds a new ModuleList per call
        for layer in hidden:
            x = self.activation(layer(x))
        return x, output(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.hidden_and_output(x)[1]


class LinearActor(TensorDictModule):
    """Linear controller ``loc = Θ x (+ b)`` reading ``observation`` and writing ``loc``.

    Args:
        in_features: observation size ``S``.
        out_features: action size ``A``.
        bias: learn a bias (the paper's linear controllers have none).
        runs: number of independent runs stacked along a leading dimension, or ``None``.
        init: initial ``Θ``: constant (the paper's 1-D task starts at -2) or ``[low, high)``.
        in_key: observation key.

    Examples:
        >>> from tensordict import TensorDict
        >>> actor = LinearActor(1, 1, bias=False, init=-2.0)
        >>> actor(TensorDict({"observation": torch.ones(4, 1)}, [4]))["loc"].squeeze(-1)
        tensor([-2., -2., -2., -2.], grad_fn=<SqueezeBackward1>)
    """

    def __init__(
        self, in_features: int, out_features: int, *, bias: bool = False,
        runs: int | None = None, init: Init = None, in_key: str = "observation",
    ) -> None:
        net = BatchedLinear(in_features, out_features, bias=bias, runs=runs, init=init)
        super().__init__(net, in_keys=[in_key], out_keys=["loc"])


class MLPActor(TensorDictModule):
    """MLP controller reading ``observation`` and writing ``loc``.

    Args:
        in_features: observation size.
        out_features: action size.
        hidden: hidden layer sizes (the paper's 2-D task uses one layer of 3).
        activation: hidden activation (``"sigmoid"`` in the paper).
        bias: bias units into hidden and output layers.
        runs: number of stacked independent runs, or ``None``.
        init: initial parameters: constant, ``[low, high)`` (the paper: ``[-1, 0)``), or
            ``None`` for ``U(±1/sqrt(fan_in))``.
        in_key: observation key.

    Examples:
        >>> from tensordict import TensorDict
        >>> actor = MLPActor(2, 2, hidden=[3], init=[-1.0, 0.0])
        >>> sum(p.numel() for p in actor.parameters())
        17
    """

    def __init__(
        self, in_features: int, out_features: int, hidden: Sequence[int] = (3,), *,
        activation: str = "sigmoid", bias: bool = True, runs: int | None = None,
        init: Init = None, in_key: str = "observation",
    ) -> None:
        net = MLP(in_features, out_features, list(hidden), activation=activation, bias=bias,
                  runs=runs, init=init)
        super().__init__(net, in_keys=[in_key], out_keys=["loc"])


class LatentMLPActor(TensorDictModuleBase):
    """MLP controller that also writes its last hidden layer, as exploration features for SDE.

    Writes ``loc = f(x; θ)`` (eq. 17) and the last hidden layer's activations ``h`` under
    ``feature_key``: with ``SDEParams(feature_key=...)`` the exploration ``Θ̂ h`` (eqs. 18-20)
    sees ``h`` instead of the raw state, the latent features of gSDE (Raffin et al., 2021).
    ``h`` is detached unless ``learn_features`` (gSDE's ``learn_features=False`` default), so
    the SDE likelihood then trains only ``σ̂`` and the mean. One module writing both keys:
    cheaper per call than a chain of ``TensorDictModule`` objects.

    Args:
        in_features: observation size.
        out_features: action size ``A``.
        hidden: hidden layer sizes; the last one is the feature size ``S`` (none: ``h`` is the
            observation).
        activation: hidden activation.
        learn_features: let the SDE likelihood's gradient reach the hidden layers through ``h``.
        runs: number of stacked independent runs, or ``None``.
        init: see :class:`BatchedLinear` (``None``: ``U(±1/sqrt(fan_in))``, ``torch.nn.Linear``'s
            distribution).
        in_key: observation key.
        loc_key: where the mean is written.
        feature_key: where ``h`` is written.
        clip_loc: clip the mean to ``[-clip_loc, clip_loc]`` (``hardtanh``, SB3's SAC with gSDE
            clips it at 2); ``None``: not clipped.

    Examples:
        >>> from tensordict import TensorDict
        >>> actor = LatentMLPActor(3, 2, hidden=[8, 4], activation="relu")
        >>> td = actor(TensorDict({"observation": torch.randn(5, 3)}, [5]))
        >>> td["loc"].shape, td["sde_features"].shape, td["sde_features"].requires_grad
        (torch.Size([5, 2]), torch.Size([5, 4]), False)
        >>> clipped = LatentMLPActor(3, 2, hidden=[8], clip_loc=0.125)
        >>> float(clipped(TensorDict({"observation": torch.randn(5, 3)}, [5]))["loc"].abs().max()) == 0.125
        True
    """

    def __init__(
        self, in_features: int, out_features: int, hidden: Sequence[int] = (64, 64), *,
        activation: str = "tanh", learn_features: bool = False, runs: int | None = None,
        init: Init = None, in_key: NestedKey = "observation", loc_key: NestedKey = "loc",
        feature_key: NestedKey = "sde_features", clip_loc: float | None = None,
    ) -> None:
        super().__init__()
        self.net = MLP(in_features, out_features, list(hidden), activation=activation, runs=runs, init=init)
        self.learn_features, self.clip_loc = learn_features, clip_loc
        self.feature_dim = hidden[-1] if len(hidden) else in_features
        self.in_keys, self.out_keys = [in_key], [loc_key, feature_key]

    def loc_and_features(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The mean and the exploration features of ``observation``: what :meth:`forward` writes."""
        features, loc = self.net.hidden_and_output(observation)
        if self.clip_loc is not None:
            loc = torch.nn.functional.hardtanh(loc, -self.clip_loc, self.clip_loc)
        return loc, features if self.learn_features else features.detach()

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc, features = self.loc_and_features(tensordict.get(self.in_keys[0]))
        loc_key, feature_key = self.out_keys
        tensordict.set(loc_key, loc)
        tensordict.set(feature_key, features)
        return tensordict
