"""Broadcasting of run-stacked parameters against batched data."""

from __future__ import annotations

import torch


def align(param: torch.Tensor, run_dims: int, batch_dims: int) -> torch.Tensor:
    """Views a parameter so that it broadcasts against data with ``batch_dims`` leading dims.

    Parameters of ``R`` independent runs carry a leading ``[R]`` dimension (``run_dims=1``);
    data carries ``[R, *B]``. Singleton dimensions are inserted after the run dimension so
    that the parameter's core dimensions line up with the data's feature dimensions.

    Args:
        param: tensor of shape ``[*runs, *core]`` with ``len(runs) == run_dims``.
        run_dims: number of leading run dimensions of ``param`` (0 or 1).
        batch_dims: number of batch dimensions of the data, run dimensions included.

    Returns:
        ``param`` viewed as ``[*runs, 1, ..., 1, *core]`` with ``batch_dims`` leading dims.

    Raises:
        ValueError: if the data has fewer batch dimensions than the parameter has run dims.
    """
    _check_run_dims(batch_dims, run_dims)
    shape = param.shape
    return param.reshape(*shape[:run_dims], *([1] * (batch_dims - run_dims)), *shape[run_dims:])


def stacked_matvec(matrix: torch.Tensor, x: torch.Tensor, run_dims: int) -> torch.Tensor:
    """``y[..., a] = Σ_s matrix[a, s] · x[..., s]`` for a (run-stacked) matrix.

    One matrix product per run over all of that run's data rows: a broadcast ``matrix @
    x.unsqueeze(-1)`` would expand the matrix to every row and multiply millions of tiny
    matrices.

    Args:
        matrix: ``[*runs, A, S]`` with ``len(runs) == run_dims``.
        x: ``[*runs, *B, S]``.
        run_dims: number of leading run dimensions of ``matrix`` (0 or 1).

    Returns:
        Tensor of shape ``[*runs, *B, A]``.

    Raises:
        ValueError: if ``x`` has fewer batch dimensions than ``matrix`` has run dims.
    """
    _check_run_dims(x.dim() - 1, run_dims)
    rows = x.reshape(*x.shape[:run_dims], -1, x.shape[-1])
    return (rows @ matrix.transpose(-1, -2)).reshape(*x.shape[:-1], matrix.shape[-2])


def compact_broadcast(tensor: torch.Tensor, core_dims: int) -> torch.Tensor:
    """A view of ``tensor`` with every expanded (stride-0) leading dimension cut to size 1.

    ``SDEParams`` writes one ``σ̂`` expanded to the batch so that a tensordict can hold it;
    squaring that view would materialise one copy per row. The compact view still broadcasts to
    the same shape and carries gradients to the same parameter.

    Args:
        tensor: ``[*lead, *core]``.
        core_dims: number of trailing dimensions to keep whole.

    Returns:
        ``tensor`` indexed to size 1 along each leading dimension of stride 0.

    Examples:
        >>> compact_broadcast(torch.ones(2, 3).expand(5, 2, 3), core_dims=2).shape
        torch.Size([1, 2, 3])
    """
    lead = tensor.dim() - core_dims
    index = tuple(slice(0, 1) if stride == 0 else slice(None) for stride in tensor.stride()[:lead])
    return tensor[index]


def _check_run_dims(batch_dims: int, run_dims: int) -> None:
    if batch_dims < run_dims:
        raise ValueError(
            f"data with {batch_dims} batch dims cannot hold {run_dims} run dims; "
            "stacked runs expect inputs shaped [runs, ..., features]"
        )
