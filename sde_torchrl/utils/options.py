"""The allowed values of the string options, written once.

The config schemas (:mod:`sde_torchrl.config.schemas`) and the constructors for direct Python use
check against these same tuples. Standard library only, so that checking a config imports no
torch.
"""

from __future__ import annotations

#: When the SDE noise matrix is redrawn: per episode (SDE), per step (REX), every ``n`` steps of an
#: episode, or as Stable-Baselines3's ``sde_sample_freq`` counts: every ``n`` steps of a rollout
#: whatever the episode boundaries (``every_n_steps``, ``sde_sample_freq=n``) or once per rollout
#: (``rollout``, ``sde_sample_freq=-1``).
SCHEDULES = ("episode", "step", "every_n", "every_n_steps", "rollout")
#: The schedules with a redraw period ``every_n``.
PERIODIC_SCHEDULES = ("every_n", "every_n_steps")
#: The schedules that hold ``ξ`` across episode boundaries and count a rollout's steps (SB3's
#: counting); they take an optional rollout length ``rollout_steps``.
ROLLOUT_SCHEDULES = ("every_n_steps", "rollout")
#: One ``σ̂`` per matrix element, per action, one for all (paper section 2.3, footnote 1), or one
#: per feature shared over the actions (SB3's ``full_std=False``).
SHARINGS = ("element", "action", "single", "feature")
#: The map from SDE's parameter ``p`` to ``σ̂``: expln (eq. 23) or plain exp (SB3's ``use_expln=False``).
SIGMA_TRANSFORMS = ("expln", "exp")
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
#: How REINFORCE, ENAC and GPOMDP compute the policy's scores: autograd through the policy, or
#: eqs. 16, 21 and 24 for a linear controller (:mod:`sde_torchrl.objectives.linear_scores`).
SCORE_METHODS = ("autograd", "closed_form")
#: When the scores of a queued episode are taken (``queue_scores``): at every update under the
#: current parameters, or once when the episode is collected, under the parameters that acted (the
#: authors' PyBrain learners).
QUEUE_SCORES = ("rescored", "as_collected")
#: What a NaN or an infinity does (:mod:`sde_torchrl.utils.nonfinite`): raise where it is found
#: (the default), or pass, for a guard that checks the results itself (the trainer's).
NONFINITE_POLICIES = ("raise", "guarded")
