"""The generations of a run's seeds: the lockstep and compiled loops, resuming from checkpoints, stop requests."""

#: Seeds an ES worker holds at once: its share is set up and run in groups of this many, each group in lockstep, one
#: after the other (:func:`imix_cli.running.loop.es_seeds.run_es_seeds`). Why: a share set up whole before any seed
#: ran (``seeds=100000``: 50,000 states a worker) grew memory without bound, wrote no CSV for minutes, and a SIGTERM
#: during the set-up saved nothing (issue 47, case 10). A group's memory is bounded (its seeds' states and rows);
#: results do not change, a seed's CSV being the same whichever seeds share its batch (:mod:`imix_cli.running.loop.lockstep`).
#: 64: batches large enough for the evaluator (``evaluator=pool`` spreads a generation's episodes over the cores), and a
#: first CSV after 64 seeds' generations.
SEED_GROUP = 64
