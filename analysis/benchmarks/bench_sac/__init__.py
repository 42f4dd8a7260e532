"""SAC with the SDE policy on TorchRL, against Stable-Baselines3 SAC + gSDE (and both with a plain Gaussian).

Four methods, the same hyperparameters (rl-baselines3-zoo's tuned SAC settings, ``hyperparams/sac.yml``,
:data:`.build.ZOO`), one env stepped in one process:

* ``sde``: TorchRL ``Collector`` + ``ReplayBuffer`` (``LazyTensorStorage``, uniform sampling with
  replacement) + ``SACLoss``, with the SDE policy (:func:`sde_torchrl.make_sde_actor`, tanh-squashed):
  features ``x`` from the actor's last hidden layer, *not* detached (SB3's SAC builds its gSDE
  distribution with ``learn_features=True``), the mean clipped to ``[-2, 2]`` before the squash
  (SB3's ``clip_mean=2.0``), one ``σ̂`` per matrix element (``full_std=True``), ``p`` initialised to
  ``log_std_init``; the collection noise ``ξ`` is redrawn every ``train_freq`` steps and at every
  reset (``schedule="every_n"``);
* ``plain``: the same loop with a tanh-squashed state-dependent Gaussian (TorchRL ``TanhNormal``,
  mean and log-std heads on the last hidden layer, log-std clamped to ``[-20, 2]``: SB3's SAC actor
  without gSDE);
* ``sb3``: Stable-Baselines3 ``SAC(use_sde=True)``;
* ``sb3_gauss``: the same with ``use_sde=False``.

**Which noise the actor loss uses.** The replay buffer holds the ``ξ`` each transition was
collected with, but the SAC losses (the actor loss, and the next-state action of the critic's
target) use a *fresh* standard-normal matrix, one per gradient step shared by the whole
minibatch, as SB3 does (``actor.reset_noise()`` at each gradient step, whose single
``exploration_mat`` serves every row; ``sac/sac.py``, ``common/distributions.py``). Reason: the
reparameterised SAC gradient needs ``a = μ(s) + (σ̂ ⊙ ξ) x(s)`` with ``ξ ~ N(0, I)`` independent of
``s``; a stored ``ξ`` is not: it is the noise that steered the episode into ``s`` (held for
``train_freq`` steps), so ``ξ | s`` is not standard normal and the stored noise would bias the
actor's gradient and its entropy estimate (and each transition would be scored with one and the
same ``ξ`` at every replay). :func:`sde_torchrl.trainers.sac.fresh_loss_noise` does it;
``--loss-noise stored`` keeps the buffer's ``ξ`` (the ablation row). The networks, the loss and the
gradient step are the library's (:mod:`sde_torchrl.modules.sac_actor`, :mod:`sde_torchrl.trainers.sac`),
which ``algorithm=sac`` trains with; the collection loop here is TorchRL's ``Collector``, as the
committed runs were made.

The update follows SB3's order per gradient step: critic loss and step, actor loss (with the
updated critics) and step, entropy-coefficient step (``ent_coef: auto`` only; the critic and actor
use the coefficient from before that step), Polyak update of the target critics. TorchRL's
critic loss ``Σ_k (Q_k - y)²`` is halved to SB3's ``½ Σ_k MSE`` (Adam would not see the factor).
With ``learning_starts > 0`` both sides act uniformly at random until then (SB3's default
``use_sde_at_warmup=False``; TorchRL's ``init_random_frames``).

Differences left, as the committed runs were made: ``σ̂ = expln(p)`` here, ``exp(p)`` in SB3
(equal while ``p <= 0``: each run records its largest ``p``; the library's
``SDEParams(sigma_transform="exp")`` is SB3's); SB3 counts its ``train_freq`` resampling period
over the run, our ``every_n`` restarts at each reset (``schedule="every_n_steps"`` is SB3's
counting); SB3 adds 1e-6 to the action variance and to ``1 - tanh²`` and scores ``atanh`` of the
squashed action, ours scores the exact pre-squash sample.

**The compiled update** (``run --compile``, the ``sde_compiled`` row): the whole gradient step
above (fresh noise, both losses, their backward passes, the Adam steps, the target update) goes
through ``torch.compile`` (inductor, its min-cut partitioner told to recompute boolean masks rather
than save them: :func:`.compiler.recompute_boolean_masks`), as TorchRL's own SAC scripts compile theirs with
their ``compile`` option. It computes the same step (tested against the eager one with
inductor and the stored noise); the fresh noise inside it
comes from inductor's random generator, not eager PyTorch's, so a compiled run is not the eager
run of the same seed. The first steps compile, inside the timed training: the report gives the
compilation's time (the first round of gradient steps less the median round, :func:`.report.compilation_s`)
and the speed without it, the speed a longer run tends to. ``run --compile --compile-policy`` also
compiles the collector's policy forward (TorchRL's ``Collector(compile_policy=True)``; the
``sde_compiled_policy`` row): the SDE actor's TensorDict modules, distribution and sample in one graph.

Each run writes ``<out>/<env>_<method>_seed<k>.json``: the deterministic return of 10 evaluation
episodes at the end, the training episodes' returns against env steps, env steps per
second of the whole training (collection and updates, evaluation excluded), wall clock and CPU
time, and (TorchRL) the wall and CPU seconds of each round of gradient steps. ``report`` turns
a folder of runs into a table per env and a plot; ``update-speed`` times
single gradient steps of the four methods and profiles ours.

Usage::

    python -m analysis.benchmarks.bench_sac run --env mountaincar --method sde --seed 0 --steps 8000 \
        --out results/sac/runs
    python -m analysis.benchmarks.bench_sac run --env mountaincar --method sde --compile --compile-policy --seed 0 \
        --out results/sac/zoo_budget/runs
    python -m analysis.benchmarks.bench_sac report results/sac/runs --out docs/sac
    python -m analysis.benchmarks.bench_sac update-speed --env mountaincar --profile \
        --out docs/sac/update_speed_mountaincar.md

One module per job: :mod:`.build` (the settings, the env, the networks and the loss),
:mod:`.compiler` (the compiled update's pass over AOTAutograd's private settings), :mod:`.train`
(the gradient step, both training loops and a run's record), :mod:`.update_speed` (the timed and
profiled gradient steps), :mod:`.report` (the tables and the plot), :mod:`.cli` (the command
line); what it shares with the PPO benchmark is in :mod:`analysis.benchmarks.common`.
"""
