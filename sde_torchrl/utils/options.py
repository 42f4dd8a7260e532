"""The allowed values of the string options, written once.

The config schemas (:mod:`sde_torchrl.config.schemas`) and the constructors for direct Python use
check against these same tuples. Standard library only, so that checking a config imports no
torch.
"""

from __future__ import annotations

#: When the SDE noise matrix is redrawn: per episode (SDE), per step (REX), every ``n`` steps.
SCHEDULES = ("episode", "step", "every_n")
#: One ``σ̂`` per matrix element, per action, or one for all (paper section 2.3, footnote 1).
SHARINGS = ("element", "action", "single")
#: Hidden-layer activations of the MLP controllers.
ACTIVATIONS = ("sigmoid", "tanh", "relu")
#: How a gymnasium env's observations are normalised.
NORMALIZATIONS = ("bounds", "stats")
#: The minimisation task's reward: of the noise-free or the noisy state.
REWARD_STATES = ("noise_free", "noisy")
#: An episode's return: the sum (the authors' code) or the mean (the paper's text) of its rewards.
EPISODE_RETURNS = ("sum", "mean")
#: The learning rate over the updates.
LR_SCHEDULES = ("constant", "linear", "cosine")
