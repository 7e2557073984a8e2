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
  (:mod:`imix_cli.core.envs.kernels`: gymnasium's arithmetic, operation for operation; a batch of
  2 costs what its steps cost). The first call in a fresh install compiles them (seconds,
  once: the machine code is cached on disk);
* any other registered gymnasium id (e.g. ``"MountainCar-v0"``, ``"Pendulum-v1"``,
  ``"Hopper-v5"``): one ``gymnasium.make(id)`` env per member, reset with
  ``reset(seed=seeds[i])`` (as ``make_vec`` with a list of seeds) and stepped until its
  episode ends (finished members are not stepped on). Slower, but any env with a Box
  observation space and a Discrete or Box action space. The env's own time limit applies
  unless ``max_steps`` is given (then it replaces it); an env without a time limit needs
  ``max_steps``. MuJoCo ids need the ``mujoco`` extra (:func:`missing_extra_message`);
* ``"Swimmer-v5"``, ``"Hopper-v5"``, ``"HalfCheetah-v5"``, ``"Walker2d-v5"``, ``"Ant-v5"``: the
  same episodes, bit for bit, without gymnasium (:class:`MujocoDirectEvaluator`, on the
  ``mujoco`` bindings directly), unless ``backend="gymnasium"`` or ``IMIX_MUJOCO_BACKEND=gymnasium``.

Policies (:mod:`imix_cli.core.evaluation.policies`): MLP obs -> 8 -> 8 -> out with tanh hidden units by
default; ``make_evaluator(..., hidden=(64, 64))`` or ``hidden=()`` (linear) for others.
Discrete actions: ``start + argmax`` of the outputs. Box actions: ``tanh`` of the outputs
mapped affinely onto ``[low, high]`` (``high * tanh`` for symmetric bounds, so ``[-1, 1]``
is plain ``tanh``); the bounds must be finite.

On the generic path all members roll out as one batch: every live env is stepped together,
finished members are masked (their later data is ignored).
"""

from __future__ import annotations

import os
import warnings

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import imix_cli.core.envs  # noqa: F401  (registers the imix/ gymnasium ids, in spawned workers too)
from imix_cli.core.envs.mujoco_direct import DIRECT_ENV_IDS  # imports no mujoco
from imix_cli.core.evaluation.policies import HIDDEN, OUTPUTS, BatchPolicy, num_params
from imix_cli.core.registry import BUILTIN_ENVS, ENV_SPECS

__all__ = [
    "BatchEvaluator", "make_evaluator", "MujocoDirectEvaluator", "mujoco_backend", "missing_extra_message", "MUJOCO_EXTRA_HINT",
    "CARTPOLE_MAX_STEPS", "ACROBOT_MAX_STEPS",
]  # fmt: skip

CARTPOLE_MAX_STEPS = ENV_SPECS["cartpole"].max_steps  # CartPole-v0 (reward threshold 195)
ACROBOT_MAX_STEPS = ENV_SPECS["acrobot"].max_steps  # the paper's cap (Acrobot-v1 itself allows 500)


class BatchEvaluator:
    """Evaluates B policies for one episode each on one environment. See the module docstring.

    Attributes: ``env_name``, ``obs_dim``, ``out_dim`` (policy outputs), ``num_params``,
    ``discrete``, ``max_steps``, ``hidden``, ``output`` (continuous actions: ``"tanh"`` or ``"clip"``,
    :mod:`imix_cli.core.evaluation.policies`).
    """

    env_name: str
    obs_dim: int
    out_dim: int
    discrete: bool
    max_steps: int
    hidden: tuple[int, ...] = HIDDEN
    output: str = "tanh"

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

    def _roll_out(self, policy: BatchPolicy, obs: np.ndarray, step) -> tuple[np.ndarray, np.ndarray]:
        """Every member's episode from its first observation ``obs`` (B, obs_dim), all live members stepped
        together until each ends or ``max_steps``: ``(returns, steps)``; the per-member sums of the
        observations seen go to ``self.last_obs_stats`` (``policy.obs_norm``'s warm-up).

        ``step(live, members, actions, ret, length, alive, obs)`` steps the members ``members`` (held by
        the policy slots ``live``) with their slots' ``actions``, adds each reward and step to ``ret`` and
        ``length`` (by member), clears ``alive`` of the slots whose episode ended and writes the others'
        new observations into ``obs`` (by slot). Once half the slots are done, finished members leave the
        policy batch."""
        n = obs.shape[0]
        ret, length = np.zeros(n), np.zeros(n, dtype=np.int64)
        sums, sumsqs = np.zeros((n, self.obs_dim)), np.zeros((n, self.obs_dim))
        idx = np.arange(n)  # member held by each policy slot
        alive = np.ones(n, dtype=bool)
        for _ in range(self.max_steps):
            actions = policy(obs)
            live = np.flatnonzero(alive)
            members = idx[live]
            sums[members] += obs[live]
            sumsqs[members] += obs[live] * obs[live]
            step(live, members, actions, ret, length, alive, obs)
            n_alive = np.count_nonzero(alive)
            if n_alive == 0:
                break
            if n_alive <= alive.size // 2:  # drop finished members from the policy batch
                rows = np.flatnonzero(alive)
                idx, obs, alive = idx[rows], obs[rows], alive[rows]
                policy.select(rows)
        self.last_obs_stats = (sums, sumsqs)
        return ret, length

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.env_name!r}, obs_dim={self.obs_dim}, out_dim={self.out_dim}, "
            f"num_params={self.num_params}, discrete={self.discrete}, max_steps={self.max_steps})"
        )


class _CompiledEvaluator(BatchEvaluator):
    """A built-in environment: whole episodes, policy included, in a compiled kernel
    (:mod:`imix_cli.core.envs.kernels`), one member after the other. Its sizes and default episode
    cap are those of its record in :data:`imix_cli.core.registry.ENV_SPECS`."""

    def __init__(self, env_name: str, max_steps: int | None):
        spec = ENV_SPECS[env_name]
        self.env_name, (self.obs_dim, self.out_dim), self.discrete = env_name, spec.policy_dims, not spec.continuous
        self.max_steps = spec.max_steps if max_steps is None else int(max_steps)
        if self.max_steps < 1:
            raise ValueError(f"{env_name}: max_steps must be >= 1, got {max_steps}")
        from imix_cli.core.envs import kernels  # numba: loaded (and compiled on first use) only here

        self._kernels = kernels
        self._no_trace = np.empty((0, 0, 0))

    def layer_sizes(self) -> np.ndarray:
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
        super().__init__("cartpole", max_steps)

    def _episodes(self, params, seeds, returns, steps, trace):
        self._kernels.cartpole_episodes(params, seeds, self.layer_sizes(), False, False, self.max_steps, returns, steps, trace)


class AcrobotEvaluator(_CompiledEvaluator):
    """Acrobot-v1 dynamics (``AcrobotEnv``'s rk4, compiled), capped at 200 steps by default."""

    def __init__(self, max_steps: int | None = None):
        super().__init__("acrobot", max_steps)

    def _episodes(self, params, seeds, returns, steps, trace):
        # gymnasium's reset(seed=s): a float32 state and its observation computed in float32 (the
        # float32 cos/sin of numpy's vector kernel, which numpy runs on CPUs with FMA3 only: imix_cli.core.numerics.elementary)
        self._kernels.acrobot_seeded_episodes(params, seeds, self.layer_sizes(), self.max_steps, returns, steps, trace)


class ContinuousCartPoleEvaluator(_CompiledEvaluator):
    """``imix/ContinuousCartPole(Hard)-v0`` (compiled): one output squashed by ``tanh`` into
    the action range [-1, 1], force 10 N x a; the Hard variant's sparse reward gives the same return."""

    def __init__(self, hard: bool = False, max_steps: int | None = None):
        super().__init__("continuous_cartpole_hard" if hard else "continuous_cartpole", max_steps)
        self.hard = bool(hard)

    def _episodes(self, params, seeds, returns, steps, trace):
        self._kernels.cartpole_episodes(params, seeds, self.layer_sizes(), True, self.hard, self.max_steps, returns, steps, trace)


#: The built-ins' compiled evaluators, ``env name -> (max_steps -> evaluator)``: one entry per
#: :data:`imix_cli.core.registry.BUILTIN_ENVS` name (tests/test_registry.py checks the two agree).
BUILTIN_EVALUATORS = {
    "cartpole": CartPoleEvaluator,
    "acrobot": AcrobotEvaluator,
    "continuous_cartpole": lambda max_steps: ContinuousCartPoleEvaluator(False, max_steps),
    "continuous_cartpole_hard": lambda max_steps: ContinuousCartPoleEvaluator(True, max_steps),
}


class UserEnvError(RuntimeError):
    """An env raised, or broke gymnasium's contract (an observation of the wrong shape, a reward that is no number):
    carries the env id and the first line of what it said, for the one line a command ends with
    (:mod:`imix_cli.commands.boundary`). Picklable: it crosses from worker processes."""

    def __init__(self, env_id: str, message: str) -> None:
        super().__init__(env_id, message)
        self.env_id, self.message = env_id, message

    def __str__(self) -> str:
        return f"env {self.env_id!r} failed: {self.message}"

    @classmethod
    def wrap(cls, env_id: str, where: str, err: BaseException) -> UserEnvError:
        text = str(err).strip()
        return cls(env_id, f"{where}: {type(err).__name__}: {text.splitlines()[0] if text else ''}".rstrip(": "))


class GymEvaluator(BatchEvaluator):
    """Any registered gymnasium id, one ``gym.make`` env per member, stepped while it is alive.

    Each member's env is reset with ``reset(seed=seeds[i])`` (what ``make_vec`` does with a
    list of seeds) and stepped only until its episode ends: no autoreset, no stepping of
    finished members, which matters where episodes end at very different times (Hopper,
    Walker2d). Envs are made once and kept (as many as the largest batch seen).

    After every :meth:`evaluate`, :attr:`last_obs_stats` holds ``(sums, sumsqs)`` (B, obs_dim):
    per member, the sum and sum of squares of the observations its policy acted on (``steps[i]``
    of them), for :class:`imix_cli.core.evaluation.policies.ObsNormalizer`.
    """

    def __init__(self, env_id: str, max_steps: int | None = None, hidden=HIDDEN, output: str = "tanh", env_kwargs=None):
        self.env_name = env_id
        self.hidden, self.output = tuple(int(h) for h in hidden), output
        spec = gym.spec(env_id)
        limit = spec.max_episode_steps if max_steps is None else int(max_steps)
        if limit is None:
            raise ValueError(f"gymnasium env {env_id!r} has no time limit: pass max_steps")
        self.max_steps = int(limit)
        # env_kwargs: the env's constructor arguments (gym.make(id, continuous=True)), checked by the caller
        self._make_kwargs = {**dict(env_kwargs or {}), **({} if max_steps is None else {"max_episode_steps": self.max_steps})}
        message = missing_extra_message(env_id)
        if message:
            raise ValueError(message)
        probe = self._make()
        obs_space, act_space = probe.observation_space, probe.action_space
        if not isinstance(obs_space, spaces.Box):
            probe.close()
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
                probe.close()
                raise ValueError(f"gymnasium env {env_id!r}: Box actions need finite bounds, got {act_space}")
        else:
            probe.close()
            raise ValueError(f"gymnasium env {env_id!r}: unsupported action space {act_space}")
        self._act_space = act_space
        self._envs: list = [probe]  # the probe is the first member's env
        self.last_obs_stats: tuple[np.ndarray, np.ndarray] | None = None

    def policy(self, params):
        return BatchPolicy(params, self.obs_dim, self.out_dim, discrete=self.discrete, hidden=self.hidden, low=self._low, high=self._high, output=self.output)

    def _make(self):
        try:
            return gym.make(self.env_name, **self._make_kwargs)
        except Exception as err:  # noqa: BLE001 - the user's code: any exception, named with the env
            raise UserEnvError.wrap(self.env_name, "gym.make", err) from err

    def _env_list(self, n: int) -> list:
        while len(self._envs) < n:
            self._envs.append(self._make())
        return self._envs[:n]

    def close(self) -> None:
        for env in self._envs:
            env.close()
        self._envs = []

    def _run(self, policy, seeds):
        envs = self._env_list(len(seeds))
        obs = np.empty((len(seeds), self.obs_dim))
        for i, env in enumerate(envs):
            obs[i] = self._observation(self._call(env.reset, "reset", seed=int(seeds[i]))[0], "reset")
        shape, dtype = self._act_space.shape, self._act_space.dtype

        def step(live, members, actions, ret, length, alive, obs):
            for j, i in zip(live, members):
                a = actions[j] + self._start if self.discrete else actions[j].reshape(shape).astype(dtype)
                o, reward, terminated, truncated, _ = self._call(envs[i].step, "step", a)
                ret[i] += self._reward(reward)
                length[i] += 1
                if terminated or truncated:
                    alive[j] = False
                else:
                    obs[j] = self._observation(o, "step")

        return self._roll_out(policy, obs, step)

    def _call(self, method, where: str, *args, **kwargs):
        """``env.reset`` / ``env.step``: whatever the user's env raises comes out as a :class:`UserEnvError` naming it."""
        try:
            return method(*args, **kwargs)
        except Exception as err:  # noqa: BLE001 - the user's code
            raise UserEnvError.wrap(self.env_name, where, err) from err

    def _observation(self, o, where: str) -> np.ndarray:
        try:
            flat = np.asarray(o, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as err:
            raise UserEnvError.wrap(self.env_name, f"{where} returned an observation that is not numbers", err) from None
        if flat.size != self.obs_dim:
            raise UserEnvError(self.env_name, f"{where} returned an observation of shape {np.shape(o)}; its observation space has {self.obs_dim} numbers")
        return flat

    def _reward(self, reward) -> float:
        if isinstance(reward, (str, bytes)) or not np.ndim(reward) == 0:  # float("1.5") would pass a str for a number
            raise UserEnvError(self.env_name, f"step returned the reward {reward!r:.60} ({type(reward).__name__}); a reward is a number")
        try:
            return float(reward)
        except (TypeError, ValueError) as err:
            raise UserEnvError.wrap(self.env_name, "step returned a reward that is no number", err) from None


class MujocoDirectEvaluator(BatchEvaluator):
    """Gymnasium's v5 Swimmer, Hopper, HalfCheetah, Walker2d and Ant without gymnasium (``backend="direct"``).

    The same episodes as :class:`GymEvaluator` on the same id -- bit for bit: returns, lengths
    and :attr:`last_obs_stats` (tests/test_mujoco_direct.py) -- computed by
    :class:`imix_cli.core.envs.mujoco_direct.DirectEpisodes`: one ``MjData`` per member, one
    ``mj_step(nstep=frame_skip)`` call per member and env step, and the observations, rewards
    and health checks of all live members in a few numpy operations per step instead of a
    wrapped ``env.step`` per member. The loop below is :meth:`GymEvaluator._run`'s, with the
    per-member ``env.step`` calls replaced by one batched step.
    """

    def __init__(self, env_id: str, max_steps: int | None = None, hidden=HIDDEN, output: str = "tanh"):
        from imix_cli.core.envs.mujoco_direct import DirectEpisodes

        message = missing_extra_message(env_id)  # also routes MuJoCo's warnings (HalfCheetah's model)
        if message:
            raise ValueError(message)
        self.env_name = env_id
        self.hidden, self.output = tuple(int(h) for h in hidden), output
        self.max_steps = int(gym.spec(env_id).max_episode_steps if max_steps is None else max_steps)
        if self.max_steps < 1:
            raise ValueError(f"{env_id}: max_steps must be >= 1, got {max_steps}")
        self._episodes = DirectEpisodes(env_id)
        self.obs_dim, self.out_dim, self.discrete = self._episodes.obs_dim, self._episodes.act_dim, False
        self._low = self._episodes.low.astype(np.float64)
        self._high = self._episodes.high.astype(np.float64)
        self.last_obs_stats: tuple[np.ndarray, np.ndarray] | None = None

    def policy(self, params):
        return BatchPolicy(params, self.obs_dim, self.out_dim, discrete=False, hidden=self.hidden, low=self._low, high=self._high, output=self.output)

    def close(self) -> None:
        pass

    def _run(self, policy, seeds):
        episodes = self._episodes

        def step(live, members, actions, ret, length, alive, obs):
            # float32: what gymnasium's Box action space hands the env
            new_obs, reward, terminated = episodes.step(members, actions[live].astype(np.float32))
            ret[members] += reward
            length[members] += 1
            alive[live[terminated]] = False
            obs[live] = new_obs

        return self._roll_out(policy, episodes.reset(seeds), step)


#: Gymnasium's MuJoCo environments need the ``mujoco`` package: imix's ``mujoco`` extra, installed from the clone
#: (:func:`imix_cli.messages.install_extra`'s words; the numerical library imports nothing outside it, so they are
#: written out here and tests/test_missing_extra.py checks they are the same).
MUJOCO_EXTRA_HINT = 'pip install ".[mujoco]" from the imix clone (or make install-all)'


def missing_extra_message(env_id: str) -> str | None:
    """One line naming the extra to install if ``env_id`` is a MuJoCo env and mujoco is missing, else None.

    Only the physics engine is checked: training needs no rendering backend (no OpenGL).
    When mujoco is there, its C-level warnings are routed to Python's :mod:`warnings` (see
    :func:`_route_mujoco_warnings`).
    """
    try:
        entry = str(gym.spec(env_id).entry_point)
    except Exception:
        return None
    if not entry.startswith("gymnasium.envs.mujoco"):
        return None
    try:
        import mujoco
    except ImportError:
        return f"env.id={env_id!r} is a MuJoCo environment and the mujoco package is not installed: {MUJOCO_EXTRA_HINT}"
    _route_mujoco_warnings(mujoco)
    return None


def _mujoco_warning(message: str) -> None:
    if "is deprecated" in message:  # a model file's attribute: gymnasium's to update, harmless for training
        return
    warnings.warn(f"mujoco: {message}", RuntimeWarning, stacklevel=2)


def _route_mujoco_warnings(mujoco) -> None:
    """MuJoCo's default warning handler prints to stderr *and appends to ./MUJOCO_LOG.TXT*:
    with mujoco 4, HalfCheetah-v5's model (``settotalmass``, deprecated) triggers it on every
    ``gym.make``, littering the working directory and every worker's stderr. Route the
    warnings to Python's instead, minus deprecations of model attributes (the model still
    loads as before: HalfCheetah's random-policy returns are the usual ~-280)."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_mujoco_warning)


#: Environment variable choosing how the v5 MuJoCo ids are run: ``direct`` (default) or ``gymnasium``.
MUJOCO_BACKEND_VARIABLE = "IMIX_MUJOCO_BACKEND"
MUJOCO_BACKENDS = ("direct", "gymnasium")


def mujoco_backend(backend: str | None = None) -> str:
    """``backend``, else ``$IMIX_MUJOCO_BACKEND``, else ``"direct"``; ``ValueError`` (one line) for another value."""
    value = backend if backend is not None else os.environ.get(MUJOCO_BACKEND_VARIABLE) or "direct"
    if value not in MUJOCO_BACKENDS:
        source = "backend" if backend is not None else MUJOCO_BACKEND_VARIABLE
        raise ValueError(f"{source}={value!r}: the MuJoCo backend is one of {', '.join(MUJOCO_BACKENDS)}")
    return value


def make_evaluator(
    env_name: str, max_steps: int | None = None, hidden=HIDDEN, backend: str | None = None, output: str = "tanh", env_kwargs=None
) -> BatchEvaluator:
    """Evaluator for a built-in (``"cartpole"``, ``"acrobot"``, ``"continuous_cartpole"``,
    ``"continuous_cartpole_hard"``: :data:`imix_cli.core.registry.BUILTIN_ENVS`) or a gymnasium id
    (see the module docstring).

    ``hidden``: the policy's hidden layer sizes (``()``: linear), default the paper's (8, 8).
    ``output``: how continuous actions are made from the outputs, ``"tanh"`` or ``"clip"``
    (:mod:`imix_cli.core.evaluation.policies`); the built-in envs' compiled episodes squash with tanh only.
    ``backend`` (default ``$IMIX_MUJOCO_BACKEND``, else ``"direct"``): how ``Swimmer-v5``,
    ``Hopper-v5``, ``HalfCheetah-v5``, ``Walker2d-v5`` and ``Ant-v5`` run -- ``"direct"``:
    :class:`MujocoDirectEvaluator` (the same episodes, bit for bit, without gymnasium's per-step
    overhead), ``"gymnasium"``: :class:`GymEvaluator`. Every other id runs on gymnasium.
    ``env_kwargs``: the constructor arguments of a gymnasium env (a mapping or (key, value) pairs), given to ``gym.make``;
    a MuJoCo id given some runs on gymnasium (the direct evaluator reproduces the default envs only); the built-in
    envs take none.
    Raises ``ValueError`` for an unknown environment id or backend, or a MuJoCo id without mujoco installed.
    """
    hidden = tuple(int(h) for h in hidden)
    env_kwargs = dict(env_kwargs or {})
    backend = mujoco_backend(backend)
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
    key = str(env_name).lower()
    if key in BUILTIN_ENVS:
        if env_kwargs:
            raise ValueError(f"{key}: the built-in env's compiled episodes take no constructor arguments, got {sorted(env_kwargs)}")
        if output != "tanh":
            raise ValueError(f"{key}: the built-in env's compiled episodes take output='tanh' only, got {output!r}")
        builtin = BUILTIN_EVALUATORS[key](max_steps)
        if hidden != HIDDEN:
            builtin.hidden = hidden  # the compiled kernels read the layer sizes from it
        return builtin
    from imix_cli.core.envs.ids import import_user_env

    # ``module:Id``: an id the user typed for this run (imix eval/render resolve ids read from
    # files before they come here), so its module is imported -- in every worker process too.
    env_name = import_user_env(str(env_name))
    try:
        gym.spec(env_name)
    except (gym.error.UnregisteredEnv, gym.error.DeprecatedEnv, gym.error.RegistrationError) as err:
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"unknown environment {env_name!r}: not {', '.join(map(repr, BUILTIN_ENVS))} or a registered gymnasium id ({msg})") from None
    if backend == "direct" and env_name in DIRECT_ENV_IDS and not env_kwargs:
        return MujocoDirectEvaluator(env_name, max_steps, hidden=hidden, output=output)
    return GymEvaluator(env_name, max_steps, hidden=hidden, output=output, env_kwargs=env_kwargs)
