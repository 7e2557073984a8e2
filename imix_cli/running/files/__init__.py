"""What a run reads and writes: the CSV contract, checkpoints, policy files, the run folder's lock, trackers,
and the one safe writer (atomic writes, symbolic links refused).
"""
