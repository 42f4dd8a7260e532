"""``compile_step``'s partitioner: the same gradients as eager, and no boolean masks saved."""

from __future__ import annotations

import torch
from torch._dynamo.backends.common import aot_autograd
from torch._inductor.decomposition import select_decomp_table

from sde_torchrl.utils.compile import SaveForwardValues


def _relu_net() -> torch.nn.Sequential:
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.ReLU(), torch.nn.Linear(16, 16), torch.nn.ReLU(),
                               torch.nn.Linear(16, 1))


def _saved_dtypes(partition, x: torch.Tensor) -> tuple[list[torch.dtype], list[torch.Tensor]]:
    """Compile a ReLU net's loss as inductor would partition it; the dtypes the forward saves, the grads."""
    net, saved = _relu_net(), []

    def forward_compiler(gm, example_inputs):
        outputs = next(node for node in gm.graph.nodes if node.op == "output").args[0]
        saved.extend(node.meta["val"].dtype for node in outputs[1:] if "val" in node.meta)  # [0]: the loss
        return gm

    backend = aot_autograd(fw_compiler=forward_compiler, bw_compiler=lambda gm, _: gm, partition_fn=partition,
                           decompositions=select_decomp_table())
    torch._dynamo.reset()
    loss = torch.compile(lambda x: net(x).square().mean(), backend=backend)(x)
    loss.backward()
    return saved, [p.grad for p in net.parameters()]


def test_save_forward_values_saves_no_boolean_masks_and_keeps_the_gradients():
    """Inductor's min-cut partition of SAC's step saves 5 boolean masks, this one 1 (the mean's clip,
    ``[B]``): seen in the generated code, too slow to compile here; a ReLU net's graph shows the rule."""
    x = torch.randn(64, 3, generator=torch.Generator().manual_seed(1))
    eager_net = _relu_net()
    eager_net(x).square().mean().backward()
    ours_saved, ours_grads = _saved_dtypes(SaveForwardValues(), x)
    assert ours_saved and torch.bool not in ours_saved  # the ReLU outputs, not their masks
    for grad, eager in zip(ours_grads, (p.grad for p in eager_net.parameters()), strict=True):
        torch.testing.assert_close(grad, eager)
