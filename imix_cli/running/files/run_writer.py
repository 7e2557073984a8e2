"""The writer of an ES run's seeds: every file a seed writes as it trains, and only here.

The loop (:mod:`imix_cli.running.loop.es_seeds`) hands it each step of a seed -- the seed's state and the
step's :class:`imix_cli.running.loop.lockstep.SeedRecord` -- and it writes what falls due:

* every new row: its wall time, and a copy to the tracker (``logger=``, :mod:`imix_cli.running.files.tracking`);
* every ``checkpoint_every`` generations, once ``checkpoint_seconds`` have passed since the seed's last one:
  the seed's checkpoint (:mod:`imix_cli.running.files.checkpoints`) and ``seed_<k>.partial.csv``, its live view
  (:mod:`imix_cli.running.files.results`). Why a time floor: a checkpoint bounds the work a kill loses, and that is
  a matter of seconds, not generations -- fifty generations are 10 ms of the main job and hours of a large
  MuJoCo policy; writing one every 50 of the main job's generations cost a fifth of its wall time;
* between two checkpoints, every :data:`LIVE_VIEW_SECONDS`: the live view alone (no checkpoint), so that ``imix status``
  and ``imix plot`` see a seed's generations within seconds, not only after its first checkpoint (``checkpoint_seconds``,
  30 s by default: ``imix status`` said "last gen -" for the first half-minute of the main job while its bar moved);
* at a finished seed's end: its policy files (:mod:`imix_cli.running.files.policy_files`), its final state, from
  which a larger ``generations=`` continues, then ``seed_<k>.csv``;
* at a diverged seed's end: one warning line, ``seed_<k>.csv`` ending at the diverged row, and its
  checkpoint removed;
* when the run is stopped (Ctrl-C, SIGTERM: :mod:`imix_cli.running.loop.stopping`): every unfinished seed's checkpoint
  and live view at its current generation (:meth:`RunWriter.checkpoint_now`).

The file formats are the modules named, which know nothing of the loop; what falls due when, and in
which order, is here: a seed's CSV, which marks it done, comes after its policy files and final state,
and its older files go after its CSV (a run killed in between redoes the seed's last steps, or only
its files).
"""

from __future__ import annotations

import dataclasses
import time

from imix_cli.messages import warn
from imix_cli.running.files.checkpoints import remove_checkpoint, save_checkpoint
from imix_cli.running.files.policy_files import write_seed_policies
from imix_cli.running.files.results import partial_csv_path, rows_csv_text, seed_csv_path, write_run_csv
from imix_cli.running.files.tracking import make_tracker
from imix_cli.running.files.writing import atomic_write_text

#: Seconds between two writes of a seed's live view ``seed_<k>.partial.csv`` when no checkpoint falls due: a rewrite of
#: text already formatted (only the new rows are), not flushed to the disk -- a few ms every few seconds.
LIVE_VIEW_SECONDS = 5.0


class RunWriter:
    """The files of run ``spec``'s seeds in this process; ``identity``: what their checkpoints are of.
    ``summaries``: seed -> :func:`imix_cli.running.files.results.seed_summary`, of each seed whose CSV it wrote."""

    def __init__(self, spec, evaluator, identity: dict):
        self.spec, self.evaluator, self.identity, self.run_dir = spec, evaluator, identity, spec.run_dir
        self.tracker = make_tracker(spec)  # logger=: a copy of each row, as it is made
        self.started = time.perf_counter()
        self.summaries: dict[int, dict] = {}
        self.partial: dict[int, tuple[int, str]] = {}  # seed -> (rows in its live CSV, their text)
        self.tables: dict[int, dict] = {}  # seed -> its rows' encoding at its last checkpoint (imix_cli.running.files.checkpoints.TableCache)
        self.saved: dict[int, float] = {}  # seed -> when (perf_counter) its last checkpoint was written in this process
        self.saved_generation: dict[int, int] = {}  # seed -> the generation of its checkpoint on disk (written or resumed from)
        self.viewed: dict[int, float] = {}  # seed -> when (perf_counter) its live view was last written in this process

    def begin_group(self, on_disk: dict) -> None:
        """A new group of seeds starts (:data:`imix_cli.running.loop.es_seeds.SEED_GROUP`): its rows' wall times count
        from now, as a share's did from its start; ``on_disk``: seed -> the generation of its checkpoint on disk."""
        self.started = time.perf_counter()
        self.saved_generation.update(on_disk)

    def write(self, st, record, began: float | None = None) -> None:
        """Seed ``st``'s step ``record``: its new rows, then what falls due. ``began``: when the compiled
        chunk that made the rows began (``time.perf_counter()``): their wall times spread evenly over it."""
        now = time.perf_counter() - self.started
        start = now if began is None else began - self.started
        rows = st.rows[record.first :]
        for i, row in enumerate(rows, start=1):  # a compiled chunk's rows: times spread evenly over it
            row["wall_time"] = st.elapsed + start + (now - start) * i / len(rows)
        if self.tracker is not None:
            for row in rows:
                self.tracker.log(st.seed, row)
        ended = bool(record.finished or record.diverged)
        if record.diverged:
            warn(f"seed {st.seed} diverged at generation {st.generation - 1} ({record.diverged}); its CSV ends there")
        if record.finished:
            write_seed_policies(self.spec, st.seed, self.evaluator, record.mean_policy, st.best_params, st.best_return, st.generation)
        due = record.checkpoint and (ended or self._time_for_checkpoint(st.seed))
        if due:  # with the wall time the seed has spent so far, ``now`` seconds into this process's share
            # A periodic checkpoint is a shortcut, not a result: not flushed to the disk (a kill leaves it whole; one a
            # machine crash damaged is refused and costs recomputation). A finished seed's final state is flushed.
            state = dataclasses.replace(st, elapsed=st.elapsed + now)
            save_checkpoint(self.run_dir, state, self.identity, self.tables.setdefault(st.seed, {}), durable=ended)
            self.saved[st.seed] = time.perf_counter()
            self.saved_generation[st.seed] = st.generation
        if ended:  # its CSV; its live view is no longer needed
            self.summaries[st.seed] = write_run_csv(seed_csv_path(self.run_dir, st.seed), st.rows)
            partial_csv_path(self.run_dir, st.seed).unlink(missing_ok=True)
            self.partial.pop(st.seed, None)
        elif due or self._time_for_live_view(st.seed):  # the live view with each checkpoint, and every few seconds between
            self._write_partial(st)
        if ended:  # its checkpoint is no longer needed -- but for a final state, from which a larger ``generations=`` continues
            self.tables.pop(st.seed, None)
            if not due:
                remove_checkpoint(self.run_dir, st.seed)

    def checkpoint_now(self, st) -> None:
        """Seed ``st``'s checkpoint and live view at its current generation, whatever the schedule: the run is being
        stopped (:mod:`imix_cli.running.loop.stopping`), and what a re-run keeps is what is on disk. Flushed to the disk:
        a SIGTERM is often a machine going down. Nothing is written for a seed at generation 0, or whose
        checkpoint on disk is already of this generation."""
        if st.generation == 0 or self.saved_generation.get(st.seed) == st.generation:
            return
        state = dataclasses.replace(st, elapsed=st.elapsed + time.perf_counter() - self.started)
        save_checkpoint(self.run_dir, state, self.identity, self.tables.setdefault(st.seed, {}), durable=True)
        self.saved_generation[st.seed] = st.generation
        self._write_partial(st)

    def _write_partial(self, st) -> None:
        """The live view ``seed_<k>.partial.csv``, rewritten whole with only its new rows formatted: earlier rows never change."""
        done, text = self.partial.get(st.seed, (0, ""))
        text += rows_csv_text(st.rows[done:], header=not done)
        self.partial[st.seed] = (len(st.rows), text)
        atomic_write_text(partial_csv_path(self.run_dir, st.seed), text, durable=False)  # a live view, not a result
        self.viewed[st.seed] = time.perf_counter()

    def _time_for_checkpoint(self, seed: int) -> bool:
        """Whether ``checkpoint_seconds`` have passed since seed ``seed``'s last checkpoint (or since this process took it)."""
        return time.perf_counter() - self.saved.get(seed, self.started) >= self.spec.checkpoint_seconds

    def _time_for_live_view(self, seed: int) -> bool:
        """Whether :data:`LIVE_VIEW_SECONDS` have passed since seed ``seed``'s live view was written (or this process started)."""
        return time.perf_counter() - self.viewed.get(seed, self.started) >= LIVE_VIEW_SECONDS

    def close(self) -> None:
        if self.tracker is not None:
            self.tracker.close()
