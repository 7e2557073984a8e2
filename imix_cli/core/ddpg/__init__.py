"""The DDPG baseline (paper section 4.3), in one place: the agent (stable-baselines3), its paper
settings, its config checks and the training of its seeds. :mod:`imix_cli.running` reaches it
through the ``DDPG`` trainer (:mod:`imix_cli.running.trainers`) and the config's ``algo=ddpg``
branch; SB3 and torch load only when a DDPG seed runs.
"""
