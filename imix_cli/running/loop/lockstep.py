"""The lockstep step: one generation of several seeds of one run, with one batched rollout -- no files.

What the step reads of the run is resolved once, up front, into :class:`LoopSettings` (:func:`loop_settings`);
a step changes the seeds' states (:class:`SeedState`) and each seed's step ends in a plain
:class:`SeedRecord`: its new rows, and what of its files falls due -- for the run's writer
(:mod:`imix_cli.running.files.run_writer`) to write.

Every seed advances one generation at a time *in lockstep*, and the members that need an
episode -- of all the seeds given -- are rolled out as one batch: with mixing on, only a few
members per seed are fresh, and sharing one rollout is what keeps the per-step overhead low.
Each seed's generation itself is :mod:`imix_cli.core.mixing.generation`'s (plan, evaluate, finish).

Reproducibility: seed ``k`` owns two random streams derived from ``SeedSequence(k)`` -- one for
sampling and mixing, one for episode seeds -- and every episode's initial state comes from its
own episode seed. A seed's rows are therefore identical whatever the other seeds sharing its
batch, or whether it was resumed from a checkpoint (:class:`SeedState` is what is saved).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from imix_cli.core.algorithms import make_es
from imix_cli.core.divergence import GuardedES
from imix_cli.core.evaluation.policies import ObsNormalizer, searched_params, with_zero_biases
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation


@dataclass
class SeedState:
    """Everything seed ``seed`` needs to continue; saved whole as its checkpoint (field by field,
    by type: see :mod:`imix_cli.running.files.checkpoints`, which needs no change when a field is added)."""

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
    obs_norm: object = None  # policy.obs_norm: this seed's ObsNormalizer (imix_cli.core.evaluation.policies)
    # eval_mean_every: episode seeds for measuring the distribution mean, a stream of its own so the
    # measurement never changes training; and the episodes spent on it so far.
    mean_eval_rng: np.random.Generator | None = None
    mean_policy_episodes: int = 0

    @property
    def generation(self) -> int:
        return len(self.rows)


@dataclass(frozen=True)
class LoopSettings:
    """What the loop reads of a run (a :class:`imix_cli.running.config.run_spec.RunSpec` and its evaluator), once."""

    algo: str  # the rows' algo, env and mixing labels
    env: str
    mixing_name: str
    popsize: int
    generations: int
    dim: int  # the parameters the ES searches (:func:`search_dim`)
    obs_dim: int  # the policy's inputs
    es_options: dict  # make_es's keyword arguments but the dimension: popsize, sigma, lr, weight decay, algo options
    mixing: MixingSettings
    obs_norm_warmup: int | None  # policy.obs_norm's warm-up; None: no observation normaliser
    obs_var_floor: float  # policy.obs_var_floor
    policy_bias: bool
    eval_mean_every: int
    eval_mean_episodes: int
    checkpoint_every: int  # 0: no checkpoints (as for an ES that has no state dict)
    obs_norm_freeze: bool = True  # policy.obs_norm_freeze: false, the statistics keep updating and the archive is re-expressed


def loop_settings(spec, evaluator) -> LoopSettings:
    """What the loop needs of run ``spec``, resolved once; the evaluator gives the policy's dimension."""
    es_options = dict(
        popsize=spec.popsize, sigma=spec.sigma, lr=spec.lr, weight_decay=spec.weight_decay, weight_decay_form=spec.weight_decay_form,
        **spec.algo_options,
    )  # fmt: skip
    mixing = mixing_settings(spec)
    return LoopSettings(
        spec.algo, spec.env_name, spec.mixing, spec.popsize, spec.generations, search_dim(spec, evaluator), evaluator.obs_dim, es_options, mixing,
        spec.obs_norm_warmup if spec.obs_norm else None, spec.obs_var_floor, spec.policy_bias, spec.eval_mean_every, spec.eval_mean_episodes,
        spec.checkpoint_every, spec.obs_norm_freeze,
    )  # fmt: skip


@dataclass(frozen=True)
class SeedRecord:
    """What a seed's step did, for the writer: ``st.rows[first:]`` are new, and what falls due at the last."""

    first: int
    diverged: str | None  # why the search diverged at the last row (marked ``diverged``): the seed ends there
    finished: bool  # the run's last generation: the seed's CSV and policy files are due
    checkpoint: bool  # a checkpoint is due: at the seed's end (its final state) or every checkpoint_every generations
    mean_policy: np.ndarray | None  # finished: the distribution mean as the policy it is (policy_<k>_mean.npz)


def seed_record(st: SeedState, first: int, settings: LoopSettings, evaluator) -> SeedRecord:
    """The record of seed ``st``'s rows from ``first`` on; a diverged seed's last row is marked here."""
    diverged = st.es.diverged
    if diverged:
        st.rows[-1]["diverged"] = 1
    finished = not diverged and st.generation == settings.generations
    every = settings.checkpoint_every
    checkpoint = not diverged and bool(every) and (finished or st.generation % every == 0)
    mean = policy_params(settings, st, st.es.distribution.mean[None, :], evaluator)[0] if finished else None
    return SeedRecord(first, diverged, finished, checkpoint, mean)


#: Spawn key of the episode seeds that measure the distribution mean (training uses the spawn keys 0
#: and 1 of SeedSequence(seed), ``imix eval`` 0x6576616C "eval"): "mean".
MEAN_EVAL_STREAM = 0x6D65616E


def new_seed_state(settings: LoopSettings, seed: int) -> SeedState:
    """Seed ``seed`` of a run at generation 0."""
    sample_seq, episode_seq = np.random.SeedSequence(seed).spawn(2)
    es = GuardedES(make_es(settings.algo, settings.dim, **settings.es_options))
    obs_norm = None
    if settings.obs_norm_warmup is not None:
        obs_norm = ObsNormalizer(settings.obs_dim, settings.obs_norm_warmup, settings.obs_var_floor, freeze=settings.obs_norm_freeze)
    mean_eval_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(MEAN_EVAL_STREAM,)))
    return SeedState(
        seed, es, np.random.default_rng(sample_seq), np.random.default_rng(episode_seq), obs_norm=obs_norm, mean_eval_rng=mean_eval_rng
    )  # fmt: skip


def mixing_settings(spec) -> MixingSettings:
    return MixingSettings(variant=spec.variant, eim_generations=spec.eim_generations, alpha=spec.im_alpha, reeval_age=spec.reeval_age,
                          reeval_prob=spec.reeval_prob, reeval_count=spec.reeval_count, min_fresh=spec.min_fresh)  # fmt: skip


def generation_row(settings: LoopSettings, st: SeedState, fitness: np.ndarray, reused: tuple, sigma_mean: float) -> dict:
    """The CSV row of seed ``st``'s generation ``st.generation`` (its columns: :data:`imix_cli.running.files.results.COLUMNS`),
    with the seed's totals (``evaluations``, ``env_steps``) counted up to it. ``fitness``: one return per member,
    stored or new; non-finite returns (a user's env may produce them) are left out of the mean and best, and counted.
    ``reused``: (reused, from the previous generation, from older ones, re-evaluated).
    ``wall_time`` is 0.0, for the caller, which owns the clock, to fill in; the ``mean_policy_*``
    columns are added by whoever measures the distribution mean."""
    finite = np.isfinite(fitness)
    scores = (float(np.mean(fitness[finite])), float(np.max(fitness[finite]))) if finite.any() else (float("nan"), float("nan"))
    return scored_row(settings, st, scores, reused, sigma_mean, int(np.count_nonzero(~finite)))


def scored_row(settings: LoopSettings, st: SeedState, scores: tuple, reused: tuple, sigma_mean: float, nonfinite: int = 0) -> dict:
    """:func:`generation_row` from the generation's ``scores`` = (mean, best) of its finite returns, computed by the
    caller (the compiled loop: numpy's mean of each row of its chunk's returns at once, the same numbers)."""
    reused_all, reused_im, reused_eim, reevaluated = reused
    return {
        "algo": settings.algo, "env": settings.env, "mixing": settings.mixing_name, "seed": st.seed, "generation": st.generation,
        "evaluations": st.evaluations, "env_steps": st.env_steps, "mean_score": scores[0], "best_score": scores[1],
        "reused": reused_all, "reused_im": reused_im, "reused_eim": reused_eim, "reevaluated": reevaluated,
        "popsize": settings.popsize, "sigma_mean": sigma_mean, "nonfinite": nonfinite, "wall_time": 0.0,
    }  # fmt: skip


def advance_lockstep(states: list[SeedState], settings: LoopSettings, evaluator, plan=plan_generation) -> None:
    """Run one generation of every seed in ``states``, with one batched rollout for all members to evaluate.

    ``plan``: the planning half of the generation step (:func:`imix_cli.core.mixing.generation.plan_generation`,
    which mixes); a benchmark passes a timed one instead of patching a module.
    """
    # policy.obs_norm: during a seed's warm-up, its generations neither mix nor enter the archive (the statistics
    # change a lot and there is nothing to reuse yet); after it, the statistics are frozen, or they keep updating
    # (policy.obs_norm_freeze=false) and the archive is re-expressed under every new statistics (reexpress_archive).
    warming = [st.obs_norm is not None and st.obs_norm.warming for st in states]
    mixing = [dataclasses.replace(settings.mixing, variant=None) if w else settings.mixing for w in warming]
    plans = [plan(st.es, st.archive, m, st.sample_rng) for st, m in zip(states, mixing)]
    points = [p.points for p in plans]  # the members to evaluate, then any probes (CMA-ES's TPA): all are episodes
    episode_seeds = [st.episode_rng.integers(0, np.iinfo(np.int64).max, size=len(x), dtype=np.int64) for st, x in zip(states, points)]
    returns, steps = evaluator.evaluate(
        np.concatenate([policy_params(settings, st, x, evaluator) for st, x in zip(states, points)]),
        np.concatenate(episode_seeds),
    )
    offset = 0
    for st, p, x, m, warm in zip(states, plans, points, mixing, warming):
        g, n = p.generation, len(x)
        dist = st.es.distribution  # the distribution g was drawn from, before tell moves it
        fitness = finish_generation(st.es, st.archive, m, p, st.es.training_fitness(returns[offset : offset + n], steps[offset : offset + n]))
        updating = st.obs_norm is not None and not st.obs_norm.frozen
        if updating:  # the statistics absorb this generation's observations (after its best is kept)
            sums, sumsqs = evaluator.last_obs_stats
            observed = (sums[offset : offset + n], sumsqs[offset : offset + n], steps[offset : offset + n])
        st.evaluations += n
        st.env_steps += int(steps[offset : offset + n].sum())
        offset += n
        reused = (g.reused, g.reused_from_previous, g.reused_from_older, p.reevaluated)
        st.rows.append(generation_row(settings, st, fitness, reused, dist.sigma_mean))
        finite = np.isfinite(fitness)
        if finite.any() and np.max(fitness[finite]) > st.best_return:  # strictly better: the first best is kept
            top = np.flatnonzero(finite)[np.argmax(fitness[finite])]
            # with policy.obs_norm, as the policy on raw observations it was evaluated as
            st.best_params, st.best_return = policy_params(settings, st, g.samples[top : top + 1], evaluator)[0], float(fitness[top])
        if updating:
            before = (st.obs_norm.mean, st.obs_norm.std)
            st.obs_norm.add(*observed)
            st.obs_norm.end_generation()
            if not warm:
                reexpress_archive(settings, st, before, evaluator)
    measure_distribution_means(states, settings, evaluator)


def reexpress_archive(settings: LoopSettings, st: SeedState, before: tuple, evaluator) -> None:
    """``policy.obs_norm_freeze=false``: the seed's statistics moved from ``before`` (mean, std) to its normaliser's
    current ones; every archived member becomes the same policy under the new statistics, its generation's
    distribution the pushforward (:meth:`imix_cli.core.mixing.generation.Archive.reexpress`, :class:`imix_cli.core.evaluation.policies.NormalizerChange`).
    Exact with biases only: ``imix run`` refuses mixing with ``policy.bias=false`` here."""
    if not st.archive.generations:
        return
    if not settings.policy_bias:
        raise ValueError("policy.obs_norm_freeze=false with mixing needs policy.bias=true (a change of mean needs a bias to re-express it)")
    change = st.obs_norm.change(*before, evaluator.out_dim, evaluator.hidden)
    if np.array_equal(change.mean0, change.mean1) and np.array_equal(change.std0, change.std1):
        return  # no observation this generation (every member reused): nothing changed
    st.archive.reexpress(change)


def measure_distribution_means(states: list[SeedState], settings: LoopSettings, evaluator) -> None:
    """Fill the last row's ``mean_policy_*`` columns; every ``eval_mean_every`` generations, the return of
    each seed's distribution mean on ``eval_mean_episodes`` fresh episodes, all seeds in one batch.
    ES papers report this policy -- the one a user deploys -- rather than the population's mean return. Its episodes are counted apart, never as evaluations."""
    every, episodes = settings.eval_mean_every, settings.eval_mean_episodes
    due = []
    for st in states:
        st.rows[-1]["mean_policy_score"] = float("nan")
        mean = st.es.distribution.mean
        # Only at multiples of eval_mean_every (not also at the last generation): a run continued to more
        # generations must measure exactly where the longer run made at once measures.
        if every and st.generation % every == 0 and np.all(np.isfinite(mean)):
            due.append(st)
    if due:
        params = np.concatenate([np.repeat(policy_params(settings, st, st.es.distribution.mean[None, :], evaluator), episodes, axis=0) for st in due])
        seeds = np.concatenate([st.mean_eval_rng.integers(0, np.iinfo(np.int64).max, size=episodes, dtype=np.int64) for st in due])
        returns, _ = evaluator.evaluate(params, seeds)
        for k, st in enumerate(due):
            mine = returns[k * episodes : (k + 1) * episodes]
            mine = mine[np.isfinite(mine)]
            st.rows[-1]["mean_policy_score"] = float(np.mean(mine)) if mine.size else float("nan")
            st.mean_policy_episodes += episodes
    for st in states:
        st.rows[-1]["mean_policy_episodes"] = st.mean_policy_episodes


def search_dim(spec, evaluator) -> int:
    """The number of parameters the ES searches: the policy's, or its weights' with ``policy.bias=false``."""
    return searched_params(evaluator.obs_dim, evaluator.out_dim, evaluator.hidden, spec.policy_bias)


def policy_params(settings: LoopSettings, st: SeedState, params: np.ndarray, evaluator) -> np.ndarray:
    """ES points ``params`` (B, search_dim) as the evaluator's policies (B, num_params) on raw
    observations: zero biases put back (``policy.bias=false``), then the seed's normaliser folded
    in, if any (the fold gives the first layer a bias even where the policy had none)."""
    params = np.array(params, dtype=np.float64)
    if not settings.policy_bias:
        params = with_zero_biases(params, evaluator.obs_dim, evaluator.out_dim, evaluator.hidden)
    if st.obs_norm is None:
        return params
    return st.obs_norm.fold(params, evaluator.out_dim, evaluator.hidden)
