"""The runner: the only module that wires ES, mixing, evaluation and results together.

One run = one config (algo, env, mixing, hyper-parameters) x ``seeds`` seeds. Its seeds are
split over ``workers`` processes (spawn-safe). Inside a process, every seed advances one
generation at a time *in lockstep*, and the members that need an episode -- of all its seeds
-- are rolled out as one batch: with mixing on, only a few members per seed are fresh, and
sharing one rollout is what keeps the per-step overhead low.

Reproducibility: seed ``k`` owns two random streams derived from ``SeedSequence(k)`` --
one for sampling and mixing, one for episode seeds -- and every episode's initial state comes
from its own episode seed. A seed's CSV is therefore identical whatever the worker count,
the other seeds sharing its batch, or whether it was resumed from a checkpoint.

Files (see :mod:`imix_cli.results`): ``seed_<k>.csv`` is written atomically when seed ``k``
finishes; a checkpoint of its whole state (ES, archive, RNG states, rows so far) is written
atomically every ``checkpoint_every`` generations to ``.checkpoints/seed_<k>.npz`` (plain data,
see :mod:`imix_cli.checkpoints`) and deleted once the CSV exists. Re-running the same command
skips finished seeds and resumes the others from their checkpoints, saying so on stderr
(``seed k resumes at generation G``); a checkpoint that is damaged or of another config is
refused with one warning line and its seed restarts from scratch.

algo=ddpg (the deep-RL baseline of the paper's section 4.3) uses the same run folder, process
pool and CSV contract, but its own seed loop (section "algo=ddpg" below): seeds run one after
another in each worker, one CSV row per finished episode, no mid-run checkpoint.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import queue as queue_module
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imix_cli.algorithms import make_es
from imix_cli.checkpoints import load_or_warn, write_checkpoint
from imix_cli.config import RunSpec, differing_keys, identity_of, resume_identity
from imix_cli.divergence import GuardedES
from imix_cli.generation import Archive, MixingSettings, finish_generation, plan_generation
from imix_cli.parallel_evaluation import build_evaluator
from imix_cli.policies import ObsNormalizer
from imix_cli.policy_files import write_seed_policies
from imix_cli.results import (
    CorruptResultError,
    atomic_write_text,
    partial_csv_path,
    read_run_csv,
    rows_to_frame,
    seed_csv_path,
    write_run_csv,
)
from imix_cli.stats import mean_ci


class RunError(RuntimeError):
    """A run cannot proceed (existing results conflict, unwritable folder...); one-line message."""


# ----------------------------------------------------------------------------- one seed's state
@dataclass
class SeedState:
    """Everything seed ``seed`` needs to continue; saved whole as its checkpoint (field by field,
    by type: see :mod:`imix_cli.checkpoints`, which needs no change when a field is added)."""

    seed: int
    es: object
    sample_rng: np.random.Generator  # sampling and mixing
    episode_rng: np.random.Generator  # one episode seed per fresh member
    archive: Archive = field(default_factory=Archive)  # earlier generations, their returns and ages
    rows: list = field(default_factory=list)
    evaluations: int = 0
    env_steps: int = 0
    elapsed: float = 0.0  # wall seconds spent on this seed before the current process took it
    # The best-ever member (a finite return, fresh or reused) and its return, for policy_<k>_best.npz:
    # a plain (d,) float64 array and a float so that checkpoints stay data. None / -inf until one exists.
    best_params: np.ndarray | None = None
    best_return: float = -np.inf
    obs_norm: object = None  # policy.obs_norm: this seed's ObsNormalizer (imix_cli.policies)
    # eval_mean_every: episode seeds for measuring the distribution mean, a stream of its own so the
    # measurement never changes training; and the episodes spent on it so far.
    mean_eval_rng: np.random.Generator | None = None
    mean_policy_episodes: int = 0

    @property
    def generation(self) -> int:
        return len(self.rows)


def new_seed_state(spec: RunSpec, seed: int, dim: int) -> SeedState:
    sample_seq, episode_seq = np.random.SeedSequence(seed).spawn(2)
    es = GuardedES(make_es(
        spec.algo, dim, popsize=spec.popsize, sigma=spec.sigma, lr=spec.lr,
        weight_decay=spec.weight_decay, weight_decay_form=spec.weight_decay_form, **spec.algo_options,
    ))  # fmt: skip
    mean_eval_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(MEAN_EVAL_STREAM,)))
    return SeedState(seed, es, np.random.default_rng(sample_seq), np.random.default_rng(episode_seq), mean_eval_rng=mean_eval_rng)


#: Spawn key of the episode seeds that measure the distribution mean (training uses the spawn keys 0
#: and 1 of SeedSequence(seed), ``imix eval`` 0x6576616C "eval"): "mean".
MEAN_EVAL_STREAM = 0x6D65616E


def mixing_settings(spec: RunSpec) -> MixingSettings:
    return MixingSettings(spec.variant, spec.eim_generations, spec.im_alpha, spec.reeval_age, spec.reeval_prob)


def advance_lockstep(states: list[SeedState], spec: RunSpec, evaluator) -> None:
    """Run one generation of every seed in ``states``, with one batched rollout for all members to evaluate."""
    mixing = mixing_settings(spec)
    # policy.obs_norm: while a seed's statistics still change (its warm-up), stored returns would
    # belong to another policy function, so its generation neither mixes nor enters the archive.
    warming = []
    for st in states:
        if spec.obs_norm and st.obs_norm is None:
            st.obs_norm = ObsNormalizer(evaluator.obs_dim, spec.obs_norm_warmup)
        warming.append(st.obs_norm is not None and not st.obs_norm.frozen)
    settings = [dataclasses.replace(mixing, variant=None) if w else mixing for w in warming]
    plans = [plan_generation(st.es, st.archive, s, st.sample_rng) for st, s in zip(states, settings)]
    episode_seeds = [st.episode_rng.integers(0, np.iinfo(np.int64).max, size=p.evaluate.size, dtype=np.int64) for st, p in zip(states, plans)]
    returns, steps = evaluator.evaluate(
        np.concatenate([raw_obs_params(st, p.generation.samples[p.evaluate], evaluator) for st, p in zip(states, plans)]),
        np.concatenate(episode_seeds),
    )
    offset = 0
    for st, plan, s, warm in zip(states, plans, settings, warming):
        g, n = plan.generation, plan.evaluate.size
        dist = st.es.distribution  # the distribution g was drawn from, before tell moves it
        fitness = finish_generation(st.es, st.archive, s, plan, returns[offset : offset + n])
        if warm:  # the warm-up: the statistics absorb this generation's observations (after its best is kept)
            sums, sumsqs = evaluator.last_obs_stats
            observed = (sums[offset : offset + n], sumsqs[offset : offset + n], steps[offset : offset + n])
        st.evaluations += n
        st.env_steps += int(steps[offset : offset + n].sum())
        offset += n
        finite = np.isfinite(fitness)
        st.rows.append(
            {
                "algo": spec.algo,
                "env": spec.env_name,
                "mixing": spec.mixing,
                "seed": st.seed,
                "generation": st.generation,
                "evaluations": st.evaluations,
                "env_steps": st.env_steps,
                # Non-finite returns (a user's env may produce them) are left out of the mean and counted.
                "mean_score": float(np.mean(fitness[finite])) if finite.any() else float("nan"),
                "best_score": float(np.max(fitness[finite])) if finite.any() else float("nan"),
                "reused": g.reused,
                "reused_im": g.reused_from_previous,
                "reused_eim": g.reused_from_older,
                "reevaluated": plan.reevaluated,
                "popsize": spec.popsize,
                "sigma_mean": dist.sigma_mean,
                "nonfinite": int(np.count_nonzero(~finite)),
                "wall_time": 0.0,  # filled in by the caller, which owns the clock
            }
        )
        if finite.any() and np.max(fitness[finite]) > st.best_return:  # strictly better: the first best is kept
            top = np.flatnonzero(finite)[np.argmax(fitness[finite])]
            # with policy.obs_norm, as the policy on raw observations it was evaluated as
            st.best_params, st.best_return = raw_obs_params(st, g.samples[top : top + 1], evaluator)[0], float(fitness[top])
        if warm:
            st.obs_norm.add(*observed)
            st.obs_norm.end_generation()
    measure_distribution_means(states, spec, evaluator)


def measure_distribution_means(states: list[SeedState], spec: RunSpec, evaluator) -> None:
    """Fill the last row's ``mean_policy_*`` columns; every ``eval_mean_every`` generations, the return of each seed's distribution mean on ``eval_mean_episodes`` fresh episodes,
    all seeds in one batch. ES papers report this policy -- the one a user deploys -- rather than
    the population's mean return. Its episodes are counted apart, never as evaluations."""
    every, episodes = spec.eval_mean_every, spec.eval_mean_episodes
    due = []
    for st in states:
        st.rows[-1]["mean_policy_score"] = float("nan")
        mean = st.es.distribution.mean
        # Only at multiples of eval_mean_every (not also at the last generation): a run continued to more
        # generations must measure exactly where the longer run made at once measures.
        if every and st.generation % every == 0 and np.all(np.isfinite(mean)):
            due.append(st)
    if due:
        params = np.concatenate([np.repeat(raw_obs_params(st, st.es.distribution.mean[None, :], evaluator), episodes, axis=0) for st in due])
        seeds = np.concatenate([st.mean_eval_rng.integers(0, np.iinfo(np.int64).max, size=episodes, dtype=np.int64) for st in due])
        returns, _ = evaluator.evaluate(params, seeds)
        for k, st in enumerate(due):
            mine = returns[k * episodes : (k + 1) * episodes]
            mine = mine[np.isfinite(mine)]
            st.rows[-1]["mean_policy_score"] = float(np.mean(mine)) if mine.size else float("nan")
            st.mean_policy_episodes += episodes
    for st in states:
        st.rows[-1]["mean_policy_episodes"] = st.mean_policy_episodes


def raw_obs_params(st: SeedState, params: np.ndarray, evaluator) -> np.ndarray:
    """``params`` (B, d) as a policy on raw observations: the seed's normaliser folded in, if any."""
    if st.obs_norm is None:
        return np.array(params, dtype=np.float64)
    return st.obs_norm.fold(params, evaluator.out_dim, evaluator.hidden)


# ----------------------------------------------------------------------------- files of a run
def checkpoint_path(run_dir: Path, seed: int) -> Path:
    return Path(run_dir) / ".checkpoints" / f"seed_{seed}.npz"


def legacy_checkpoint_path(run_dir: Path, seed: int) -> Path:
    """Where imix 0.1 kept a pickled checkpoint: never opened (unpickling runs code), only removed."""
    return Path(run_dir) / ".checkpoints" / f"seed_{seed}.pkl"


def save_checkpoint(run_dir: Path, st: SeedState, identity: dict) -> None:
    write_checkpoint(checkpoint_path(run_dir, st.seed), st, identity=identity, seed=st.seed, generation=st.generation)


def load_checkpoint(run_dir: Path, seed: int, identity: dict, fresh: SeedState, warn=None) -> SeedState | None:
    """The saved state of ``seed`` (built on ``fresh``, a new state of the same run and seed), or None.

    None if there is no checkpoint, or -- after one warning line naming the file and why --
    if it is damaged, of another seed or config, or a pickle of an older imix.
    """
    legacy = legacy_checkpoint_path(run_dir, seed)
    if legacy.exists():
        (warn or _warn)(f"{legacy}: checkpoint ignored: a pickle (older imix), never opened since loading it could run code; seed {seed} restarts from scratch")
    st = load_or_warn(checkpoint_path(run_dir, seed), fresh, identity=identity, seed=seed, warn=warn)
    if st is not None and (st.seed != seed or st.generation != len(st.rows)):
        (warn or _warn)(f"{checkpoint_path(run_dir, seed)}: checkpoint ignored: inconsistent state; seed {seed} restarts from scratch")
        return None
    return st


def _can_checkpoint(es) -> bool:
    """Whether ``es`` has a state dict; if not, say once that its seeds will not be checkpointed."""
    try:
        es.state_dict()
    except NotImplementedError:
        _warn(f"algo={es.name} cannot be checkpointed yet: a killed run restarts its unfinished seeds")
        return False
    return True


def _warn(message: str) -> None:
    print(f"imix: warning: {message}", file=sys.stderr, flush=True)


def _remove_checkpoints(run_dir: Path, seed: int, keep_final: bool = False) -> None:
    """A finished seed's checkpoints (and its live-view partial CSV) are no longer needed -- but for
    its final state (``keep_final``), from which a larger ``generations=`` continues the seed."""
    if not keep_final:
        checkpoint_path(run_dir, seed).unlink(missing_ok=True)
    legacy_checkpoint_path(run_dir, seed).unlink(missing_ok=True)
    partial_csv_path(run_dir, seed).unlink(missing_ok=True)


def prepare_run_dir(spec: RunSpec) -> list[int]:
    """Create the run folder, check/write config.yaml, and return the seeds still to run.

    Raises RunError if the folder holds results of a different config or a corrupt CSV;
    nothing existing is overwritten.
    """
    import yaml

    run_dir = spec.run_dir
    config_file = run_dir / "config.yaml"
    _make_run_dir(spec)
    if config_file.exists():
        try:
            existing = yaml.safe_load(config_file.read_text())
        except Exception as err:
            raise RunError(f"{config_file}: unreadable ({type(err).__name__}); move it away or choose another experiment=") from None
        if not isinstance(existing, dict):
            raise RunError(f"{config_file}: not a config mapping; move it away or choose another experiment=")
        old, new = identity_of(existing), spec.identity()
        differing = differing_keys(resume_identity(old), resume_identity(new))
        if differing:
            changes = ", ".join(f"{k}={old.get(k)!r} there, {new.get(k)!r} now" for k in differing)
            raise RunError(
                f"{config_file} holds a different config ({changes}); "
                "choose another experiment= or move that folder away"
            )
        if spec.algo != "ddpg" and isinstance(old.get("generations"), int) and old["generations"] > spec.generations:
            raise RunError(
                f"{config_file} holds a different config (generations={old['generations']} there, {spec.generations} now): "
                "a run can be continued to more generations, not shortened; choose another experiment= or move that folder away"
            )
    continued = config_file.exists() and spec.algo != "ddpg" and old.get("generations") != spec.generations
    todo = []
    for seed in range(spec.seeds):
        path = seed_csv_path(run_dir, seed)
        if not path.exists():
            todo.append(seed)
            continue
        try:
            frame = read_run_csv(path)
        except CorruptResultError as err:
            raise RunError(f"{err}; move or delete it, then re-run") from None
        partial_csv_path(run_dir, seed).unlink(missing_ok=True)  # left by a kill between the CSV and its clean-up
        if spec.algo == "ddpg":
            if int(frame["env_steps"].iloc[-1]) > spec.total_steps:
                raise RunError(f"{path}: has {int(frame['env_steps'].iloc[-1])} env steps, config asks for {spec.total_steps}; move it away or choose another experiment=")
        elif len(frame) > spec.generations:
            raise RunError(f"{path}: has {len(frame)} generations, config asks for {spec.generations}; move it away or choose another experiment=")
        elif len(frame) < spec.generations and frame["diverged"].iloc[-1] != 1:  # continue it from its final state
            if not checkpoint_path(run_dir, seed).exists():
                raise RunError(
                    f"{path}: has {len(frame)} of {spec.generations} generations and no final state to continue from "
                    f"({checkpoint_path(run_dir, seed).name} missing: made with checkpoint_every=0 or an older imix); "
                    "move it away or choose another experiment="
                )
            todo.append(seed)
    if not config_file.exists() or continued:  # new, or continued to more generations
        atomic_write_text(config_file, yaml.safe_dump(spec.config, sort_keys=False))
    # Temporaries of writes cut short by a kill are never at a final name; clear them away. (run()
    # holds the folder's lock, so no other live run is writing them; an orphaned worker of a
    # killed run exits within a second and only loses a write that is redone on resume.)
    for stale in [*run_dir.glob(".*.tmp"), *run_dir.glob(".checkpoints/.*.tmp")]:
        stale.unlink(missing_ok=True)
    return todo


def _make_run_dir(spec: RunSpec) -> None:
    run_dir = spec.run_dir
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RunError(f"results_dir={spec.results_dir!r}: cannot create {run_dir} ({err.strerror or err})") from None
    if not os.access(run_dir, os.W_OK):
        raise RunError(f"results_dir={spec.results_dir!r}: {run_dir} is not writable")


LOCK_NAME = ".lock"


@contextlib.contextmanager
def run_dir_lock(spec: RunSpec):
    """Hold the run folder's lock for the ``with`` block; RunError at once if another run holds it.

    ``fcntl.flock`` on ``<run_dir>/.lock``: the kernel drops the lock when its holder exits,
    however it dies (kill -9 included), so a stale lock file never blocks a re-run. The file
    holds the holder's pid, for the message.
    """
    import fcntl

    _make_run_dir(spec)
    path = spec.run_dir / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise RunError(f"{spec.run_dir} is in use by another imix run (pid {holder}); wait for it to end, or choose another experiment=") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


# ----------------------------------------------------------------------------- a worker's job
_progress_queue = None


def _init_worker(progress_queue) -> None:
    global _progress_queue
    _progress_queue = progress_queue
    # Ctrl-C reaches the whole process group: the main process alone decides, and stops us.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_when_orphaned, args=(os.getppid(),), daemon=True).start()


def _exit_when_orphaned(parent_pid: int) -> None:
    """A pool worker whose main process died (kill -9) must not linger, idle on the task queue
    forever or racing the re-run: it exits within a second (its checkpoints stay valid)."""
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(1)


def run_seeds(spec: RunSpec, seeds: list[int], progress=None) -> list[int]:
    """Run ``seeds`` of ``spec`` to completion in this process, in lockstep; return them.

    ``progress(n)`` is called with the number of seed-generations just completed
    (algo=ddpg: environment steps; see :func:`run_ddpg_seeds`).
    """
    progress = progress or _queue_progress
    if spec.algo == "ddpg":
        return run_ddpg_seeds(spec, seeds, progress)
    evaluator = build_evaluator(spec)
    identity = resume_identity(spec.identity())  # a run continued to more generations resumes too
    run_dir = spec.run_dir
    states = []
    for seed in seeds:
        # A refused checkpoint may have been half loaded into the ES it was given: start from a new one.
        st = load_checkpoint(run_dir, seed, identity, new_seed_state(spec, seed, evaluator.num_params))
        st = st or new_seed_state(spec, seed, evaluator.num_params)
        states.append(st)
        if st.generation:
            print(f"imix: seed {seed} resumes at generation {st.generation} from {checkpoint_path(run_dir, seed)}", file=sys.stderr, flush=True)
            progress(st.generation)
    checkpoint_every = spec.checkpoint_every if states and _can_checkpoint(states[0].es) else 0
    started = time.perf_counter()
    active = [st for st in states if st.generation < spec.generations]
    while active:
        advance_lockstep(active, spec, evaluator)
        now = time.perf_counter() - started
        for st in active:
            st.rows[-1]["wall_time"] = st.elapsed + now
            if end_if_diverged(st):
                write_run_csv(seed_csv_path(run_dir, st.seed), rows_to_frame(st.rows))
                _remove_checkpoints(run_dir, st.seed)
            elif st.generation == spec.generations:
                write_seed_policies(spec, st.seed, evaluator, raw_obs_params(st, st.es.distribution.mean[None, :], evaluator)[0], st.best_params, st.best_return, st.generation)
                write_run_csv(seed_csv_path(run_dir, st.seed), rows_to_frame(st.rows))
                if checkpoint_every:  # the final state: `generations=` larger continues from it
                    elapsed, st.elapsed = st.elapsed, st.elapsed + now
                    save_checkpoint(run_dir, st, identity)
                    st.elapsed = elapsed
                _remove_checkpoints(run_dir, st.seed, keep_final=bool(checkpoint_every))
            elif checkpoint_every and st.generation % checkpoint_every == 0:
                elapsed, st.elapsed = st.elapsed, st.elapsed + now
                save_checkpoint(run_dir, st, identity)
                write_run_csv(partial_csv_path(run_dir, st.seed), rows_to_frame(st.rows))  # live view (imix status/plot)
                st.elapsed = elapsed
        progress(len(active))
        active = [st for st in active if st.generation < spec.generations and not st.es.diverged]
    for st in states:  # seeds resumed from a checkpoint taken after their last generation
        if not seed_csv_path(run_dir, st.seed).exists():
            write_seed_policies(spec, st.seed, evaluator, raw_obs_params(st, st.es.distribution.mean[None, :], evaluator)[0], st.best_params, st.best_return, st.generation)
            write_run_csv(seed_csv_path(run_dir, st.seed), rows_to_frame(st.rows))
            _remove_checkpoints(run_dir, st.seed)
    return list(seeds)


def end_if_diverged(st: SeedState) -> bool:
    """If seed ``st``'s search just diverged, mark its last row and say so (one line); return whether it did."""
    if not st.es.diverged:
        return False
    st.rows[-1]["diverged"] = 1
    _warn(f"seed {st.seed} diverged at generation {st.generation - 1} ({st.es.diverged}); its CSV ends there")
    return True


def _queue_progress(n: int) -> None:
    if _progress_queue is not None:
        _progress_queue.put(n)


# ============================================================================= algo=ddpg
# The DDPG baseline (stable-baselines3, through imix_cli.algorithms.ddpg, which knows SB3 and
# not files). Seed k is SB3's seed=k; a worker runs its seeds one after another with one torch
# thread. Each finished training episode is one CSV row: generation = episode index,
# evaluations = episodes so far, env_steps = steps so far, mean_score = best_score = the
# episode's return (on ContinuousCartPoleHard the sparse sum, which equals the dense return),
# reused* 0, popsize 1, sigma_mean = the OU noise's sigma, nonfinite 1 if the return is NaN/inf
# (mean_score then NaN). An episode still running when total_steps is spent is not a row.
#
# No checkpoint: SB3's state (replay buffer of up to 1e6 transitions, optimisers, noise) is
# not saved mid-run, so a DDPG seed killed before its CSV is written restarts from scratch
# when the command is re-run; finished seeds are skipped, like ES seeds.
def ddpg_row(spec: RunSpec, seed: int, episode, wall_time: float) -> dict:
    """The CSV row of one finished DDPG episode (an :class:`imix_cli.algorithms.ddpg.Episode`)."""
    finite = bool(np.isfinite(episode.ret))
    score = float(episode.ret) if finite else float("nan")
    return {
        "algo": spec.algo,
        "env": spec.env_name,
        "mixing": spec.mixing,
        "seed": seed,
        "generation": episode.index,
        "evaluations": episode.index + 1,
        "env_steps": episode.env_steps,
        "mean_score": score,
        "best_score": score,
        "reused": 0,
        "reused_im": 0,
        "reused_eim": 0,
        "reevaluated": 0,
        "mean_policy_score": float("nan"),
        "mean_policy_episodes": 0,
        "popsize": 1,
        "sigma_mean": float(spec.ddpg["ou_sigma"]),
        "nonfinite": 0 if finite else 1,
        "wall_time": wall_time,
    }


def run_ddpg_seeds(spec: RunSpec, seeds: list[int], progress) -> list[int]:
    """Train DDPG for each of ``seeds`` in turn and write its CSV; ``progress(n)`` gets env steps."""
    from imix_cli.algorithms.ddpg import make_ddpg, train_ddpg

    for seed in seeds:
        rows = []
        started = time.perf_counter()
        model = make_ddpg(spec.env_id, spec.ddpg, seed=seed, max_steps=spec.env_max_steps)
        train_ddpg(
            model,
            spec.total_steps,
            on_episode=lambda ep, seed=seed, started=started, rows=rows: rows.append(ddpg_row(spec, seed, ep, time.perf_counter() - started)),
            on_steps=progress,
            torch_threads=1,
        )
        model.env.close()
        write_run_csv(seed_csv_path(spec.run_dir, seed), rows_to_frame(rows))
    return list(seeds)


# ----------------------------------------------------------------------------- the whole run
def run(spec: RunSpec, echo=print) -> dict:
    """Run every unfinished seed of ``spec``; print and return the summary.

    The run folder is locked for the whole run (:func:`run_dir_lock`): a second run on it is
    refused with RunError before it touches anything.
    """
    with run_dir_lock(spec):
        return _run_locked(spec, echo)


def _run_locked(spec: RunSpec, echo) -> dict:
    todo = prepare_run_dir(spec)
    total = len(todo) * (spec.total_steps if spec.algo == "ddpg" else spec.generations)
    bar = _progress_bar(spec, total)
    started = time.perf_counter()
    if todo:
        workers = min(spec.workers, len(todo))
        chunks = [list(map(int, c)) for c in np.array_split(np.array(todo), workers)]
        if workers == 1:
            run_seeds(spec, chunks[0], progress=bar.update)
        else:
            _run_pool(spec, chunks, bar)
    bar.close()
    summary = summarize(spec)
    summary["wall_time"] = time.perf_counter() - started
    summary["seeds_run"] = len(todo)
    echo(format_summary(spec, summary))
    return summary


def _run_pool(spec: RunSpec, chunks: list[list[int]], bar) -> None:
    # One BLAS thread per process: the seeds already use every core.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    ctx = multiprocessing.get_context("spawn")
    progress_queue = ctx.Queue()
    pool = ProcessPoolExecutor(max_workers=len(chunks), mp_context=ctx, initializer=_init_worker, initargs=(progress_queue,))
    try:
        pending = {pool.submit(run_seeds, spec, chunk) for chunk in chunks}
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(progress_queue, bar)
            for future in done:
                future.result()  # re-raise a worker's error here
        _drain(progress_queue, bar)
    except BaseException:
        # Ctrl-C / SIGINT to this process alone, or a worker's error: stop the other workers now
        # rather than let them finish their seeds (what is checkpointed is kept; writes are atomic).
        _terminate_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=5)


def _drain(progress_queue, bar) -> None:
    while True:
        try:
            bar.update(progress_queue.get_nowait())
        except queue_module.Empty:
            return


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


def _progress_bar(spec: RunSpec, total: int):
    if not spec.progress or total == 0:
        return _NoBar()
    from tqdm import tqdm

    unit = "step" if spec.algo == "ddpg" else "gen"
    return tqdm(total=total, desc=spec.run_name, unit=unit, unit_scale=unit == "step", mininterval=0.5, dynamic_ncols=True)


# ----------------------------------------------------------------------------- the summary
#: Config keys that only say how (and whether) mixing is done: runs that differ in these alone are
#: "the same config with and without mixing", compared in the summary.
MIXING_KEYS = ("im", "eim", "im_variant", "im_alpha", "eim_generations", "mixing")


def summarize(spec: RunSpec, run_dir: Path | None = None) -> dict:
    """Final mean score +- 68 % CI over seeds, evaluations and env steps (total over seeds and per
    seed), reuse %, non-finite returns -- of ``spec``'s run folder, or of ``run_dir`` (a sibling)."""
    run_dir = spec.run_dir if run_dir is None else Path(run_dir)
    finals, evaluations, env_steps, reused, members, nonfinite, diverged = [], 0, 0, 0, 0, 0, 0
    mixing = spec.mixing
    paths = [seed_csv_path(run_dir, seed) for seed in range(spec.seeds)]
    if run_dir != spec.run_dir:  # a sibling: whatever seeds it has finished
        paths = sorted(run_dir.glob("seed_*[0-9].csv"))
    for path in paths:
        frame = read_run_csv(path)
        finals.append(float(frame["mean_score"].iloc[-1]))
        evaluations += int(frame["evaluations"].iloc[-1])
        env_steps += int(frame["env_steps"].iloc[-1])
        reused += int(frame["reused"].sum())
        members += int(frame["popsize"].sum())
        nonfinite += int(frame["nonfinite"].sum())
        mixing = str(frame["mixing"].iloc[0])
        diverged += int(frame["diverged"].iloc[-1] == 1)
    mean, half_width, _ = mean_ci(finals, level=0.68)
    n = max(len(paths), 1)
    return {
        "run": run_dir.name,
        "mixing": mixing,
        "seeds": len(paths),
        "final_mean_score": mean,
        "ci68": half_width,
        "evaluations": evaluations,  # total over seeds
        "evaluations_per_seed": evaluations / n,
        "env_steps": env_steps,  # total over seeds
        "env_steps_per_seed": env_steps / n,
        "reuse_percent": 100.0 * reused / members if members else 0.0,
        "nonfinite_returns": nonfinite,
        "diverged_seeds": diverged,
    }


def counterpart_runs(spec: RunSpec) -> list[Path]:
    """Sibling run folders of the same experiment holding the same config with other mixing settings
    (and at least one finished seed), e.g. the ``-none`` run of an ``-eim`` run."""
    import yaml

    mine = {k: v for k, v in spec.identity().items() if k not in MIXING_KEYS}
    found = []
    for other in sorted(spec.run_dir.parent.iterdir()):
        if other == spec.run_dir or not (other / "config.yaml").is_file() or not any(other.glob("seed_*[0-9].csv")):
            continue
        try:
            config = yaml.safe_load((other / "config.yaml").read_text())
        except Exception:  # an unreadable sibling is simply not compared
            continue
        if isinstance(config, dict) and {k: v for k, v in identity_of(config).items() if k not in MIXING_KEYS} == mine:
            found.append(other)
    return found


def format_summary(spec: RunSpec, s: dict) -> str:
    """The summary table: this run, then any sibling with the same config and other mixing, and the reduction."""
    rows = [s]
    for other in counterpart_runs(spec) if spec.algo != "ddpg" else []:
        try:
            rows.append(summarize(spec, other))
        except CorruptResultError:
            continue
    width = max(32, *(len(r["run"]) for r in rows))
    header = (
        f"{'run':<{width}} {'seeds':>5} {'final mean score (68% CI)':>26} {'episodes/seed':>14} "
        f"{'env steps/seed':>15} {'reuse':>7} {'non-finite':>10} {'diverged':>8}"
    )
    lines = [header]
    for r in rows:
        score = f"{r['final_mean_score']:.2f}" + (f" ± {r['ci68']:.2f}" if np.isfinite(r["ci68"]) else "")
        lines.append(
            f"{r['run']:<{width}} {r['seeds']:>5} {score:>26} {r['evaluations_per_seed']:>14,.0f} "
            f"{r['env_steps_per_seed']:>15,.0f} {r['reuse_percent']:>6.1f}% {r['nonfinite_returns']:>10} {r['diverged_seeds']:>8}"
        )
    without = [r for r in rows if r["mixing"] == "none"]
    with_mixing = [r for r in rows if r["mixing"] != "none"]
    for base in without[:1]:
        for r in with_mixing:
            if r["evaluations_per_seed"]:
                lines.append(
                    f"  {r['run']} vs {base['run']}: {base['evaluations_per_seed'] / r['evaluations_per_seed']:.2f}x fewer "
                    f"episodes for the same {spec.generations} generations (final mean score {r['final_mean_score']:.2f} vs "
                    f"{base['final_mean_score']:.2f}; sample efficiency to a threshold: imix plot)"
                )
    if "seeds_run" in s:
        lines.append(f"results: {spec.run_dir}/seed_*.csv  ({s['seeds_run']} seed(s) run now, {s['wall_time']:.1f} s)")
    return "\n".join(lines)
