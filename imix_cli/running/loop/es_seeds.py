"""The evolution strategies' trainer: seeds of one run, in lockstep groups, with checkpoints and resume.

The run is read once (:func:`imix_cli.running.loop.lockstep.loop_settings`); a process's seeds are set up and run
in groups of :data:`~imix_cli.running.loop.SEED_GROUP`, one group after the other (memory bounded whatever
``seeds=`` is); each seed starts fresh or from its checkpoint (:mod:`imix_cli.running.loop.resume`); the loop
steps the seeds (:mod:`imix_cli.running.loop.lockstep`, :mod:`imix_cli.running.loop.compiled_loop`) and hands each step's record to the run's one writer
(:mod:`imix_cli.running.files.run_writer`): ``seed_<k>.csv`` written atomically when seed ``k`` finishes, its
state checkpointed every ``checkpoint_every`` generations with ``seed_<k>.partial.csv`` as a live view,
and at its current generation when the run is stopped (:mod:`imix_cli.running.loop.stopping`). Re-running the
same command resumes each seed from its checkpoint; the runner says so in one line.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import time
from pathlib import Path

from imix_cli.messages import RunError, warn
from imix_cli.running.config.run_spec import resume_identity
from imix_cli.running.files.checkpoints import checkpoint_path
from imix_cli.running.files.results import es_seed_finished
from imix_cli.running.files.run_writer import RunWriter
from imix_cli.running.loop import SEED_GROUP, stopping
from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state, seed_record
from imix_cli.running.loop.resume import can_checkpoint, load_checkpoint


def run_es_seeds(spec, seeds: list[int], progress, evaluator, resumed=None) -> dict:
    """Run ``seeds`` of ``spec`` to completion in this process, in lockstep groups of :data:`SEED_GROUP`, on the run's
    ``evaluator`` (:func:`imix_cli.core.evaluation.parallel.build_evaluator`, built and closed by the caller);
    ``progress(n)`` gets the number of seed-generations just completed, ``resumed({seed: generation})`` the generation
    each seed of a group starts from (0: from scratch) as the group is set up, for the runner's one line about them.
    Returns seed -> :func:`imix_cli.running.files.results.seed_summary`.

    Stopped by a signal (:mod:`imix_cli.running.loop.stopping`, which the caller sets up), the loop checkpoints every
    unfinished seed of its group at its current generation and raises :class:`~imix_cli.running.loop.stopping.StopRequested`;
    the groups before it are finished (their CSVs written), those after it not started."""
    identity = resume_identity(spec.identity())  # a run continued to more generations resumes too
    settings = loop_settings(spec, evaluator)
    writer = RunWriter(spec, evaluator, identity)
    try:
        for first in range(0, len(seeds), SEED_GROUP):
            if stopping.requested():  # the groups not set up yet have nothing to save
                raise stopping.StopRequested(stopping.requested())
            states = [_set_up(spec, seed, settings, identity, evaluator, progress) for seed in seeds[first : first + SEED_GROUP]]
            if resumed is not None:
                resumed({st.seed: st.generation for st in states})
            group_settings = settings if can_checkpoint(states[0].es) else dataclasses.replace(settings, checkpoint_every=0)
            writer.begin_group({st.seed: st.generation for st in states if st.generation})  # on disk already
            _run_loop(group_settings, states, evaluator, writer, progress)
    finally:
        writer.close()
    return writer.summaries


def _set_up(spec, seed: int, settings, identity: dict, evaluator, progress):
    """Seed ``seed``'s state: from its checkpoint if it has a valid one, else fresh at generation 0."""
    fresh = new_seed_state(settings, seed)
    path = checkpoint_path(spec.run_dir, seed)
    # A refused checkpoint may have been half loaded into the state it was given: a copy of the fresh one.
    st = load_checkpoint(
        spec.run_dir, seed, identity, copy.deepcopy(fresh), spec=spec, max_steps=int(evaluator.max_steps), policy_dim=evaluator.num_params
    )  # fmt: skip
    if st is not None and st.generation > settings.generations:  # a longer continuation's, killed before it finished
        warn(f"{path}: checkpoint at generation {st.generation} is past generations={settings.generations}; seed {seed} restarts from generation 0")
        st = None
    if st is not None:
        progress(st.generation)
    _say_policy_rebuild(spec, seed, st, settings.generations)
    return fresh if st is None else st


#: Most generations a seed runs in one compiled call (:mod:`imix_cli.running.loop.compiled_loop`): the progress bar
#: and the rows' wall times move by this step (about a fifth of a second on the main job). 50, the default
#: ``checkpoint_every``: a chunk per checkpoint interval; each call's Python side (the arrays handed in, the archive
#: and the rows handed back) cost ~7 % of a worker's CPU time at 25.
CHUNK = 50


def _run_loop(settings, states, evaluator, writer: RunWriter, progress) -> None:
    """The lockstep loop of :func:`run_es_seeds`: generations of the seeds until each is done, each step
    handed to ``writer`` with its :class:`imix_cli.running.loop.lockstep.SeedRecord` (a seed resumed after its
    last generation only has its files written).

    Seeds the compiled loop applies to (:mod:`imix_cli.running.loop.compiled_loop`: the same rows, bit for bit)
    advance by chunks of up to :data:`CHUNK` generations, a chunk ending where a checkpoint falls due
    or the seed finishes, the seeds of the same chunk together (:func:`_calls`); the other seeds advance one generation at a time, together. A chunk the
    compiled loop hands back (a non-finite return, a diverging update) is stepped instead, up to its end."""
    from imix_cli.running.loop import compiled_loop  # numba's kernels: loaded by the processes that run seeds only

    compiles = compiled_loop.applies_to_run(settings, evaluator)  # the run's part of the check, once
    every = settings.checkpoint_every
    stepped_until: dict[int, int] = {}  # seed -> the end of a chunk the compiled loop handed back
    active = states
    while active:
        if stopping.requested():  # here every seed is between two generations: keep them all
            if every:  # checkpoint_every=0: the user asked for no checkpoints
                for st in active:
                    writer.checkpoint_now(st)
            raise stopping.StopRequested(stopping.requested())
        firsts = [st.generation for st in active]
        began, stepped = {}, []  # seed -> when its compiled chunk began
        chunks: dict = {}  # (first generation, stop) -> the seeds whose chunk it is: advanced together
        for st in (st for st in active if st.generation < settings.generations):
            if st.generation < stepped_until.get(st.seed, 0) or not (compiles and compiled_loop.applies(settings, evaluator, st)):
                stepped.append(st)
                continue
            stop = min(settings.generations, st.generation + CHUNK, (st.generation // every + 1) * every if every else settings.generations)
            chunks.setdefault((st.generation, stop), []).append(st)
        for (start, stop), together in chunks.items():
            for calls in _calls(together):
                if stopping.requested():  # the seeds not advanced yet stay where they are
                    stepped = []
                    break
                now = time.perf_counter()
                began.update((st.seed, now) for st in calls)
                if not compiled_loop.advance_seeds(calls, settings, evaluator, stop - start):
                    for st in calls:
                        del began[st.seed]
                        stepped_until[st.seed] = stop
                        stepped.append(st)
        if stepped:
            advance_lockstep(stepped, settings, evaluator)
        records = [seed_record(st, first, settings, evaluator) for st, first in zip(active, firsts)]
        for st, record in zip(active, records):
            writer.write(st, record, began.get(st.seed))
        progress(sum(st.generation - first for st, first in zip(active, firsts)))
        active = [st for st in active if st.generation < settings.generations and not st.es.diverged]


def _calls(together: list) -> list:
    """Seeds at the same generation and chunk end, split into the compiled calls that advance them: as few as
    :data:`~imix_cli.core.mixing.compiled_generation.SEEDS_PER_CALL` allows, of near-equal sizes (13 seeds: 7 and 6, not 8
    and 5), so that each call's generation has as many fresh members as can be for the episode kernel's lanes."""
    from imix_cli.core.mixing.compiled_generation import SEEDS_PER_CALL

    calls = -(-len(together) // SEEDS_PER_CALL)
    size, extra = divmod(len(together), calls)
    bounds = [0]
    for c in range(calls):
        bounds.append(bounds[-1] + size + (c < extra))
    return [together[a:b] for a, b in zip(bounds, bounds[1:])]


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
    if not es_seed_finished(frame, spec.generations):  # continue it from its final state
        if not checkpoint_path(run_dir, seed).exists():
            raise RunError(
                f"{path}: has {len(frame)} of {spec.generations} generations and no final state to continue from "
                f"({checkpoint_path(run_dir, seed).name} missing: made with checkpoint_every=0); "
                "move it away or choose another experiment="
            )
        return True
    # A finished seed whose policy file is there but cannot be read back (truncated, damaged): its files are written
    # again from its final state -- or, with none (checkpoint_every=0), by running it again (_say_policy_rebuild).
    return bool(unreadable_policies(run_dir, seed))


def unreadable_policies(run_dir, seed: int) -> list[str]:
    """The one-line refusal (:class:`~imix_cli.running.files.policy_files.PolicyFileError`) of each policy file of seed
    ``seed`` that exists but cannot be read back as data (:func:`~imix_cli.running.files.policy_files.read_policy`).
    A missing file is not one: a diverged seed writes none."""
    from imix_cli.running.files.policy_files import WHICH, PolicyFileError, policy_path, read_policy

    broken = []
    for which in WHICH:
        path = policy_path(run_dir, seed, which)
        if os.path.lexists(path):
            try:
                read_policy(path)
            except PolicyFileError as err:
                broken.append(str(err))
    return broken


def _say_policy_rebuild(spec, seed: int, st, generations: int) -> None:
    """One line for a finished seed run again only because a policy file of its cannot be read back
    (:func:`needs_running`): rebuilt from its final state (``st`` at ``generations``: only its files are written), or
    run again from generation 0 (no final state: ``checkpoint_every=0``). Before, a truncated ``policy_0_mean.npz`` was
    left as it was: "0 seed(s) run now" (issue 47, case 11)."""
    from imix_cli.running.files.results import seed_csv_path

    if not seed_csv_path(spec.run_dir, seed).exists() or (st is not None and st.generation < generations):
        return  # a seed continued to more generations writes its policy files anew at its end all the same
    broken = unreadable_policies(spec.run_dir, seed)
    if not broken:
        return
    more = f" (and {len(broken) - 1} other policy file)" if len(broken) > 1 else ""
    how = f"rebuilding {'them' if more else 'it'} from seed {seed}'s final checkpoint"
    if st is None:
        how = f"seed {seed} has no final state to rebuild {'them' if more else 'it'} from (checkpoint_every=0): running it again from generation 0"
    warn(f"{broken[0]}{more}; {how}")
