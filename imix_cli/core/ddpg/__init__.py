"""The DDPG baseline (paper section 4.3): the agent (stable-baselines3) and its paper settings. Its config
checks are :mod:`imix_cli.running.config.ddpg` and the training of its seeds :mod:`imix_cli.running.loop.ddpg_seeds`;
:mod:`imix_cli.running` reaches them through the ``DDPG`` trainer (:mod:`imix_cli.running.trainers`) and the
config's ``algo=ddpg`` branch. SB3 and torch load only when a DDPG seed runs.
"""
