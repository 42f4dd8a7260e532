"""The function-minimisation task of paper section 4.1, natively batched.

State ``x ∈ R^d``; action ``u``; ``x_{t+1} = x_t + s u_t + N(0, σ_noise² I)``; reward
``r_t = -‖x_t + s u_t‖²`` (``g`` of the noise-free successor, as in the authors' PyBrain code) or
``r_t = -‖x_{t+1}‖²`` (the noisy next state); ``g(x) = x²`` per coordinate, summed. All episodes
of all runs advance in one tensor operation.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, EnvBase, InitTracker, StepCounter, TransformedEnv

from sde_torchrl.utils.checks import ArgumentError, finite, one_of, positive_int
from sde_torchrl.utils.nonfinite import GUARDED_FIX, check_finite
from sde_torchrl.utils.options import REWARD_STATES
from sde_torchrl.utils.rng import RunStreams

#: What to do about a non-finite action, as the env's error says it.
_ACTION_FIX = ("the policy produced them (a diverged policy: lower the learning rate or bound the gradient with "
               f"max_grad_norm); {GUARDED_FIX}")


class MinimizeEnv(EnvBase):
    """Minimise ``‖x‖²`` by steering ``x`` with noisy steps (paper section 4.1).

    With ``runs`` set, the batch is ``[runs, episodes]`` and every run owns its random stream
    (seeded by :meth:`set_seed` from ``(seed, first_run + r, stream)``), so run ``r`` of a
    batched job sees exactly the noise a single job of that run would see. Without ``runs``,
    the batch is ``[episodes]`` and one private generator serves it.

    Episodes have no end of their own: wrap with ``StepCounter`` (see :func:`make_minimize_env`).

    Args:
        episodes: episodes simulated side by side (per run).
        dim: ``d``, dimension of the state and action.
        x0: start state, a scalar (every coordinate) or a ``d``-vector.
        x0_spread: half-width of a uniform jitter around ``x0`` (0 for a fixed start).
        step_size: ``s``, the factor on the action.
        noise_std: ``σ_noise``, standard deviation of the additive state noise.
        reward_state: which state ``g`` scores: ``"noise_free"``, the successor ``x_t + s u_t``
            before the state noise is added (the authors' PyBrain ``MinimizeTask`` on
            ``SimpleEnvironment``, which adds the noise afterwards to form the next
            observation), or ``"noisy"``, the next state ``x_{t+1}`` itself.
        runs: number of independent runs (leading batch dimension), or ``None``.
        first_run: global index of the first run (for seeding shards of a sweep).
        stream: random stream name, ``"env"`` for training or ``"eval_env"`` for evaluation.
        seed: seed applied at construction (``None``: seed 0; call :meth:`set_seed` to change).
        device: where the states, actions and rewards live (the random draws are made on the
            CPU by the runs' streams and moved, so a seed gives the same noise on every device).

    Raises:
        ArgumentError: a parameter is not allowed (``x0``, ``step_size`` and ``noise_std`` must
            be finite).

    Examples:
        >>> from torchrl.envs.utils import check_env_specs
        >>> env = MinimizeEnv(episodes=4, runs=2, seed=0)
        >>> env.rollout(3)["next", "reward"].shape
        torch.Size([2, 4, 3, 1])
    """

    def __init__(
        self, episodes: int = 10, *, dim: int = 1, x0: float | Sequence[float] = 5.0,
        x0_spread: float = 0.0, step_size: float = 0.1, noise_std: float = 0.5, reward_state: str = "noisy",
        runs: int | None = None, first_run: int = 0, stream: str = "env", seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        positive_int("episodes", episodes)
        positive_int("dim", dim)
        start = torch.as_tensor(x0, dtype=torch.float64)
        if start.numel() not in (1, dim) or start.dim() > 1 or not bool(torch.isfinite(start).all()):
            raise ArgumentError("x0", x0, f"a finite number or a list of dim={dim} finite numbers")
        finite("x0_spread", x0_spread, minimum=0)
        finite("step_size", step_size)
        finite("noise_std", noise_std, minimum=0)
        one_of("reward_state", reward_state, REWARD_STATES)
        self.reward_state = reward_state
        batch = (episodes,) if runs is None else (runs, episodes)
        super().__init__(batch_size=torch.Size(batch), device=device)
        self.dim, self.runs, self.first_run, self.stream = dim, runs, first_run, stream
        self.x0 = torch.as_tensor(x0, dtype=torch.float32).expand(dim).clone().to(self.device)
        self.x0_spread, self.step_size, self.noise_std = float(x0_spread), float(step_size), float(noise_std)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*batch, dim), device=self.device), shape=batch, device=self.device
        )
        self.action_spec = Unbounded(shape=(*batch, dim), device=self.device)
        self.reward_spec = Unbounded(shape=(*batch, 1), device=self.device)
        self._streams: RunStreams | None = None
        self.set_seed(0 if seed is None else seed)

    def _set_seed(self, seed: int | None) -> None:
        seed = 0 if seed is None else int(seed)
        self._streams = RunStreams(seed, self.runs or 1, self.stream, self.first_run)

    def _draw(self, kind: str, shape: tuple[int, ...]) -> torch.Tensor:
        """Draws ``shape`` (the full batch shape first) from the env's own streams (on the CPU),
        on the env's device."""
        if self.runs is None:  # one stream, viewed as a single run
            return getattr(self._streams, kind)((1, *shape))[0].to(self.device)
        return getattr(self._streams, kind)(shape).to(self.device)

    def initial_state(self) -> torch.Tensor:
        """Start states ``x₀`` (plus jitter) for the whole batch, ``[*batch, d]``."""
        jitter = self._draw("uniform", (*self.batch_size, self.dim))
        return self.x0 + self.x0_spread * (2 * jitter - 1)

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x_{t+1} = x_t + s u_t + N(0, σ_noise²)`` and ``r_t = -‖x_t + s u_t‖²`` (noise-free
        successor) or ``-‖x_{t+1}‖²`` (noisy), by ``reward_state`` (section 4.1).

        Args:
            x: states ``[*batch, d]``.
            u: actions ``[*batch, d]``.

        Returns:
            ``(x_next, reward)`` with ``reward`` shaped ``[*batch, 1]``.

        Raises:
            ValueError: ``u`` is not shaped like ``x``.
            NonFiniteInputError: ``u`` holds NaN or infinity, naming the runs and episodes
                (under the non-finite policy ``"raise"``, the default; under ``"guarded"``, the
                trainer's, the states and rewards become non-finite and its guard names the
                update: :mod:`sde_torchrl.utils.nonfinite`).
        """
        if u.shape != x.shape:
            raise ValueError(f"action has shape {tuple(u.shape)}, expected {tuple(x.shape)}")
        check_finite("action", u, ("episode",) if self.runs is None else ("run", "episode"), _ACTION_FIX)
        successor = x + self.step_size * u
        x_next = successor + self.noise_std * self._draw("normal", tuple(x.shape))
        return x_next, self._reward(successor, x_next)

    def linear_episodes(self, matrices: torch.Tensor, steps: int, squash: bool = True) -> tuple[torch.Tensor, ...]:
        """Fresh episodes under a linear controller ``u_t = M_t x_t`` whose maps are known in
        advance: one ``M`` per episode or one per step.

        SDE with its episode schedule makes the exploratory policy one linear map of the state
        for a whole episode (``Θ + Θ̂``, eqs. 17-19), REX one known map per step (``Θ + Θ̂_t``),
        and the deterministic policy is ``Θ`` itself. The episode is :meth:`transition` unrolled
        with no policy call per step: the start states and every step's state noise come from the
        env's streams in one draw each (the numbers, in the order, that :meth:`initial_state` and
        ``steps`` calls of :meth:`transition` draw), and the rewards are computed once at the end.

        Args:
            matrices: ``M``, shaped ``[*batch_size, d, d]`` (one per episode) or
                ``[*batch_size, steps, d, d]`` (one per step).
            steps: episode length.
            squash: apply ``tanh`` to ``M x`` before it acts (the bounds ``[-1, 1]``).

        Returns:
            ``(states [*batch, steps + 1, d], pre-squash actions [*batch, steps, d], rewards
            [*batch, steps, 1])``.

        Raises:
            ArgumentError: ``steps`` is not a positive integer.
            ValueError: ``matrices`` has another shape.
            NonFiniteInputError: an action is NaN or infinite, naming its run, episode and step
                (as :meth:`transition`, under the non-finite policy ``"raise"``).

        Examples:
            >>> env = MinimizeEnv(episodes=4, runs=2, x0=2.0, seed=0)
            >>> states, actions, rewards = env.linear_episodes(torch.full((2, 4, 1, 1), -5.0), 15, squash=False)
            >>> states.shape, actions.shape, rewards.shape
            (torch.Size([2, 4, 16, 1]), torch.Size([2, 4, 15, 1]), torch.Size([2, 4, 15, 1]))
        """
        positive_int("steps", steps)
        batch, d = tuple(self.batch_size), self.dim
        if tuple(matrices.shape) not in ((*batch, d, d), (*batch, steps, d, d)):
            raise ValueError(f"matrices must have shape {(*batch, d, d)} or {(*batch, steps, d, d)}, "
                             f"got {tuple(matrices.shape)}")
        per_step = matrices.dim() == len(batch) + 3
        x = self.initial_state()
        # step t's noise: what the t-th call of transition draws (each run's stream in order)
        runs = 0 if self.runs is None else 1  # the draws' leading run dimension, if any
        noise = self.noise_std * self._draw("normal", (*batch[:runs], steps, *batch[runs:], d)).movedim(runs, 0)
        rows = matrices.transpose(-1, -2)  # u_t as the row x_tᵀ M_tᵀ
        states, samples, actions = [x], [], []
        for t in range(steps):
            samples.append((x.unsqueeze(-2) @ (rows[..., t, :, :] if per_step else rows)).squeeze(-2))
            actions.append(torch.tanh(samples[-1]) if squash else samples[-1])
            x = x + self.step_size * actions[-1] + noise[t]
            states.append(x)
        time_dim = len(batch)
        states, samples, actions = (torch.stack(column, time_dim) for column in (states, samples, actions))
        check_finite("action", actions, ("episode", "step") if self.runs is None else ("run", "episode", "step"),
                     _ACTION_FIX)
        successors = states[..., :-1, :] + self.step_size * actions
        return states, samples, self._reward(successors, states[..., 1:, :])

    def _reward(self, successor: torch.Tensor, x_next: torch.Tensor) -> torch.Tensor:
        """``-‖x_t + s u_t‖²`` or ``-‖x_{t+1}‖²`` by ``reward_state``, ``[..., 1]``."""
        scored = successor if self.reward_state == "noise_free" else x_next
        return -scored.square().sum(-1, keepdim=True)

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        # Fresh starts for the whole batch: on a partial reset TorchRL keeps, by the "_reset"
        # mask, the running episodes' entries; drawing for all keeps the streams data-independent.
        return TensorDict({"observation": self.initial_state()}, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        x_next, reward = self.transition(tensordict["observation"], tensordict["action"])
        done = torch.zeros(*self.batch_size, 1, dtype=torch.bool, device=self.device)
        return TensorDict(
            {"observation": x_next, "reward": reward, "done": done, "terminated": done.clone()},
            batch_size=self.batch_size, device=self.device,
        )

def make_minimize_env(episode_length: int = 15, **kwargs) -> TransformedEnv:
    """A :class:`MinimizeEnv` whose episodes last ``episode_length`` steps, with ``is_init``.

    Args:
        episode_length: steps per episode (EL in the paper).
        **kwargs: passed to :class:`MinimizeEnv`.

    Returns:
        The env wrapped in ``StepCounter(max_steps=episode_length)`` and ``InitTracker``.
    """
    positive_int("episode_length", episode_length)
    env = TransformedEnv(MinimizeEnv(**kwargs), Compose(StepCounter(episode_length), InitTracker()))
    return env


def expected_linear_return(
    theta: float, episode_length: int, x0: float, step_size: float = 0.1, noise_std: float = 0.5,
    reward_state: str = "noisy", episode_return: str = "mean",
) -> float:
    """Expected return of the deterministic controller ``u = θ x`` on the 1-D task (closed form).

    With ``a = 1 + sθ`` and ``m_t = E[x_t²]``: ``m_0 = x_0²``, ``m_{t+1} = a² m_t + σ_noise²``.
    The noise-free successor scores ``E[r_t] = -a² m_t``, the noisy next state
    ``E[r_t] = -m_{t+1}`` (``t = 0..T-1``); the return is the sum or the mean (eq. 1's ``R``,
    section 2.1) of those.

    Args:
        theta: controller gain.
        episode_length: ``T``.
        x0: fixed start state.
        step_size: ``s``.
        noise_std: ``σ_noise``.
        reward_state: ``"noise_free"`` or ``"noisy"`` (see :class:`MinimizeEnv`).
        episode_return: ``"sum"`` or ``"mean"`` of the rewards.

    Returns:
        The expected return.

    Examples:
        >>> round(expected_linear_return(-2.0, 15, 2.0, 0.1, 0.5, "noise_free", "sum"), 2)
        -12.54
    """
    if reward_state not in REWARD_STATES:
        raise ValueError(f"reward_state must be one of {REWARD_STATES}, got {reward_state!r}")
    if episode_return not in ("sum", "mean"):
        raise ValueError(f"episode_return must be 'sum' or 'mean', got {episode_return!r}")
    a2, second_moment, total = (1 + step_size * theta) ** 2, float(x0) ** 2, 0.0
    for _ in range(episode_length):
        following = a2 * second_moment + noise_std**2
        total += a2 * second_moment if reward_state == "noise_free" else following
        second_moment = following
    return -total if episode_return == "sum" else -total / episode_length


def midway_threshold(
    episode_length: int, x0: float, step_size: float, noise_std: float, theta0: float
) -> float:
    """Convergence threshold half-way, in expected return, from ``θ₀`` to the optimum ``-1/s``.

    The paper's ``R_lim`` is "a value that all controllers reached"; its own numbers do not fit
    its other settings (README, "Calibration"). This rule gives one threshold per setting, the
    same for every explorer: the mean of the expected returns of the starting controller and of
    the optimal one (:func:`expected_linear_return`).
    """
    start = expected_linear_return(theta0, episode_length, x0, step_size, noise_std)
    best = expected_linear_return(-1 / step_size, episode_length, x0, step_size, noise_std)
    return (start + best) / 2
