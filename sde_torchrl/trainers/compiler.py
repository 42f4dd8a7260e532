"""Compiling the updates' losses (``algorithm.compile``): :func:`compiled`, ``torch.compile``
without tensordict's deprecation noise, and a backend for small networks' losses on the CPU,
inductor with its min-cut partitioner told (through AOTAutograd's private settings,
``torch._functorch.config``) to recompute boolean masks in the backward rather than save them;
the compiled SAC update (:class:`~sde_torchrl.trainers.sac.SACUpdate`) uses it."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import torch

#: tensordict 0.14 reads ``torch._dynamo.config.inline_inbuilt_nn_modules`` whenever a compiled
#: graph swaps parameters into a module (``to_module``, as TorchRL's functional losses do), and
#: torch 2.13 answers each read with this deprecation warning, which nobody using either can act on.
TENSORDICT_DYNAMO_WARNING = r"torch\._dynamo\.config\.inline_inbuilt_nn_modules is deprecated"


def compiled(function: Callable[..., Any], **options: Any) -> Callable[..., Any]:
    """``torch.compile(function, **options)``, with tensordict's deprecation warning about
    :data:`TENSORDICT_DYNAMO_WARNING` ignored from now on (that warning alone, in this process).

    Examples:
        >>> double = compiled(lambda x: 2 * x)
        >>> callable(double), hasattr(double, "_torchdynamo_orig_callable")
        (True, True)
    """
    warnings.filterwarnings("ignore", message=TENSORDICT_DYNAMO_WARNING, category=FutureWarning)
    return torch.compile(function, **options)


def inductor_recomputing_boolean_masks(graph, example_inputs):
    """``torch.compile``'s inductor backend, its partition made under :func:`recomputing_boolean_masks`.

    The settings hold while a graph compiles, not at every call of the compiled function.
    """
    from torch._inductor.compile_fx import compile_fx

    with recomputing_boolean_masks():
        return compile_fx(graph, example_inputs)


def recomputing_boolean_masks():
    """AOTAutograd's settings that apply :func:`recompute_boolean_masks` to what compiles within them.

    The pass is not part of AOTAutograd's cache key, so its cache is off: a graph cached by a
    process without the pass is not reused.
    """
    return torch._functorch.config.patch(joint_custom_pass=recompute_boolean_masks, enable_autograd_cache=False)


def recompute_boolean_masks(joint_graph, joint_inputs):
    """AOTAutograd joint-graph pass: the backward recomputes boolean tensors instead of saving them.

    Inductor's min-cut partitioner saves the smallest tensors the backward needs; for ReLU,
    ``hardtanh``, ``clamp`` and ``min`` those are their boolean masks (1 byte each, where the
    float inputs they come from are 4). Inductor's CPU code (torch 2.13) stores a boolean tensor many
    times slower than a float one, and at the zoo's batch of 512 those stores took more of the
    compiled step than its matrix products.
    Marking every boolean node ``MUST_RECOMPUTE`` (the tag of selective activation checkpointing)
    keeps the min-cut partitioner but makes it save the float values and recompute the masks,
    fused into the backward's kernels. The step computes the same values (tested against the
    eager step, compiled by inductor); only what crosses from the forward to the backward changes.

    Args:
        joint_graph: the forward-and-backward FX graph AOTAutograd is about to partition.
        joint_inputs: its example inputs (unused).

    Returns:
        ``joint_graph``, its boolean nodes tagged.

    Examples:
        >>> graph = torch.fx.symbolic_trace(lambda x: x > 0)
        >>> mask = list(graph.graph.nodes)[1]
        >>> mask.meta["val"] = torch.zeros(2, dtype=torch.bool)
        >>> recompute_boolean_masks(graph, None) is graph, mask.meta["recompute"].name
        (True, 'MUST_RECOMPUTE')
    """
    from torch.utils.checkpoint import CheckpointPolicy

    for node in joint_graph.graph.nodes:
        value = node.meta.get("val")
        if node.op == "call_function" and isinstance(value, torch.Tensor) and value.dtype == torch.bool:
            node.meta["recompute"] = CheckpointPolicy.MUST_RECOMPUTE
    return joint_graph
