"""What ``imix run`` does between a config and its files, one folder per job: ``config/`` (the command line and
``conf/`` into a checked RunSpec), ``loop/`` (the generations of the seeds: lockstep and compiled loops, resume,
stop requests), ``files/`` (the CSV contract, checkpoints, policy files, locks, trackers, the one safe writer);
here the run itself: the seed grid (:mod:`~imix_cli.running.runner`), the process pool, the run folder, the
trainers, the numba warm-up and the summary. Built on :mod:`imix_cli.core`; the other subcommands are in
:mod:`imix_cli.commands`.
"""
