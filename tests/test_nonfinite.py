"""The one non-finite policy (sde_torchrl.utils.nonfinite): "raise" by default for direct use,
"guarded" inside the trainer, whose guard names the update; set in one place, restored after it."""

from __future__ import annotations

import threading

import pytest
import torch
from _helpers import build

import sde_torchrl
from sde_torchrl.trainers.guard import NonFiniteError
from sde_torchrl.utils.checks import ArgumentError, NonFiniteInputError
from sde_torchrl.utils.nonfinite import check_finite, current_nonfinite_policy, nonfinite_policy

# ------------------------------------------------------------------------------ the default: raise


def test_the_default_is_raise():
    assert current_nonfinite_policy() == "raise"
    assert sde_torchrl.nonfinite_policy is nonfinite_policy  # the public name


def test_check_finite_names_the_tensor_the_entries_and_the_fix():
    value = torch.zeros(2, 3, 4)
    value[1, 2, 0] = float("inf")
    with pytest.raises(NonFiniteInputError, match=r"^my tensor: NaN/inf in run 1 episode 2; do this$"):
        check_finite("my tensor", value, ("run", "episode"), "do this")
    with pytest.raises(NonFiniteInputError, match=r"^my tensor: NaN/inf in the batch; do this$"):
        check_finite("my tensor", value, (), "do this")
    check_finite("integers", torch.arange(3), ("episode",))  # finite by their type
    check_finite("finite", torch.ones(2, 3), ("run", "episode"))


# ------------------------------------------------------------------------------ the context manager


def test_the_policy_is_restored_after_the_block_and_nests():
    with nonfinite_policy("guarded"):
        assert current_nonfinite_policy() == "guarded"
        with nonfinite_policy("raise"):
            assert current_nonfinite_policy() == "raise"
            with pytest.raises(NonFiniteInputError):
                check_finite("x", torch.tensor([float("nan")]))
        assert current_nonfinite_policy() == "guarded"
        check_finite("x", torch.tensor([float("nan")]))
    assert current_nonfinite_policy() == "raise"


def test_the_policy_is_restored_after_an_exception_in_the_block():
    with pytest.raises(KeyError), nonfinite_policy("guarded"):
        raise KeyError("inside")
    assert current_nonfinite_policy() == "raise"
    with nonfinite_policy("guarded"):
        with pytest.raises(RuntimeError), nonfinite_policy("raise"):
            raise RuntimeError("inside")
        assert current_nonfinite_policy() == "guarded"
    assert current_nonfinite_policy() == "raise"


def test_the_policy_is_restored_after_a_trainer_that_failed(tmp_path):
    trainer = build("runs=2", "updates=3", "lr=1e38")
    with pytest.raises(NonFiniteError):
        trainer.train(tmp_path)
    assert current_nonfinite_policy() == "raise"


def test_another_thread_keeps_its_own_policy():
    seen = []
    with nonfinite_policy("guarded"):
        thread = threading.Thread(target=lambda: seen.append(current_nonfinite_policy()))
        thread.start()
        thread.join()
    assert seen == ["raise"]


@pytest.mark.parametrize("policy", ["ignore", "Guarded", "", None, True, 1])
def test_an_unknown_policy_is_refused_before_the_block(policy):
    ran = []
    with pytest.raises(ArgumentError) as info, nonfinite_policy(policy):
        ran.append(1)
    message = str(info.value)
    assert message.startswith("nonfinite_policy=") and "raise" in message and "guarded" in message, message
    assert not ran and current_nonfinite_policy() == "raise"
