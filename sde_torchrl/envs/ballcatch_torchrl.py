"""Batched TorchRL form of the ball-catching task: N pybullet worlds stepped together in one process.

Each world is a :class:`~sde_torchrl.envs.ballcatch.BallCatchWorld` (its own DIRECT physics
client); the env has ``batch_size [N]`` so a policy runs once per step for all N worlds. Physics,
reward and episode length are exactly those of the gymnasium env
:class:`~sde_torchrl.envs.ballcatch.BallCatchEnv`.

To use a second core, run two batched envs in two processes with :func:`make_parallel_ballcatch`
(a :class:`torchrl.envs.ParallelEnv`, batch size ``[workers, N]``).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, InitTracker, ParallelEnv, TransformedEnv

from sde_torchrl.envs.ballcatch import (
    DISTANCE_CAP,
    EPISODE_STEPS,
    GROUND_REWARD,
    MIN_DISTANCE,
    BallCatchConfig,
    BallCatchWorld,
    joint_torques,
    step_reward,
)
from sde_torchrl.rng import RunStreams

__all__ = ["BatchedBallCatchEnv", "make_ballcatch_env", "make_parallel_ballcatch"]


class BatchedBallCatchEnv(EnvBase):
    """N independent ball-catching worlds as one TorchRL env with ``batch_size [N]``.

    Keys: ``"observation"`` (float32 ``[N, 3]``, ball xyz), ``"distance"`` (float32 ``[N, 1]``,
    ball-palm centre distance, for diagnostics), ``"action"`` (``Bounded(-1, 1, [N, 4])``: shoulder,
    elbow, wrist, fingers, scaled by the max torques), ``("next", "reward")`` ``[N, 1]`` and
    ``"done"``/``"terminated"``/``"truncated"`` ``[N, 1]``. Episodes are never terminated; they are
    truncated after ``max_steps`` (500) steps. A ``"_reset"`` mask resets only the selected worlds.

    With ``runs`` set, the batch is ``[runs, num_worlds]`` (``runs × num_worlds`` worlds): the
    layout of independent learners trained side by side, each run drawing its release jitter
    from its own stream (:class:`~sde_torchrl.rng.RunStreams`, seeded by :meth:`set_seed`).

    Args:
        num_worlds: number of worlds N (one pybullet DIRECT client each), per run if ``runs``.
        config: physical parameters shared by all worlds, the arm model among them (default
            :class:`BallCatchConfig`: model "cup").
        max_steps: episode length (the paper's 500).
        seed: seed of the env's private generator for the ball's release jitter.
        device: torch device of the returned tensors (physics always runs on the CPU).
        runs: number of independent runs (leading batch dimension), or ``None``.
        first_run: global index of the first run (seeding shards of a sweep).
        stream: random stream name for the runs (``"env"`` or ``"eval_env"``).

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
    ) -> None:
        if num_worlds < 1:
            raise ValueError(f"num_worlds must be >= 1, got {num_worlds}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if runs is not None and runs < 1:
            raise ValueError(f"runs must be >= 1, got {runs}")
        batch = (num_worlds,) if runs is None else (runs, num_worlds)
        super().__init__(device=device, batch_size=torch.Size(batch))
        self.config = config or BallCatchConfig()
        self.num_worlds = num_worlds * (runs or 1)  # worlds in all, stored flat
        num_worlds = self.num_worlds
        self.max_steps = max_steps
        self.runs, self.first_run, self.stream = runs, first_run, stream
        self._set_seed(seed)
        self._torque_scale = np.asarray(self.config.max_torques, dtype=np.float64)
        self._transmission = self.config.arm.transmission
        self._ground_z = self.config.arm.ground_z
        self._t = np.zeros(num_worlds, dtype=np.int64)
        self._grounded = np.zeros(num_worlds, dtype=bool)
        self._ball = np.zeros((num_worlds, 3), dtype=np.float64)
        self._palm = np.zeros((num_worlds, 3), dtype=np.float64)
        self.worlds: list[BallCatchWorld] = []
        try:
            for i in range(num_worlds):
                self.worlds.append(BallCatchWorld(self.config, name=f"world {i}"))
        except Exception:
            self._close_worlds()
            raise
        self._make_specs()

    # ------------------------------------------------------------------ specs
    def _make_specs(self) -> None:
        n = tuple(self.batch_size)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*n, 3), dtype=torch.float32, device=self.device),
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
        for i in np.flatnonzero(mask):
            world = self.worlds[i]
            world.reset(offsets[i])
            self._ball[i] = world.ball_position()
            self._palm[i] = world.palm_position()
        self._t[mask] = 0
        self._grounded[mask] = False
        distance = np.linalg.norm(self._ball - self._palm, axis=1)
        truncated = self._t >= self.max_steps
        return self._pack(distance, truncated)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Apply the ``[N, 4]`` action in every world, step once, observe and score."""
        distance, reward = self._advance(tensordict.get("action"))
        return self._pack(distance, self._t >= self.max_steps, reward)

    def _advance(self, action: torch.Tensor | None) -> tuple[np.ndarray, np.ndarray]:
        """One physics step of every world under ``action``: distances and rewards ``[N]``.

        Worlds whose ball has touched the ground are frozen (absorbing state, reward -3): they
        are not stepped and keep their last positions.
        """
        scaled = self._scaled_action(action)
        live = np.flatnonzero(~self._grounded)
        if len(live):
            worlds = self.worlds
            forces = joint_torques(scaled[live], self._transmission).tolist()
            observed = [worlds[i].step_and_observe(f) for i, f in zip(live.tolist(), forces, strict=True)]
            self._ball[live] = [o[0] for o in observed]
            self._palm[live] = [o[1] for o in observed]
        ball, palm = self._ball, self._palm
        self._t += 1
        self._grounded |= ball[:, 2] < self._ground_z
        distance = np.sqrt(((ball - palm) ** 2).sum(axis=1))
        reward = np.where(self._grounded, GROUND_REWARD, -np.minimum(np.maximum(distance, MIN_DISTANCE), DISTANCE_CAP))
        return distance, reward

    # ---------------------------------------------- tensor stepping (sde_torchrl.rollout)
    def initial_state(self) -> torch.Tensor:
        """Resets every world; returns the ball positions ``[N, 3]`` (the observation)."""
        return self._reset(None)["observation"]

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Steps every world under ``u`` (``x``, the current observation, lives in the worlds).

        Returns:
            Ball positions ``[N, 3]`` and rewards ``[N, 1]``, as :meth:`_step` computes them.
        """
        _, reward = self._advance(u)
        batch = tuple(self.batch_size)
        return (torch.from_numpy(self._ball.astype(np.float32)).reshape(*batch, 3),
                torch.from_numpy(reward.astype(np.float32)).reshape(*batch, 1))

    # ----------------------------------- whole episodes of fixed linear controllers (fast path)
    def linear_episodes(self, matrices: torch.Tensor, steps: int, squash: bool = True) -> tuple[torch.Tensor, ...]:
        """Fresh episodes of every world under a fixed linear controller ``u = M x`` each.

        SDE with its episode schedule makes the exploratory policy one linear map of the
        observation for a whole episode (``Θ + Θ̂``, eqs. 17-19), and the deterministic policy
        is ``Θ`` itself. Such a controller needs no batched policy call per step, so each world
        runs its whole episode on its own, while its physics state stays in the CPU cache
        (stepping N worlds in turn evicts it at every step). Physics, release jitter, reward
        and grounding are those of :meth:`_step`; the controller works in float64 where the
        step-by-step path rounds the observation and action to float32 (differences ~1e-7).

        Args:
            matrices: ``M``, shaped ``[*batch_size, 4, 3]``.
            steps: episode length.
            squash: apply ``tanh`` to ``u`` (else ``u`` is clipped to ``[-1, 1]`` like any action).

        Returns:
            ``(observations [*batch, steps + 1, 3], samples [*batch, steps, 4], rewards
            [*batch, steps, 1])``: the ball positions from the reset on, the pre-squash ``u``
            and the rewards, float32.

        Raises:
            ValueError: for matrices of the wrong shape or with non-finite entries, or
                ``steps < 1``.
        """
        if steps < 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        batch = tuple(self.batch_size)
        if tuple(matrices.shape) != (*batch, 4, 3):
            raise ValueError(f"matrices must have shape {(*batch, 4, 3)}, got {tuple(matrices.shape)}")
        flat = matrices.detach().cpu().double().reshape(-1, 4, 3).numpy()
        finite = np.isfinite(flat).all(axis=(1, 2))
        if not finite.all():
            bad = np.flatnonzero(~finite).tolist()
            raise ValueError(f"controller matrices contain non-finite values in worlds {bad}")
        offsets, scale = self._jitter(), self._torque_scale.tolist()
        episodes = []
        for i, world in enumerate(self.worlds):
            world.reset(offsets[i])
            episodes.append(
                _linear_episode(world, flat[i].tolist(), scale, squash, steps, self._transmission, self._ground_z)
            )
            observations, _, _, self._palm[i], self._grounded[i] = episodes[-1]
            self._ball[i] = observations[-1]
        self._t[:] = steps
        observations, samples, rewards = (torch.tensor([e[k] for e in episodes], dtype=torch.float64) for k in range(3))
        return (observations.float().reshape(*batch, steps + 1, 3), samples.float().reshape(*batch, steps, 4),
                rewards.float().reshape(*batch, steps, 1))

    # ------------------------------------------------------------------ helpers
    def _reset_mask(self, tensordict: TensorDictBase | None) -> np.ndarray:
        """Boolean ``[N]`` mask of the worlds to reset (all if no ``"_reset"`` entry)."""
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None:
            return np.ones(self.num_worlds, dtype=bool)
        return reset.reshape(self.num_worlds, -1).any(-1).cpu().numpy()

    def _scaled_action(self, action: torch.Tensor | None) -> np.ndarray:
        """Validate the ``[N, 4]`` action; the actuator torques ``clip(action) * max_torques``."""
        if action is None:
            raise ValueError("the input tensordict has no 'action' entry")
        if tuple(action.shape) != (*self.batch_size, 4):
            raise ValueError(f"action must have shape {(*self.batch_size, 4)}, got {tuple(action.shape)}")
        a = action.detach().cpu().reshape(-1, 4).numpy().astype(np.float64)  # numpy: far cheaper than torch ops here
        finite = np.isfinite(a).all(axis=-1)
        if not finite.all():
            raise ValueError(f"action contains non-finite values in worlds {np.flatnonzero(~finite).tolist()}")
        return np.minimum(np.maximum(a, -1.0), 1.0) * self._torque_scale

    def _pack(self, distance: np.ndarray, truncated: np.ndarray, reward: np.ndarray | None = None) -> TensorDict:
        """Observations, done flags (never terminated) and, after a step, rewards as a ``[N]`` TensorDict."""
        batch = tuple(self.batch_size)
        trunc = torch.from_numpy(truncated).reshape(*batch, 1)
        data = {
            "observation": torch.from_numpy(self._ball.astype(np.float32)).reshape(*batch, 3),
            "distance": torch.from_numpy(distance.astype(np.float32)).reshape(*batch, 1),
            "done": trunc,
            "terminated": torch.zeros_like(trunc),
            "truncated": trunc.clone(),
        }
        if reward is not None:
            data["reward"] = torch.from_numpy(reward.astype(np.float32)).reshape(*batch, 1)
        return TensorDict(data, batch_size=self.batch_size, device=self.device)

    def _close_worlds(self) -> None:
        for world in self.worlds:
            world.close()

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Disconnect every physics client."""
        self._close_worlds()
        super().close(raise_if_closed=raise_if_closed)


def _linear_episode(
    world: BallCatchWorld, matrix: list[list[float]], torque_scale: list[float], squash: bool, steps: int,
    transmission: tuple[tuple[int, float], ...], ground_z: float,
) -> tuple[list, list, list, tuple[float, ...], bool]:
    """One episode of a freshly reset ``world`` under ``u = M x`` (the hot loop of
    :meth:`BatchedBallCatchEnv.linear_episodes`, in plain Python floats: numpy is slower on
    3-vectors). A world whose ball touched the ground (centre below ``ground_z``) is frozen, as
    in :meth:`BatchedBallCatchEnv._advance`; ``transmission`` maps the actuator torques to the
    joints (:attr:`~sde_torchrl.envs.ballcatch.ArmModel.transmission`).

    Returns:
        The ball positions (``steps + 1``), the pre-squash ``u`` and the rewards (``steps``
        each) as lists, the last palm position and whether the ball is on the ground.
    """
    ball, palm = world.ball_position(), world.palm_position()
    observations, samples, rewards = [ball], [], []
    grounded = False
    (m0, m1, m2, m3) = matrix
    # tanh's values lie in [-1, 1] already: the clip of any action is needed without it.
    action = math.tanh if squash else (lambda v: min(max(v, -1.0), 1.0))
    for _ in range(steps):
        x0, x1, x2 = ball
        u = (m0[0] * x0 + m0[1] * x1 + m0[2] * x2, m1[0] * x0 + m1[1] * x1 + m1[2] * x2,
             m2[0] * x0 + m2[1] * x1 + m2[2] * x2, m3[0] * x0 + m3[1] * x1 + m3[2] * x2)
        samples.append(u)
        if not grounded:
            scaled = [action(v) * s for v, s in zip(u, torque_scale, strict=True)]
            ball, palm = world.step_and_observe([scaled[a] * g for a, g in transmission])
            grounded = ball[2] < ground_z
        observations.append(ball)
        rewards.append(step_reward(ball, palm, grounded)[0])
    return observations, samples, rewards, palm, grounded


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
    episode_length: int = EPISODE_STEPS, jitter: float = 0.05, seed: int | None = None, model: str = "cup",
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
        model: the arm, ``"cup"`` or ``"pybrain"`` (:data:`~sde_torchrl.envs.ballcatch.ARM_MODELS`).

    Returns:
        ``TransformedEnv(BatchedBallCatchEnv(...), InitTracker())``.
    """
    base = BatchedBallCatchEnv(
        num_worlds=episodes, config=BallCatchConfig(jitter=jitter, model=model), max_steps=episode_length,
        seed=seed, runs=runs, first_run=first_run, stream=stream,
    )
    return TransformedEnv(base, InitTracker())
