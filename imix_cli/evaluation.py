"""Batched episode evaluation of MLP policies (one flat parameter vector per member).

Usage::

    ev = make_evaluator("cartpole")            # built once per process and environment
    returns, steps = ev.evaluate(params, seeds)  # params (B, ev.num_params), seeds (B,) ints >= 0

``returns`` (B,) float64 is the undiscounted sum of rewards of one episode per member and
``steps`` (B,) int64 its length. Member i's episode depends only on ``params[i]`` and
``seeds[i]``: it is identical whether the member is evaluated alone or in any batch, and on
every call with the same seed. The seed plays the role of gymnasium's ``reset(seed=...)``:
the episode starts from the same state as ``gym.make(id).reset(seed=seeds[i])``.

Environments (``env_name``):

* ``"cartpole"``: CartPole-v0 semantics (CartPole-v1 dynamics, episodes capped at 200
  steps, reward 1 per step, so return == steps);
* ``"acrobot"``: Acrobot-v1 dynamics capped at 200 steps as in the paper (reward -1 per
  step, 0 on the terminating step, as gymnasium);
* ``"continuous_cartpole"`` / ``"continuous_cartpole_hard"``: ``imix/ContinuousCartPole-v0``
  and ``imix/ContinuousCartPoleHard-v0`` (paper section 4.3: CartPole with a force of
  10 N x a, a in [-1, 1]; the Hard one pays the episode's total on its last step only), 200
  steps, one tanh-bounded output. The returns equal the registered envs' and, for both
  variants, the episode length.

  These four run whole episodes, policy and dynamics together, in numba-compiled kernels
  (:mod:`imix_cli.envs.kernels`: gymnasium's arithmetic, operation for operation; a batch of
  2 costs what its steps cost). The first call in a fresh install compiles them (seconds,
  once: the machine code is cached on disk);
* any other registered gymnasium id (e.g. ``"MountainCar-v0"``, ``"Pendulum-v1"``): a
  ``gymnasium.make_vec(id, num_envs=B, vectorization_mode="sync")`` reset with
  ``seed=[seeds...]``. Slower, but any env with a Box observation space and a Discrete or
  Box action space. The env's own time limit applies unless ``max_steps`` is given (then it
  replaces it); an env without a time limit needs ``max_steps``.

Policies (:mod:`imix_cli.policies`): MLP obs -> 8 -> 8 -> out with tanh hidden units.
Discrete actions: ``start + argmax`` of the outputs. Box actions: ``tanh`` of the outputs
mapped affinely onto ``[low, high]`` (``high * tanh`` for symmetric bounds, so ``[-1, 1]``
is plain ``tanh``); the bounds must be finite.

On the generic path all members roll out as one batch: every live env is stepped together,
finished members are masked (their later data is ignored).
"""

from __future__ import annotations

from collections import OrderedDict

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from imix_cli.policies import HIDDEN, BatchPolicy, num_params

__all__ = ["BatchEvaluator", "make_evaluator", "CARTPOLE_MAX_STEPS", "ACROBOT_MAX_STEPS", "CONTINUOUS_ENVS"]

CARTPOLE_MAX_STEPS = 200  # CartPole-v0 (reward threshold 195)
ACROBOT_MAX_STEPS = 200  # the paper's cap (Acrobot-v1 itself allows 500)
#: Built-in continuous-action environments: evaluator name -> sparse (Hard) reward or not.
CONTINUOUS_ENVS = {"continuous_cartpole": False, "continuous_cartpole_hard": True}


class BatchEvaluator:
    """Evaluates B policies for one episode each on one environment. See the module docstring.

    Attributes: ``env_name``, ``obs_dim``, ``out_dim`` (policy outputs), ``num_params``,
    ``discrete``, ``max_steps``, ``hidden``.
    """

    env_name: str
    obs_dim: int
    out_dim: int
    discrete: bool
    max_steps: int
    hidden: tuple[int, ...] = HIDDEN

    @property
    def num_params(self) -> int:
        return num_params(self.obs_dim, self.out_dim, self.hidden)

    def policy(self, params: np.ndarray) -> BatchPolicy:
        """The batched policy of ``params`` (B, num_params) for this environment."""
        return BatchPolicy(params, self.obs_dim, self.out_dim, discrete=self.discrete, hidden=self.hidden)

    def evaluate(self, params: np.ndarray, episode_seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One episode per member: ``(returns (B,) float64, steps (B,) int64)``."""
        params, seeds = self._checked(params, episode_seeds)
        if params.shape[0] == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        return self._evaluate_checked(params, seeds)

    def _checked(self, params, episode_seeds) -> tuple[np.ndarray, np.ndarray]:
        """``(params (B, num_params) float64, seeds (B,))``, or ``ValueError`` naming what is wrong."""
        params = np.asarray(params, dtype=np.float64)
        if params.ndim == 1:
            params = params[None, :]
        if params.ndim != 2 or params.shape[1] != self.num_params:
            raise ValueError(f"{self.env_name}: params must have shape (B, {self.num_params}), got {params.shape}")
        seeds = np.asarray(episode_seeds).reshape(-1)
        if seeds.shape[0] != params.shape[0]:
            raise ValueError(f"{self.env_name}: {params.shape[0]} members but {seeds.shape[0]} episode seeds")
        if seeds.size and (seeds.dtype.kind not in "iu" or seeds.min() < 0):
            raise ValueError(f"{self.env_name}: episode seeds must be non-negative integers")
        return params, seeds

    def _evaluate_checked(self, params: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._run(self.policy(params), seeds)

    def _run(self, policy: BatchPolicy, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.env_name!r}, obs_dim={self.obs_dim}, out_dim={self.out_dim}, "
            f"num_params={self.num_params}, discrete={self.discrete}, max_steps={self.max_steps})"
        )


class _CompiledEvaluator(BatchEvaluator):
    """A built-in environment: whole episodes, policy included, in a compiled kernel
    (:mod:`imix_cli.envs.kernels`), one member after the other."""

    def __init__(self, env_name: str, obs_dim: int, out_dim: int, discrete: bool, max_steps: int):
        self.env_name, self.obs_dim, self.out_dim, self.discrete = env_name, obs_dim, out_dim, discrete
        self.max_steps = int(max_steps)
        if self.max_steps < 1:
            raise ValueError(f"{env_name}: max_steps must be >= 1, got {max_steps}")
        from imix_cli.envs import kernels  # numba: loaded (and compiled on first use) only here

        self._kernels = kernels
        self._no_trace = np.empty((0, 0, 0))

    def _sizes(self) -> np.ndarray:
        return np.array([self.obs_dim, *self.hidden, self.out_dim], dtype=np.int64)

    def _evaluate_checked(self, params, seeds):
        n = params.shape[0]
        returns, steps = np.empty(n), np.empty(n, dtype=np.int64)
        self._episodes(np.ascontiguousarray(params), seeds.astype(np.uint64), returns, steps, self._no_trace)
        return returns, steps

    def trajectories(self, params: np.ndarray, episode_seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``evaluate`` that also returns every member's states: (returns, steps, states
        (B, max_steps + 1, 4) float64, row t = the state after t steps; rows after the end: NaN)."""
        params, seeds = self._checked(params, episode_seeds)
        n = params.shape[0]
        returns, steps = np.empty(n), np.empty(n, dtype=np.int64)
        trace = np.full((n, self.max_steps + 1, 4), np.nan)
        if n:
            self._episodes(np.ascontiguousarray(params), seeds.astype(np.uint64), returns, steps, trace)
        return returns, steps, trace

    def _episodes(self, params, seeds, returns, steps, trace) -> None:
        raise NotImplementedError


class CartPoleEvaluator(_CompiledEvaluator):
    """CartPole-v0 semantics: CartPole-v1 dynamics (``CartPoleEnv.step``, compiled), 200 steps."""

    def __init__(self, max_steps: int | None = None):
        max_steps = CARTPOLE_MAX_STEPS if max_steps is None else int(max_steps)
        super().__init__("cartpole", 4, 2, True, max_steps)

    def _episodes(self, params, seeds, returns, steps, trace):
        self._kernels.cartpole_episodes(params, seeds, self._sizes(), False, False, self.max_steps, returns, steps, trace)


class AcrobotEvaluator(_CompiledEvaluator):
    """Acrobot-v1 dynamics (``AcrobotEnv``'s rk4, compiled), capped at 200 steps by default."""

    def __init__(self, max_steps: int | None = None):
        max_steps = ACROBOT_MAX_STEPS if max_steps is None else int(max_steps)
        super().__init__("acrobot", 6, 3, True, max_steps)

    def _episodes(self, params, seeds, returns, steps, trace):
        # gymnasium's reset(seed=s): a float32 state and its observation computed in float32
        # by numpy's cos/sin (not libm's, hence here rather than in the kernel)
        s32 = self._kernels.seeded_uniform_rows(seeds, -0.1, 0.1, 4).astype(np.float32)
        obs0 = np.empty((len(s32), 6))
        obs0[:, 0:4:2] = np.cos(s32[:, :2])
        obs0[:, 1:4:2] = np.sin(s32[:, :2])
        obs0[:, 4:] = s32[:, 2:]
        self._kernels.acrobot_episodes(
            params, s32.astype(np.float64), obs0, self._sizes(), self.max_steps, returns, steps, trace
        )


class ContinuousCartPoleEvaluator(_CompiledEvaluator):
    """``imix/ContinuousCartPole(Hard)-v0`` (compiled): one output squashed by ``tanh`` into
    the action range [-1, 1], force 10 N x a; the Hard variant's sparse reward gives the same return."""

    def __init__(self, hard: bool = False, max_steps: int | None = None):
        max_steps = CARTPOLE_MAX_STEPS if max_steps is None else int(max_steps)
        name = "continuous_cartpole_hard" if hard else "continuous_cartpole"
        super().__init__(name, 4, 1, False, max_steps)
        self.hard = bool(hard)

    def _episodes(self, params, seeds, returns, steps, trace):
        self._kernels.cartpole_episodes(params, seeds, self._sizes(), True, self.hard, self.max_steps, returns, steps, trace)


class GymEvaluator(BatchEvaluator):
    """Any registered gymnasium id, through ``make_vec(..., vectorization_mode="sync")``."""

    cache_size = 2  # vector envs kept per batch size

    def __init__(self, env_id: str, max_steps: int | None = None):
        self.env_name = env_id
        spec = gym.spec(env_id)
        limit = spec.max_episode_steps if max_steps is None else int(max_steps)
        if limit is None:
            raise ValueError(f"gymnasium env {env_id!r} has no time limit: pass max_steps")
        self.max_steps = int(limit)
        self._make_kwargs = {} if max_steps is None else {"max_episode_steps": self.max_steps}
        probe = gym.make(env_id, **self._make_kwargs)
        try:
            obs_space, act_space = probe.observation_space, probe.action_space
        finally:
            probe.close()
        if not isinstance(obs_space, spaces.Box):
            raise ValueError(f"gymnasium env {env_id!r}: unsupported observation space {obs_space} (need a Box)")
        self.obs_dim = int(np.prod(obs_space.shape))
        self._low = self._high = None
        if isinstance(act_space, spaces.Discrete):
            self.discrete, self.out_dim = True, int(act_space.n)
            self._start = int(act_space.start)
        elif isinstance(act_space, spaces.Box):
            self.discrete, self.out_dim = False, int(np.prod(act_space.shape))
            self._low = act_space.low.astype(np.float64).reshape(-1)
            self._high = act_space.high.astype(np.float64).reshape(-1)
            if not (np.all(np.isfinite(self._low)) and np.all(np.isfinite(self._high))):
                raise ValueError(f"gymnasium env {env_id!r}: Box actions need finite bounds, got {act_space}")
        else:
            raise ValueError(f"gymnasium env {env_id!r}: unsupported action space {act_space}")
        self._act_space = act_space
        self._venvs: OrderedDict[int, gym.vector.VectorEnv] = OrderedDict()

    def policy(self, params):
        return BatchPolicy(
            params, self.obs_dim, self.out_dim, discrete=self.discrete, hidden=self.hidden, low=self._low, high=self._high
        )

    def _venv(self, n: int):
        venv = self._venvs.pop(n, None)
        if venv is None:
            venv = gym.make_vec(self.env_name, num_envs=n, vectorization_mode="sync", **self._make_kwargs)
        self._venvs[n] = venv
        while len(self._venvs) > self.cache_size:
            self._venvs.popitem(last=False)[1].close()
        return venv

    def _run(self, policy, seeds):
        n = len(seeds)
        venv = self._venv(n)
        obs, _ = venv.reset(seed=[int(s) for s in seeds])
        ret, length = np.zeros(n), np.zeros(n, dtype=np.int64)
        alive = np.ones(n, dtype=bool)
        for _ in range(self.max_steps):
            a = policy(np.asarray(obs, dtype=np.float64).reshape(n, -1))
            if self.discrete:
                a = a + self._start if self._start else a
            else:
                a = a.reshape((n, *self._act_space.shape)).astype(self._act_space.dtype)
            obs, reward, terminated, truncated, _ = venv.step(a)
            np.add(ret, reward, out=ret, where=alive)
            np.add(length, alive, out=length)
            alive &= ~(terminated | truncated)
            if not alive.any():
                break
        return ret, length


def make_evaluator(env_name: str, max_steps: int | None = None) -> BatchEvaluator:
    """Evaluator for ``"cartpole"``, ``"acrobot"``, ``"continuous_cartpole"``,
    ``"continuous_cartpole_hard"`` or a gymnasium id (see the module docstring).

    Raises ``ValueError`` for an unknown environment id.
    """
    key = str(env_name).lower()
    if key == "cartpole":
        return CartPoleEvaluator(max_steps)
    if key == "acrobot":
        return AcrobotEvaluator(max_steps)
    if key in CONTINUOUS_ENVS:
        return ContinuousCartPoleEvaluator(CONTINUOUS_ENVS[key], max_steps)
    try:
        gym.spec(env_name)
    except (gym.error.UnregisteredEnv, gym.error.DeprecatedEnv, gym.error.RegistrationError) as err:
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(
            f"unknown environment {env_name!r}: not 'cartpole', 'acrobot', 'continuous_cartpole', "
            f"'continuous_cartpole_hard' or a registered gymnasium id ({msg})"
        ) from None
    return GymEvaluator(env_name, max_steps)
