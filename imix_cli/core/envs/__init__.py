"""Environments: the compiled episodes used by :mod:`imix_cli.core.evaluation`, and imix's gymnasium ids.

* :mod:`imix_cli.core.envs.kernels`: CartPole, Acrobot and ContinuousCartPole(Hard) episodes,
  policy included, compiled with numba (gymnasium's dynamics, operation for operation);
* :mod:`imix_cli.core.envs.continuous_cartpole`: ContinuousCartPole(Hard) (paper section 4.3), the
  registered gymnasium envs;
* :func:`seeded_uniform` (:mod:`imix_cli.core.envs.seeding`): the initial-state draw of
  ``reset(seed=s)`` for many seeds at once.

Importing this package does not load numba; the kernels module does, on first use.

Importing this package (``import imix_cli`` does) registers with gymnasium:

=================================  =====================================================
``imix/ContinuousCartPole-v0``     CartPole physics, force = 10 N x a, a in [-1, 1]; 200 steps
``imix/ContinuousCartPoleHard-v0`` the same, reward 0 but on the last step (the episode's total)
=================================  =====================================================
"""

from __future__ import annotations

from gymnasium.envs.registration import WrapperSpec, register, registry

from imix_cli.core.envs.seeding import seeded_uniform

__all__ = ["seeded_uniform", "CONTINUOUS_CARTPOLE_ID", "CONTINUOUS_CARTPOLE_HARD_ID", "EPISODE_STEPS"]

CONTINUOUS_CARTPOLE_ID = "imix/ContinuousCartPole-v0"
CONTINUOUS_CARTPOLE_HARD_ID = "imix/ContinuousCartPoleHard-v0"
EPISODE_STEPS = 200  # both ids: TimeLimit of 200 steps, as CartPole-v0 (threshold 195)

_ENTRY = "imix_cli.core.envs.continuous_cartpole:ContinuousCartPoleEnv"
_SPARSE = WrapperSpec("SparseEpisodeReward", "imix_cli.core.envs.continuous_cartpole:SparseEpisodeReward", {})


def _register() -> None:
    common = dict(entry_point=_ENTRY, max_episode_steps=EPISODE_STEPS, reward_threshold=195.0)
    if CONTINUOUS_CARTPOLE_ID not in registry:
        register(id=CONTINUOUS_CARTPOLE_ID, **common)
    if CONTINUOUS_CARTPOLE_HARD_ID not in registry:
        # The sparse wrapper goes outside gymnasium's TimeLimit, so it sees truncation as the last step.
        register(id=CONTINUOUS_CARTPOLE_HARD_ID, additional_wrappers=(_SPARSE,), **common)


_register()
