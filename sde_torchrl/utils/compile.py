"""``torch.compile`` for a training step on the CPU: :func:`compile_step`.

Inductor's default min-cut partitioner splits a compiled forward-and-backward so as to save as few
bytes as it can for the backward pass: for a ReLU network it computes each layer's ``output <= 0``
mask in the forward pass and saves it as ``bool``. In PyTorch 2.13's CPU code generation those
boolean stores are scalarised, and for SAC's small networks they dominate the compiled step.
AOTAutograd's *default* partition saves the forward values the backward pass reads instead
(ReLU's output, which the next layer's weight gradient needs anyway) and recomputes nothing:
a little more memory for the saved activations, no boolean stores. ``analysis/bench_sac.py
update-speed --compile`` measures both.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch._functorch.partitioners import default_partition
from torch._inductor.custom_graph_pass import CustomPartitionerFn


class SaveForwardValues(CustomPartitionerFn):
    """Inductor partitioner: AOTAutograd's default partition (saves forward values, recomputes nothing).

    Examples:
        >>> isinstance(SaveForwardValues().uuid(), str)
        True
    """

    def __call__(self, gm: torch.fx.GraphModule, joint_inputs: Sequence[object],
                 **kwargs: Any) -> tuple[torch.fx.GraphModule, torch.fx.GraphModule]:
        kwargs.pop("compiler", None)  # the min-cut partitioner's argument; the default one has none
        return default_partition(gm, joint_inputs, **kwargs)

    def uuid(self) -> str:
        """The key of inductor's cache for graphs partitioned this way."""
        return "sde_torchrl.SaveForwardValues"


def compile_step(step: Callable) -> Callable:
    """``torch.compile(step)`` with the :class:`SaveForwardValues` partitioner.

    The step (losses, ``backward()``, optimiser steps, target updates) compiles at its first
    calls (tens of seconds on the CPU); ``backward()`` breaks the graph, each side compiles.

    Args:
        step: the function to compile.

    Returns:
        The compiled function.

    Examples:
        >>> lin = torch.nn.Linear(3, 1)
        >>> def step(x):
        ...     lin.zero_grad()
        ...     torch.relu(lin(x)).sum().backward()
        >>> compiled = compile_step(step)  # compiles at its first call, as torch.compile
        >>> callable(compiled)
        True
    """
    return torch.compile(step, options={"custom_partitioner_fn": SaveForwardValues()})
