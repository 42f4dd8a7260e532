"""Batched TorchRL form of the ball-catching task: N pybullet worlds stepped together in one process.

Each world is a :class:`~sde_torchrl.envs.ballcatch.world.BallCatchWorld` (its own DIRECT physics
client) stepped through the task rules (:class:`~sde_torchrl.envs.ballcatch.task.CatchEpisode`,
as in the gymnasium env :class:`~sde_torchrl.envs.ballcatch.gym_env.BallCatchEnv`); the env has
``batch_size [N]`` so a policy runs once per step for all N worlds. Whole episodes of linear
controllers run world by world instead (:meth:`BatchedBallCatchEnv.linear_episodes`,
:mod:`~sde_torchrl.envs.ballcatch.episodes`).

To use a second core, run two batched envs in two processes with :func:`make_parallel_ballcatch`
(a :class:`torchrl.envs.ParallelEnv`, batch size ``[workers, N]``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, InitTracker, ParallelEnv, TransformedEnv

from sde_torchrl.envs.ballcatch.episodes import linear_episode
from sde_torchrl.envs.ballcatch.models import DEFAULT_MODEL
from sde_torchrl.envs.ballcatch.outcomes import catch_outcomes
from sde_torchrl.envs.ballcatch.task import EPISODE_STEPS, CatchEpisode
from sde_torchrl.envs.ballcatch.world import BallCatchConfig, BallCatchWorld
from sde_torchrl.utils.rng import RunStreams

__all__ = ["OBSERVATIONS", "BatchedBallCatchEnv", "make_ballcatch_env", "make_parallel_ballcatch"]

#: What the env can observe: the raw ball position (the paper's) or its scaled form.
OBSERVATIONS = ("raw", "scaled")


class BatchedBallCatchEnv(EnvBase):
    """N independent ball-catching worlds as one TorchRL env with ``batch_size [N]``.

    Keys: ``"observation"`` (float32 ``[N, 3]``, ball xyz; ``[N, 4]`` scaled, see ``observation``),
    ``"distance"`` (float32 ``[N, 1]``, ball-palm centre distance, for diagnostics), ``"action"``
    (``Bounded(-1, 1, [N, 4])``: shoulder, elbow, wrist, fingers, scaled by the max torques),
    ``("next", "reward")`` ``[N, 1]`` and
    ``"done"``/``"terminated"``/``"truncated"`` ``[N, 1]``. Episodes are never terminated; they are
    truncated after ``max_steps`` (500) steps. A ``"_reset"`` mask resets only the selected worlds.

    With ``runs`` set, the batch is ``[runs, num_worlds]`` (``runs × num_worlds`` worlds): the
    layout of independent learners trained side by side, each run drawing its release jitter
    from its own stream (:class:`~sde_torchrl.utils.rng.RunStreams`, seeded by :meth:`set_seed`).

    Args:
        num_worlds: number of worlds N (one pybullet DIRECT client each), per run if ``runs``.
        config: physical parameters shared by all worlds, the arm model among them (default
            :class:`BallCatchConfig`: model "pybrain").
        max_steps: episode length (the paper's 500).
        seed: seed of the env's private generator for the ball's release jitter.
        device: torch device of the returned tensors (physics always runs on the CPU).
        runs: number of independent runs (leading batch dimension), or ``None``.
        first_run: global index of the first run (seeding shards of a sweep).
        stream: random stream name for the runs (``"env"`` or ``"eval_env"``).
        observation: ``"raw"``, the ball position as the paper gives it, or ``"scaled"``: the
            ball position mapped onto ``[-1, 1]`` over the arm's workspace
            (:attr:`~sde_torchrl.envs.ballcatch.models.ArmModel.workspace`), a constant 1
            appended (:meth:`features`).

    Examples:
        >>> import torch
        >>> env = BatchedBallCatchEnv(num_worlds=4, seed=0)
        >>> td = env.rollout(500, lambda td: td.set("action", torch.ones(4, 4)))
        >>> td["next", "reward"].shape
        torch.Size([4, 500, 1])
        >>> bool(td["next", "truncated"][:, -1].all())
        True
        >>> env.close()
    """

    def __init__(
        self,
        num_worlds: int = 8,
        config: BallCatchConfig | None = None,
        max_steps: int = EPISODE_STEPS,
        seed: int | None = None,
        device: torch.device | str = "cpu",
        runs: int | None = None,
        first_run: int = 0,
        stream: str = "env",
        observation: str = "raw",
    ) -> None:
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {observation!r}")
        if num_worlds < 1:
            raise ValueError(f"num_worlds must be >= 1, got {num_worlds}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if runs is not None and runs < 1:
            raise ValueError(f"runs must be >= 1, got {runs}")
        batch = (num_worlds,) if runs is None else (runs, num_worlds)
        super().__init__(device=device, batch_size=torch.Size(batch))
        self.config = config or BallCatchConfig()
        self.observation = observation
        low, high = torch.tensor(self.config.arm.workspace, dtype=torch.float64).unbind(-1)
        self._centre, self._half_width = (low + high) / 2, (high - low) / 2
        self.num_worlds = num_worlds * (runs or 1)  # worlds in all, stored flat
        num_worlds = self.num_worlds
        self.max_steps = max_steps
        self.runs, self.first_run, self.stream = runs, first_run, stream
        self._set_seed(seed)
        self.worlds: list[BallCatchWorld] = []
        try:
            for i in range(num_worlds):
                self.worlds.append(BallCatchWorld(self.config, name=f"world {i}"))
        except Exception:
            self._close_worlds()
            raise
        self.episodes = [CatchEpisode(world, max_steps) for world in self.worlds]
        self._make_specs()

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        n = tuple(self.batch_size)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*n, self.feature_dim), dtype=torch.float32, device=self.device),
            distance=Unbounded(shape=(*n, 1), dtype=torch.float32, device=self.device),
            shape=n,
            device=self.device,
        )
        self.action_spec = Bounded(-1.0, 1.0, shape=(*n, 4), dtype=torch.float32, device=self.device)
        self.reward_spec = Unbounded(shape=(*n, 1), dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, shape=(*n, 1), dtype=torch.bool, device=self.device),
            terminated=Categorical(2, shape=(*n, 1), dtype=torch.bool, device=self.device),
            truncated=Categorical(2, shape=(*n, 1), dtype=torch.bool, device=self.device),
            shape=n,
            device=self.device,
        )

    # ------------------------------------------------------------------ observation
    @property
    def feature_dim(self) -> int:
        """Length of the observation: 3 (raw) or 4 (scaled, with the constant feature)."""
        return 3 if self.observation == "raw" else 4

    def features(self, ball: torch.Tensor) -> torch.Tensor:
        """The observation of ball positions ``[..., 3]``: themselves (raw) or ``[(x - c) / h, 1]``
        (scaled), ``c`` and ``h`` the workspace's centre and half-widths, in ``ball``'s dtype.

        Examples:
            >>> env = BatchedBallCatchEnv(num_worlds=1, observation="scaled")
            >>> env.features(torch.tensor([3.5, 0.0, 5.5], dtype=torch.float64)).tolist()
            [0.0, 0.0, 0.8333333333333334, 1.0]
            >>> env.close()
        """
        if self.observation == "raw":
            return ball
        centre, half = self._centre.to(ball), self._half_width.to(ball)
        return torch.cat([(ball - centre) / half, torch.ones_like(ball[..., :1])], -1)

    def ball_positions(self, observation: torch.Tensor) -> torch.Tensor:
        """The ball positions ``[..., 3]`` an observation holds (the inverse of :meth:`features`)."""
        if self.observation == "raw":
            return observation
        return observation[..., :3] * self._half_width.to(observation) + self._centre.to(observation)

    def episode_outcomes(self, episodes: TensorDictBase) -> dict[str, torch.Tensor]:
        """What whole episodes of this env (``[..., T]``, from their reset on) did: dropped, kept
        on the hand or held, and when the ball was first held
        (:func:`~sde_torchrl.envs.ballcatch.outcomes.catch_outcomes`)."""
        observed = torch.cat([episodes["observation"][..., :1, :], episodes["next", "observation"]], -2)
        return catch_outcomes(self.ball_positions(observed), episodes["action"][..., 3],
                              episodes["next", "reward"][..., 0], self.config.arm.ground_z)

    def film(self, act: Callable[[torch.Tensor], torch.Tensor], path: str | Path, seed: int = 0) -> float:
        """Films one episode of ``act`` (this env's observation ``[F]`` → action ``[4]``) in the
        gymnasium form of the same arm (a fresh ball, released by ``seed``) as a GIF at ``path``
        (about a second of rendering); returns the episode's mean reward per step."""
        from sde_torchrl.envs.ballcatch.demo import write_gif
        from sde_torchrl.envs.ballcatch.gym_env import BallCatchEnv, episode_return

        env, frames = BallCatchEnv(render_mode="rgb_array", config=self.config), []
        try:
            value = episode_return(env, lambda obs: act(self.features(torch.as_tensor(obs))).double().numpy(),
                                   seed, frames=frames)
        finally:
            env.close()
        write_gif(frames, path)
        return value

    def _affine_maps(self, matrices: torch.Tensor) -> torch.Tensor:
        """Maps ``M`` of the observation (``[..., 4, F]``, float64) as maps ``[A | b]`` of the raw
        ball position, ``M features(x) = A x + b`` (``[..., 4, 4]``)."""
        if self.observation == "raw":
            return torch.cat([matrices, torch.zeros_like(matrices[..., :1])], -1)
        scale = matrices[..., :3] / self._half_width
        offset = matrices[..., 3] - (scale * self._centre).sum(-1)
        return torch.cat([scale, offset.unsqueeze(-1)], -1)

    # ------------------------------------------------------------------ EnvBase API
    def _set_seed(self, seed: int | None) -> None:
        """Reseed the env's private generator (release jitter); global RNGs are not touched."""
        if self.runs is None:
            self._rng = np.random.default_rng(seed)
        else:
            self._streams = RunStreams(0 if seed is None else int(seed), self.runs, self.stream, self.first_run)

    def _jitter(self) -> np.ndarray:
        """Horizontal release offsets ``[worlds, 2]`` for every world (drawn for all, so the
        streams do not depend on which worlds reset)."""
        jitter = self.config.jitter
        if self.runs is None:
            return self._rng.uniform(-jitter, jitter, size=(self.num_worlds, 2))
        u = self._streams.uniform((*self.batch_size, 2)).double().numpy().reshape(-1, 2)
        return jitter * (2 * u - 1)

    def _reset(self, tensordict: TensorDictBase | None, **kwargs: object) -> TensorDictBase:
        """Reset the worlds selected by ``"_reset"`` (all if absent); others keep their state."""
        mask = self._reset_mask(tensordict)
        offsets = self._jitter()
        for i in np.flatnonzero(mask).tolist():
            self.episodes[i].reset(offsets[i])
        return self._pack()

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Apply the ``[N, 4]`` action in every world, step once, observe and score."""
        return self._pack(self._advance(tensordict.get("action")))

    def _advance(self, action: torch.Tensor | None) -> list[float]:
        """One step of the task rules in every world under ``action``: the rewards ``[N]``
        (worlds whose ball has touched the ground stay frozen)."""
        return [episode.step(a) for episode, a in zip(self.episodes, self._actions(action), strict=True)]

    # ---------------------------------------------- tensor stepping (sde_torchrl.collectors.rollout)
    def initial_state(self) -> torch.Tensor:
        """Resets every world; returns the ball positions ``[N, 3]`` (the observation)."""
        return self._reset(None)["observation"]

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Steps every world under ``u`` (``x``, the current observation, lives in the worlds).

        Returns:
            Ball positions ``[N, 3]`` and rewards ``[N, 1]``, as :meth:`_step` computes them.
        """
        reward = self._advance(u)
        batch = tuple(self.batch_size)
        ball = torch.tensor([e.ball for e in self.episodes], dtype=torch.float64).reshape(*batch, 3)
        return (self.features(ball).float().to(self.device),
                torch.tensor(reward, dtype=torch.float32).reshape(*batch, 1).to(self.device))

    # ---------------------------------------------- whole episodes of linear controllers (fast path)
    def linear_episodes(self, matrices: torch.Tensor, steps: int, squash: bool = True) -> tuple[torch.Tensor, ...]:
        """Fresh episodes of every world under a linear controller ``u_t = M_t x_t`` each, whose
        maps are known in advance: one ``M`` for the whole episode or one per step.

        SDE with its episode schedule makes the exploratory policy one linear map of the
        observation for a whole episode (``Θ + Θ̂``, eqs. 17-19), REX (the ``step`` schedule) one
        known map per step (``Θ + Θ̂_t``), and the deterministic policy is ``Θ`` itself. Such a
        controller needs no batched policy call per step, so each world runs its whole episode on
        its own (:func:`~sde_torchrl.envs.ballcatch.episodes.linear_episode`), while its physics
        state stays in the CPU cache (stepping N worlds in turn evicts it at every step). Physics,
        release jitter and task rules are those of :meth:`_step`; the controller works in float64
        where the step-by-step path rounds the observation and action to float32 (differences
        ~1e-7).

        Args:
            matrices: ``M``, shaped ``[*batch_size, 4, F]`` (one per episode) or
                ``[*batch_size, steps, 4, F]`` (one per step), ``F`` the observation's length
                (the maps act on the observation, :meth:`features`).
            steps: episode length.
            squash: apply ``tanh`` to ``u`` (else ``u`` is clipped to ``[-1, 1]`` like any action).

        Returns:
            ``(observations [*batch, steps + 1, 3], samples [*batch, steps, 4], rewards
            [*batch, steps, 1])``: the ball positions from the reset on, the pre-squash ``u``
            and the rewards, float32, on the env's device.

        Raises:
            ValueError: for matrices of the wrong shape or with non-finite entries, or
                ``steps < 1``.

        Examples:
            >>> env = BatchedBallCatchEnv(num_worlds=2, seed=0)
            >>> per_step = torch.zeros(2, 100, 4, 3)
            >>> per_step[..., 0] = 1.0  # u_t = (x, x, x, x): arm up, hand closed
            >>> observations, samples, rewards = env.linear_episodes(per_step, 100)
            >>> observations.shape, samples.shape, rewards.shape
            (torch.Size([2, 101, 3]), torch.Size([2, 100, 4]), torch.Size([2, 100, 1]))
            >>> env.close()
        """
        if steps < 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        batch = tuple(self.batch_size)
        shape = tuple(matrices.shape)
        f = self.feature_dim
        if shape not in ((*batch, 4, f), (*batch, steps, 4, f)):
            raise ValueError(f"matrices must have shape {(*batch, 4, f)} or {(*batch, steps, 4, f)}, got {shape}")
        per_step = len(shape) == len(batch) + 3
        flat = self._affine_maps(matrices.detach().cpu().double()).reshape(self.num_worlds, -1, 16).numpy()
        finite = np.isfinite(flat).all(axis=(1, 2))
        if not finite.all():
            bad = np.flatnonzero(~finite).tolist()
            raise ValueError(f"controller matrices contain non-finite values in worlds {bad}")
        offsets, episodes = self._jitter(), []
        for i, episode in enumerate(self.episodes):
            episode.reset(offsets[i])
            maps = flat[i].tolist()  # rows of 16 floats, one world at a time: numpy lists them fastest
            episodes.append(linear_episode(episode, maps if per_step else maps * steps, squash))
        observations, samples, rewards = (torch.tensor([e[k] for e in episodes], dtype=torch.float64) for k in range(3))
        observations = self.features(observations)
        return tuple(t.float().reshape(*batch, *shape).to(self.device)  # computed on the CPU, on the env's device
                     for t, shape in ((observations, (steps + 1, f)), (samples, (steps, 4)), (rewards, (steps, 1))))

    # ------------------------------------------------------------------ helpers
    def _reset_mask(self, tensordict: TensorDictBase | None) -> np.ndarray:
        """Boolean ``[N]`` mask of the worlds to reset (all if no ``"_reset"`` entry)."""
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None:
            return np.ones(self.num_worlds, dtype=bool)
        return reset.reshape(self.num_worlds, -1).any(-1).cpu().numpy()

    def _actions(self, action: torch.Tensor | None) -> list[list[float]]:
        """The validated ``[N, 4]`` action, one row of floats per world (the task clips them)."""
        if action is None:
            raise ValueError("the input tensordict has no 'action' entry")
        if tuple(action.shape) != (*self.batch_size, 4):
            raise ValueError(f"action must have shape {(*self.batch_size, 4)}, got {tuple(action.shape)}")
        a = action.detach().cpu().reshape(-1, 4).numpy().astype(np.float64)  # numpy: far cheaper than torch ops here
        finite = np.isfinite(a).all(axis=-1)
        if not finite.all():
            raise ValueError(f"action contains non-finite values in worlds {np.flatnonzero(~finite).tolist()}")
        return a.tolist()

    def _pack(self, reward: list[float] | None = None) -> TensorDict:
        """Observations, done flags (never terminated) and, after a step, rewards as a ``[N]`` TensorDict."""
        batch = tuple(self.batch_size)
        episodes = self.episodes
        trunc = torch.tensor([e.truncated for e in episodes]).reshape(*batch, 1)
        data = {
            "observation": self.features(torch.tensor([e.ball for e in episodes], dtype=torch.float64)).float()
            .reshape(*batch, self.feature_dim),
            "distance": torch.tensor([e.distance for e in episodes], dtype=torch.float32).reshape(*batch, 1),
            "done": trunc,
            "terminated": torch.zeros_like(trunc),
            "truncated": trunc.clone(),
        }
        if reward is not None:
            data["reward"] = torch.tensor(reward, dtype=torch.float32).reshape(*batch, 1)
        return TensorDict(data, batch_size=self.batch_size, device=self.device)

    def _close_worlds(self) -> None:
        for world in self.worlds:
            world.close()

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Disconnect every physics client."""
        self._close_worlds()
        super().close(raise_if_closed=raise_if_closed)


def make_parallel_ballcatch(
    num_workers: int = 2,
    worlds_per_worker: int = 8,
    config: BallCatchConfig | None = None,
    **parallel_kwargs,
) -> ParallelEnv:
    """Run ``num_workers`` :class:`BatchedBallCatchEnv` in as many processes (uses more cores).

    The result has batch size ``[num_workers, worlds_per_worker]``; seed it with ``set_seed``
    (worker ``k`` gets the k-th seed of TorchRL's seed chain).

    Examples:
        >>> env = make_parallel_ballcatch(2, 4)
        >>> _ = env.set_seed(0)
        >>> env.reset()["observation"].shape
        torch.Size([2, 4, 3])
        >>> env.close()
    """
    make = functools.partial(BatchedBallCatchEnv, num_worlds=worlds_per_worker, config=config)
    return ParallelEnv(num_workers, make, **parallel_kwargs)


def make_ballcatch_env(
    episodes: int = 1, *, runs: int | None = None, first_run: int = 0, stream: str = "env",
    episode_length: int = EPISODE_STEPS, jitter: float = 0.05, seed: int | None = None, model: str = DEFAULT_MODEL,
    observation: str = "raw", device: torch.device | str = "cpu",
) -> TransformedEnv:
    """The batched ball-catching env as the trainer builds envs: ``[runs, episodes]`` worlds
    with ``is_init`` (episodes end by themselves after ``episode_length`` steps).

    Args:
        episodes: worlds per run (episodes collected side by side).
        runs: independent runs, or ``None``.
        first_run: global index of the first run.
        stream: ``"env"`` or ``"eval_env"``.
        episode_length: steps per episode (the paper's 500).
        jitter: half-width of the uniform horizontal release offset.
        seed: seed of the release jitter.
        model: the arm, a key of :data:`~sde_torchrl.envs.ballcatch.models.ARM_MODELS` (default ``"pybrain"``).
        observation: ``"raw"`` (the paper's) or ``"scaled"`` (:class:`BatchedBallCatchEnv`).
        device: where the observations and rewards are put (the physics runs on the CPU).

    Returns:
        ``TransformedEnv(BatchedBallCatchEnv(...), InitTracker())``.
    """
    base = BatchedBallCatchEnv(
        num_worlds=episodes, config=BallCatchConfig(jitter=jitter, model=model), max_steps=episode_length,
        seed=seed, device=device, runs=runs, first_run=first_run, stream=stream, observation=observation,
    )
    return TransformedEnv(base, InitTracker())
