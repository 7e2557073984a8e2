"""What ``imix run`` does between a config and its files: the config's checks and the run's spec,
the generation loop (Python and compiled), the process pool, checkpoints and resuming, the run
folder, the CSVs and policy files, and the summary. Built on the library modules of
:mod:`imix_cli` (the ES classes, mixing, evaluators, policies, registry); the DDPG baseline's
counterparts are in :mod:`imix_cli.core.ddpg`, the other subcommands in :mod:`imix_cli.commands`.
"""
