"""The generations of a run's seeds: the lockstep and compiled loops, resuming from checkpoints, stop requests."""
