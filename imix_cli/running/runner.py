"""The runner: one run = one config (algo, env, mixing, hyper-parameters) x ``seeds`` seeds.

It wires the other modules together and does nothing else: the run folder is locked and
checked (:mod:`imix_cli.running.run_folder`), the seeds still to run are split over ``workers``
processes (:mod:`imix_cli.running.pool`, spawn-safe), each process trains its share with the run's
trainer (:mod:`imix_cli.running.trainers`: the evolution strategies in lockstep with checkpoints,
:mod:`imix_cli.running.loop.es_seeds`; the DDPG baseline, :mod:`imix_cli.running.loop.ddpg_seeds`), and the summary is
printed (:mod:`imix_cli.running.summary`) from what the seeds returned and the CSVs of seeds finished
earlier.

Re-running the same command skips finished seeds and resumes the others from their
checkpoints (:mod:`imix_cli.running.loop.resume`); a seed's CSV is identical whatever the worker count, the
other seeds sharing its batch, or whether it was resumed (:mod:`imix_cli.running.loop.lockstep`).
"""

from __future__ import annotations

import errno
import sys
import time

import numpy as np

from imix_cli.running.pool import progress_bar, report_progress, report_resumed, run_pool
from imix_cli.running.run_folder import RunError, check_run_dir, prepare_run_dir, run_dir_lock
from imix_cli.running.summary import format_summary, prepare_summary, summarize
from imix_cli.running.trainers import SEED_GROUP, trainer_for
from imix_cli.running.warmup import warm_up

__all__ = ["RunError", "run", "run_seeds"]


def run(spec, echo=print) -> dict:
    """Run every unfinished seed of ``spec`` (a :class:`imix_cli.running.config.run_spec.RunSpec`); print and return the summary.

    The run folder is checked first (:func:`imix_cli.running.run_folder.check_run_dir`: a refused run
    writes nothing, not even its lock), then locked for the whole run
    (:func:`imix_cli.running.run_folder.run_dir_lock`): a second run on it is refused with RunError
    before it touches anything.
    """
    check_run_dir(spec)
    try:
        with run_dir_lock(spec):
            return _run_locked(spec, echo)
    except OSError as err:
        refused = write_refused(spec.run_dir, err)
        if refused is None:
            raise
        raise refused from None


#: A write the run folder refused: read-only or immutable (``chmod a-w``, ``chattr +i``, a read-only mount), or full.
_NOT_WRITABLE = {errno.EACCES, errno.EPERM, errno.EROFS}
_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def write_refused(run_dir, err: OSError) -> RunError | None:
    """The one line for a write the run folder refused (mid-run, in this process or a worker): the run folder named,
    the file and the reason, and what to do -- ``None`` if ``err`` is not such a write (another errno, a file outside
    the run folder: a user env's own error keeps its line). Before, the line named only the temporary being written
    (``.seed_1.partial.csv.3d89911e.tmp``), not the folder or what to do (issue 47, case 9)."""
    import os
    from pathlib import Path

    if err.errno not in _NOT_WRITABLE | _FULL or not err.filename:
        return None
    folder, target = Path(os.path.abspath(run_dir)), Path(os.path.abspath(os.fsdecode(err.filename)))
    if target != folder and folder not in target.parents:
        return None
    what = "free some space" if err.errno in _FULL else "make it writable (chmod u+w; chattr -i if made immutable)"
    name = "the folder itself" if target == folder else str(target.relative_to(folder))
    return RunError(
        f"cannot write in the run folder {run_dir} ({name}: {err.strerror or err}); {what} and re-run the same command: the run resumes from its checkpoints"
    )


def run_seeds(spec, seeds: list[int], progress=None, resumed=None) -> dict:
    """Run ``seeds`` of ``spec`` to completion in this process; return seed -> summary of its rows.

    ``progress(n)`` is called with the progress just made, in the trainer's unit (ES:
    seed-generations; DDPG: environment steps), ``resumed({seed: generation})`` once with where each seed
    starts; by default both go to the pool's queue.
    """
    return trainer_for(spec).run_seeds(spec, seeds, progress or report_progress, resumed or report_resumed)


def _run_locked(spec, echo) -> dict:
    trainer = trainer_for(spec)
    todo = prepare_run_dir(spec)
    bar = progress_bar(len(todo) * trainer.budget(spec), spec.run_name, trainer.unit, spec.progress)
    started = time.perf_counter()
    done = {}
    if todo:
        workers = min(spec.workers, len(todo))
        chunks = [list(map(int, c)) for c in np.array_split(np.array(todo), workers)]
        resumed = ResumeLine(spec, todo, bar, first=[seed for chunk in chunks for seed in chunk[:SEED_GROUP]])
        if workers == 1:
            done = run_seeds(spec, chunks[0], progress=bar.update, resumed=resumed)
        else:
            if spec.algo != "ddpg":
                warm_up(spec, workers)  # a first run: the kernels compiled once, over the cores, not in every worker
            for share in run_pool(run_seeds, spec, chunks, bar, when_a_core_is_free=prepare_summary, resumed=resumed):
                done.update(share)
    bar.close()
    summary = summarize(spec, known=done)
    summary["wall_time"] = time.perf_counter() - started
    summary["seeds_run"] = len(todo)
    echo(format_summary(spec, summary))
    return summary


class ResumeLine:
    """Where the seeds of a run start, said on stderr once every seed of each process's first group has been told
    (``resumed({seed: generation})``, from each process of the run, as it sets a group of seeds up:
    :data:`~imix_cli.running.loop.SEED_GROUP`), then for each later group as it starts: one line per set of seeds
    resuming at the same generation (the seeds of a group advance in lockstep, so a set is usually a group), and one for
    the seeds that start from generation 0 -- said only if a seed resumes, or one of them had started (its live view is
    on disk: killed before its first checkpoint, its generations are run again). A run whose shares fit in one group
    each (every run of up to 64 seeds a process) says it all at once, before the first generation::

        imix: resuming seeds 0-12 of snes-cartpole-eim at generation 370 from their checkpoints
        imix: resuming seeds 13-24 of snes-cartpole-eim at generation 375 from their checkpoints
    """

    def __init__(self, spec, todo: list[int], bar, first=None):
        import os

        self.spec, self.bar, self.starts = spec, bar, {}
        self.first = set(todo if first is None else first)  # the seeds told before anything is said
        # one scan of the folder, not a stat per seed (seeds=100000: seconds)
        names = set(os.listdir(spec.run_dir)) if spec.run_dir.is_dir() else set()
        # before any seed runs (a worker's live view of this run, written seconds later, must not count)
        self.started = {seed for seed in todo if f"seed_{seed}.partial.csv" in names}
        # finished seeds run again only to rebuild a policy file: their worker says so, in a line of its own
        self.finished = {seed for seed in todo if f"seed_{seed}.csv" in names}

    def __call__(self, starts: dict) -> None:
        self.starts.update(starts)
        if self.first and not self.first <= set(self.starts):
            return  # the first groups are not all told yet
        told = self.starts if self.first else starts  # all at once, then each later group as it starts
        self.first = set()
        budget = getattr(self.spec, "generations", None)
        told = {seed: g for seed, g in told.items() if not (seed in self.finished and g == budget)}
        for line in resume_lines(self.spec.run_name, told, self.started):
            write = getattr(self.bar, "write", None)  # above a progress bar, not through it
            write(line, file=sys.stderr) if write else print(line, file=sys.stderr, flush=True)


def seeds_text(seeds) -> str:
    """``seed 3``, ``seeds 0-12``, ``seeds 0,2,5-7``."""
    seeds = sorted(seeds)
    ranges, start = [], seeds[0]
    for a, b in zip(seeds, [*seeds[1:], None]):
        if b != a + 1:
            ranges.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return f"seed{'s' if len(seeds) > 1 else ''} {','.join(ranges)}"


def resume_lines(run_name: str, starts: dict, started=()) -> list[str]:
    """Where the seeds start (``starts``: seed -> generation): one line per generation some seeds resume at, then
    one for those that start from generation 0, e.g. ``imix: resuming seeds 0-12 of R at generation 370 from their
    checkpoints``. Nothing if no seed resumes and none of ``started`` (seeds with a live view on disk) is among them."""
    groups: dict[int, list] = {}
    for seed, generation in starts.items():
        groups.setdefault(int(generation), []).append(seed)
    fresh = groups.pop(0, [])
    lines = [
        f"imix: resuming {seeds_text(seeds)} of {run_name} at generation {generation} from {'their checkpoints' if len(seeds) > 1 else 'its checkpoint'}"
        for generation, seeds in sorted(groups.items())
    ]
    if fresh and (lines or set(fresh) & set(started)):
        again = set(fresh) & set(started)
        why = f" (no checkpoint: {seeds_text(again)} stopped before {'their' if len(again) > 1 else 'its'} first one)" if again else ""
        lines.append(f"imix: {seeds_text(fresh)} of {run_name} start{'s' if len(fresh) == 1 else ''} from generation 0{why}")
    return lines
