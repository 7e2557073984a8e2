"""The evolution strategies' trainer: seeds of one run, in lockstep, with checkpoints and resume.

Files (see :mod:`imix_cli.running.results`): ``seed_<k>.csv`` is written atomically when seed ``k``
finishes; its state is checkpointed every ``checkpoint_every`` generations (:mod:`imix_cli.running.resume`),
with ``seed_<k>.partial.csv`` as a live view. Re-running the same command resumes each seed from
its checkpoint, saying so on stderr (``seed k resumes at generation G``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from imix_cli.messages import warn
from imix_cli.parallel_evaluation import build_evaluator
from imix_cli.running.lockstep import SeedState, advance_lockstep, new_seed_state, policy_params, search_dim
from imix_cli.running.policy_files import write_seed_policies
from imix_cli.running.results import atomic_write_text, partial_csv_path, rows_csv_text, seed_csv_path, write_run_csv
from imix_cli.running.resume import can_checkpoint, checkpoint_path, load_checkpoint, remove_checkpoints, save_checkpoint
from imix_cli.running.run_folder import RunError
from imix_cli.running.run_spec import resume_identity
from imix_cli.running.tracking import make_tracker


def run_es_seeds(spec, seeds: list[int], progress) -> dict:
    """Run ``seeds`` of ``spec`` to completion in this process, in lockstep; ``progress(n)`` gets the
    number of seed-generations just completed. Returns seed -> :func:`imix_cli.running.results.seed_summary`."""
    evaluator = build_evaluator(spec)
    try:  # the evaluator's processes (pool, Ray) end with the seeds, a Ctrl-C or SIGTERM included
        return _run_es_seeds(spec, seeds, progress, evaluator)
    finally:
        close = getattr(evaluator, "close", None)
        if close is not None:
            close()


def _run_es_seeds(spec, seeds: list[int], progress, evaluator) -> dict:
    identity = resume_identity(spec.identity())  # a run continued to more generations resumes too
    run_dir = spec.run_dir
    states = []
    for seed in seeds:
        # A refused checkpoint may have been half loaded into the ES it was given: start from a new one.
        fresh = new_seed_state(spec, seed, search_dim(spec, evaluator))
        st = load_checkpoint(run_dir, seed, identity, fresh, spec=spec, max_steps=int(evaluator.max_steps), policy_dim=evaluator.num_params)
        if st is not None and st.generation > spec.generations:  # a longer continuation's, killed before it finished
            warn(
                f"{checkpoint_path(run_dir, seed)}: checkpoint at generation {st.generation} is past generations={spec.generations}; "
                f"seed {seed} restarts from generation 0"
            )
            st = None
        st = st or new_seed_state(spec, seed, search_dim(spec, evaluator))
        states.append(st)
        if st.generation:
            print(f"imix: seed {seed} resumes at generation {st.generation} from {checkpoint_path(run_dir, seed)}", file=sys.stderr, flush=True)
            progress(st.generation)
    checkpoint_every = spec.checkpoint_every if states and can_checkpoint(states[0].es) else 0
    summaries = {}
    started = time.perf_counter()
    active = [st for st in states if st.generation < spec.generations]
    tracker = make_tracker(spec)  # logger=: a copy of each row, as it is made
    try:
        _run_active(spec, states, active, evaluator, identity, checkpoint_every, started, summaries, progress, tracker)
    finally:
        if tracker is not None:
            tracker.close()
    for st in states:  # seeds resumed from a checkpoint taken after their last generation
        if not seed_csv_path(run_dir, st.seed).exists():
            summaries[st.seed] = _finish_seed(spec, st, evaluator)
            remove_checkpoints(run_dir, st.seed)
    return summaries


#: Most generations a seed runs in one compiled call (:mod:`imix_cli.running.compiled_loop`): the progress bar
#: and the rows' wall times move by this step (about a tenth of a second on the main job).
CHUNK = 25


def _run_active(spec, states, active, evaluator, identity, checkpoint_every, started, summaries, progress, tracker) -> None:
    """The lockstep loop of :func:`run_es_seeds`: generations of the ``active`` seeds until each is done.

    Seeds the compiled loop applies to (:mod:`imix_cli.running.compiled_loop`: the same rows, bit for bit)
    advance by chunks of up to :data:`CHUNK` generations, a chunk ending where the loop below would
    checkpoint or finish; the other seeds advance one generation at a time, together."""
    from imix_cli.running import compiled_loop  # numba's kernels: loaded by the processes that run seeds only

    ended = _SeedEnd(spec, evaluator, identity, checkpoint_every, started, summaries, tracker)
    compiles = compiled_loop.applies_to_run(spec, evaluator)  # the run's part of the check, once
    while active:
        advanced = 0
        stepped = []
        for st in active:
            if not (compiles and compiled_loop.applies(spec, evaluator, st)):
                stepped.append(st)
                continue
            first, began = st.generation, time.perf_counter() - started
            stop = min(spec.generations, first + CHUNK)
            if checkpoint_every:
                stop = min(stop, (first // checkpoint_every + 1) * checkpoint_every)
            if compiled_loop.advance(st, spec, evaluator, stop - first):
                ended(st, first, began)
            else:  # a non-finite return or a diverging update: the Python loop takes the chunk
                while st.generation < stop and not st.es.diverged:
                    advance_lockstep([st], spec, evaluator)
                    ended(st, st.generation - 1)
            advanced += st.generation - first
        if stepped:
            advance_lockstep(stepped, spec, evaluator)
            for st in stepped:
                ended(st, st.generation - 1)
            advanced += len(stepped)
        progress(advanced)
        active = [st for st in active if st.generation < spec.generations and not st.es.diverged]


class _SeedEnd:
    """What follows a seed's new rows: their wall times, the tracker, then -- at the last one -- the
    end of a diverged or finished seed, or a checkpoint with its live CSV."""

    def __init__(self, spec, evaluator, identity, checkpoint_every, started, summaries, tracker):
        self.spec, self.evaluator, self.identity, self.checkpoint_every = spec, evaluator, identity, checkpoint_every
        self.started, self.summaries, self.tracker = started, summaries, tracker
        self.partial: dict[int, tuple[int, str]] = {}  # seed -> (rows in its live CSV, their text)
        self.tables: dict[int, dict] = {}  # seed -> its rows' encoding at its last checkpoint (imix_cli.running.checkpoints.TableCache)

    def __call__(self, st: SeedState, first: int, began: float | None = None) -> None:
        """``st.rows[first:]`` are new; ``began``: when the compiled chunk that made them began."""
        spec, run_dir = self.spec, self.spec.run_dir
        now = time.perf_counter() - self.started
        rows = st.rows[first:]
        for i, row in enumerate(rows, start=1):  # a compiled chunk's rows: times spread evenly over it
            row["wall_time"] = st.elapsed + (now if began is None else began + (now - began) * i / len(rows))
        diverged = end_if_diverged(st)
        if self.tracker is not None:
            for row in rows:
                self.tracker.log(st.seed, row)
        if diverged:
            self.tables.pop(st.seed, None)
            self.summaries[st.seed] = write_run_csv(seed_csv_path(run_dir, st.seed), st.rows)
            remove_checkpoints(run_dir, st.seed)
        elif st.generation == spec.generations:
            self.summaries[st.seed] = _finish_seed(spec, st, self.evaluator)
            if self.checkpoint_every:  # the final state: `generations=` larger continues from it
                _checkpoint(run_dir, st, self.identity, now, self.tables.pop(st.seed, None))
            remove_checkpoints(run_dir, st.seed, keep_final=bool(self.checkpoint_every))
        elif self.checkpoint_every and st.generation % self.checkpoint_every == 0:
            _checkpoint(run_dir, st, self.identity, now, self.tables.setdefault(st.seed, {}))
            self._write_partial(st)

    def _write_partial(self, st: SeedState) -> None:
        """The seed's live view (``seed_<k>.partial.csv``, read by imix status and plot), rewritten
        whole (atomically) with only its new rows formatted: a seed's earlier rows never change."""
        done, text = self.partial.get(st.seed, (0, ""))
        text += rows_csv_text(st.rows[done:], header=not done)
        self.partial[st.seed] = (len(st.rows), text)
        atomic_write_text(partial_csv_path(self.spec.run_dir, st.seed), text)


def _finish_seed(spec, st: SeedState, evaluator) -> dict:
    """Write seed ``st``'s policy files and CSV; return its summary."""
    mean = policy_params(spec, st, st.es.distribution.mean[None, :], evaluator)[0]
    write_seed_policies(spec, st.seed, evaluator, mean, st.best_params, st.best_return, st.generation)
    return write_run_csv(seed_csv_path(spec.run_dir, st.seed), st.rows)


def _checkpoint(run_dir: Path, st: SeedState, identity: dict, now: float, tables: dict | None = None) -> None:
    """Save ``st`` with the wall time it has spent so far, ``now`` seconds into this process's share."""
    elapsed, st.elapsed = st.elapsed, st.elapsed + now
    try:
        save_checkpoint(run_dir, st, identity, tables)
    finally:
        st.elapsed = elapsed


def end_if_diverged(st: SeedState) -> bool:
    """If seed ``st``'s search just diverged, mark its last row and say so (one line); return whether it did."""
    if not st.es.diverged:
        return False
    st.rows[-1]["diverged"] = 1
    warn(f"seed {st.seed} diverged at generation {st.generation - 1} ({st.es.diverged}); its CSV ends there")
    return True


def needs_running(spec, seed: int, path: Path, frame) -> bool:
    """Whether seed ``seed``, whose CSV ``frame`` exists at ``path``, is to be continued to more generations.

    RunError if the CSV holds more generations than asked (a run is never shortened below what a seed
    finished), or fewer with no final state to continue from."""
    run_dir = spec.run_dir
    if len(frame) > spec.generations:
        raise RunError(
            f"{path}: has {len(frame)} generations, config asks for {spec.generations}: a run can be continued to more generations, "
            "not shortened below what a seed finished; choose another experiment= or move that folder away"
        )
    if len(frame) < spec.generations and frame["diverged"].iloc[-1] != 1:  # continue it from its final state
        if not checkpoint_path(run_dir, seed).exists():
            raise RunError(
                f"{path}: has {len(frame)} of {spec.generations} generations and no final state to continue from "
                f"({checkpoint_path(run_dir, seed).name} missing: made with checkpoint_every=0); "
                "move it away or choose another experiment="
            )
        return True
    return False
