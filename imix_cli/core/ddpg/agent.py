"""DDPG (stable-baselines3) with the paper's settings: the deep-RL baseline of section 4.3.

This module knows SB3 and torch, not files: :func:`make_ddpg` builds the agent,
:func:`train_ddpg` runs it for a budget of environment steps and reports every finished
episode; DDPG's trainer (:func:`imix_cli.running.loop.ddpg_seeds.run_ddpg_seeds`) turns those into CSV
rows.
Importing it imports torch and SB3 (``pip install torch==2.13.0 stable-baselines3``); nothing
else in imix does.

Settings (``conf/algo/ddpg.yaml``; the paper's first, then what it leaves to "standard DDPG
parameters as in OpenAI baselines"):

* actor: hidden layers ``actor_arch`` = [8, 8] (ReLU, tanh output: SB3's ``Actor``), the same
  size as the evolved policy; critic: ``critic_arch`` = [16, 16] (ReLU), one Q-network
  (``n_critics=1``, plain DDPG: no twin critics, no target smoothing, no policy delay);
* Adam learning rates 0.005 (actor) and 0.01 (critic). SB3 has one ``learning_rate`` and
  re-applies it to both optimisers at every training step (``_update_learning_rate``), so
  :class:`TwoRateDDPG` keeps a second schedule for the critic and overrides that method to set
  each optimiser from its own schedule (tests check the optimisers' ``lr`` after training);
* tau 0.001, gamma 0.99;
* exploration: Ornstein-Uhlenbeck noise added to the actor's action (then clipped to the
  action bounds), ``sigma`` 0.2, ``theta`` 0.15, ``dt`` 0.01 (baselines' ``ou_0.2`` and its OU
  process), reset to 0 at the start of each episode (SB3);
* minibatch 64 (baselines), replay buffer 1e6 transitions, ``learning_starts`` 100 (SB3's
  default: the first 100 steps take uniform random actions and no update happens before),
  then one gradient step per environment step (``train_freq`` 1, ``gradient_steps`` 1, as
  Lillicrap et al. 2015); Adam's other settings torch's defaults, ``device="cpu"``.
  Time-limit truncations are not treated as terminal (SB3's ``handle_timeout_termination``).

Seeding: SB3's ``seed=`` (Python, numpy and torch generators, the action space, the env's
first reset). On CPU with one torch thread a seed's episodes are reproducible.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import DDPG
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.utils import FloatSchedule, update_learning_rate

import imix_cli.core.envs  # noqa: F401  (registers the imix/ gymnasium ids in spawned workers too)
from imix_cli.core.ddpg.settings import PAPER_SETTINGS

__all__ = ["TwoRateDDPG", "Episode", "make_ddpg", "train_ddpg", "PAPER_SETTINGS"]


class TwoRateDDPG(DDPG):
    """SB3's DDPG with separate Adam learning rates for the actor and the critic.

    ``learning_rate`` is the actor's, ``critic_learning_rate`` the critic's (each a float or an
    SB3 schedule of the remaining progress). SB3 resets every optimiser to ``learning_rate`` at
    each ``train()`` call; :meth:`_update_learning_rate` sets each from its own schedule instead.
    """

    def __init__(self, *args, critic_learning_rate: float | Callable[[float], float] = 1e-3, **kwargs):
        self.critic_learning_rate = critic_learning_rate
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        self.critic_lr_schedule = FloatSchedule(self.critic_learning_rate)
        # The policy built the critic's optimiser with the actor's rate; fix it before any update.
        update_learning_rate(self.critic.optimizer, self.critic_lr_schedule(1.0))

    def _update_learning_rate(self, optimizers) -> None:
        progress = self._current_progress_remaining
        super()._update_learning_rate(self.actor.optimizer)  # logs train/learning_rate (the actor's)
        critic_lr = self.critic_lr_schedule(progress)
        self.logger.record("train/critic_learning_rate", critic_lr)
        update_learning_rate(self.critic.optimizer, critic_lr)


@dataclass(frozen=True)
class Episode:
    """One finished training episode (with exploration noise, as the agent experienced it)."""

    index: int  # 0-based
    ret: float  # undiscounted sum of the env's rewards (sparse on the Hard variant: its total)
    length: int  # steps
    env_steps: int  # cumulative environment steps at its end


def make_env(env_id: str, max_steps: int | None = None) -> gym.Env:
    """``gym.make(env_id)``, with its time limit replaced by ``max_steps`` if given."""
    return gym.make(env_id, max_episode_steps=max_steps) if max_steps else gym.make(env_id)


def make_ddpg(env_id: str, settings: dict | None = None, seed: int = 0, max_steps: int | None = None) -> TwoRateDDPG:
    """The agent for ``env_id`` (a Box-action gymnasium id) with ``settings`` (default: the paper's)."""
    s = {**PAPER_SETTINGS, **(settings or {})}
    env = make_env(env_id, max_steps)
    if not isinstance(env.action_space, gym.spaces.Box):
        raise ValueError(f"DDPG needs continuous (Box) actions; {env_id} has {env.action_space}")
    n_actions = int(np.prod(env.action_space.shape))
    noise = OrnsteinUhlenbeckActionNoise(
        mean=np.zeros(n_actions), sigma=float(s["ou_sigma"]) * np.ones(n_actions), theta=float(s["ou_theta"]), dt=float(s["ou_dt"])
    )
    return TwoRateDDPG(
        "MlpPolicy",
        env,
        learning_rate=float(s["actor_lr"]),
        critic_learning_rate=float(s["critic_lr"]),
        buffer_size=int(s["buffer_size"]),
        learning_starts=int(s["learning_starts"]),
        batch_size=int(s["batch_size"]),
        tau=float(s["tau"]),
        gamma=float(s["gamma"]),
        train_freq=int(s["train_freq"]),
        gradient_steps=int(s["gradient_steps"]),
        action_noise=noise,
        policy_kwargs={"net_arch": {"pi": list(s["actor_arch"]), "qf": list(s["critic_arch"])}},
        seed=int(seed),
        device="cpu",
        verbose=0,
    )


class _EpisodeReporter(BaseCallback):
    """Calls ``on_episode(Episode)`` at each finished episode and ``on_steps(n)`` every ``every`` steps."""

    def __init__(self, on_episode, on_steps=None, every: int = 1000):
        super().__init__()
        self.on_episode, self.on_steps, self.every = on_episode, on_steps, int(every)
        self.episodes = 0
        self._reported = 0

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            episode = info.get("episode")  # set by SB3's Monitor wrapper at each episode end
            if episode is not None:
                ret = float(episode["r"])
                self.on_episode(Episode(self.episodes, ret, int(episode["l"]), int(self.num_timesteps)))
                self.episodes += 1
        if self.on_steps is not None and self.num_timesteps - self._reported >= self.every:
            self.on_steps(self.num_timesteps - self._reported)
            self._reported = self.num_timesteps
        return True

    def _on_training_end(self) -> None:
        if self.on_steps is not None and self.num_timesteps > self._reported:
            self.on_steps(self.num_timesteps - self._reported)
            self._reported = self.num_timesteps


def train_ddpg(
    model: TwoRateDDPG,
    total_steps: int,
    on_episode: Callable[[Episode], None],
    on_steps: Callable[[int], None] | None = None,
    torch_threads: int | None = 1,
) -> TwoRateDDPG:
    """Train ``model`` for exactly ``total_steps`` environment steps.

    ``on_episode`` gets every episode that finishes within the budget (an episode still running
    when it is spent is not reported); ``on_steps(n)`` reports progress. ``torch_threads``
    (default 1: seeds already run one process per core) is applied with ``torch.set_num_threads``.
    """
    if torch_threads:
        th.set_num_threads(int(torch_threads))
    model.learn(total_timesteps=int(total_steps), callback=_EpisodeReporter(on_episode, on_steps), progress_bar=False)
    return model
