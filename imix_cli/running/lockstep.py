"""The lockstep step: one generation of several seeds of one run, with one batched rollout -- no files.

Every seed advances one generation at a time *in lockstep*, and the members that need an
episode -- of all the seeds given -- are rolled out as one batch: with mixing on, only a few
members per seed are fresh, and sharing one rollout is what keeps the per-step overhead low.
Each seed's generation itself is :mod:`imix_cli.generation`'s (plan, evaluate, finish).

Reproducibility: seed ``k`` owns two random streams derived from ``SeedSequence(k)`` -- one for
sampling and mixing, one for episode seeds -- and every episode's initial state comes from its
own episode seed. A seed's rows are therefore identical whatever the other seeds sharing its
batch, or whether it was resumed from a checkpoint (:class:`SeedState` is what is saved).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from imix_cli.algorithms import make_es
from imix_cli.divergence import GuardedES
from imix_cli.generation import Archive, MixingSettings, finish_generation, plan_generation
from imix_cli.policies import ObsNormalizer, searched_params, with_zero_biases
from imix_cli.running.results import generation_row


@dataclass
class SeedState:
    """Everything seed ``seed`` needs to continue; saved whole as its checkpoint (field by field,
    by type: see :mod:`imix_cli.running.checkpoints`, which needs no change when a field is added)."""

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


#: Spawn key of the episode seeds that measure the distribution mean (training uses the spawn keys 0
#: and 1 of SeedSequence(seed), ``imix eval`` 0x6576616C "eval"): "mean".
MEAN_EVAL_STREAM = 0x6D65616E


def new_seed_state(spec, seed: int, dim: int) -> SeedState:
    """Seed ``seed`` of run ``spec`` (a :class:`imix_cli.running.run_spec.RunSpec`) at generation 0, for ``dim`` parameters."""
    sample_seq, episode_seq = np.random.SeedSequence(seed).spawn(2)
    es = GuardedES(make_es(
        spec.algo, dim, popsize=spec.popsize, sigma=spec.sigma, lr=spec.lr,
        weight_decay=spec.weight_decay, weight_decay_form=spec.weight_decay_form, **spec.algo_options,
    ))  # fmt: skip
    mean_eval_rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(MEAN_EVAL_STREAM,)))
    return SeedState(seed, es, np.random.default_rng(sample_seq), np.random.default_rng(episode_seq), mean_eval_rng=mean_eval_rng)


def mixing_settings(spec) -> MixingSettings:
    return MixingSettings(spec.variant, spec.eim_generations, spec.im_alpha, spec.reeval_age, spec.reeval_prob, spec.reeval_count)


def advance_lockstep(states: list[SeedState], spec, evaluator, plan=plan_generation) -> None:
    """Run one generation of every seed in ``states``, with one batched rollout for all members to evaluate.

    ``plan``: the planning half of the generation step (:func:`imix_cli.generation.plan_generation`,
    which mixes); a benchmark passes a timed one instead of patching a module.
    """
    mixing = mixing_settings(spec)
    # policy.obs_norm: while a seed's statistics still change (its warm-up), stored returns would
    # belong to another policy function, so its generation neither mixes nor enters the archive.
    warming = []
    for st in states:
        if spec.obs_norm and st.obs_norm is None:
            st.obs_norm = ObsNormalizer(evaluator.obs_dim, spec.obs_norm_warmup)
        warming.append(st.obs_norm is not None and not st.obs_norm.frozen)
    settings = [dataclasses.replace(mixing, variant=None) if w else mixing for w in warming]
    plans = [plan(st.es, st.archive, s, st.sample_rng) for st, s in zip(states, settings)]
    episode_seeds = [st.episode_rng.integers(0, np.iinfo(np.int64).max, size=p.evaluate.size, dtype=np.int64) for st, p in zip(states, plans)]
    returns, steps = evaluator.evaluate(
        np.concatenate([policy_params(spec, st, p.generation.samples[p.evaluate], evaluator) for st, p in zip(states, plans)]),
        np.concatenate(episode_seeds),
    )
    offset = 0
    for st, p, s, warm in zip(states, plans, settings, warming):
        g, n = p.generation, p.evaluate.size
        dist = st.es.distribution  # the distribution g was drawn from, before tell moves it
        fitness = finish_generation(st.es, st.archive, s, p, st.es.training_fitness(returns[offset : offset + n], steps[offset : offset + n]))
        if warm:  # the warm-up: the statistics absorb this generation's observations (after its best is kept)
            sums, sumsqs = evaluator.last_obs_stats
            observed = (sums[offset : offset + n], sumsqs[offset : offset + n], steps[offset : offset + n])
        st.evaluations += n
        st.env_steps += int(steps[offset : offset + n].sum())
        offset += n
        st.rows.append(generation_row(
            algo=spec.algo, env=spec.env_name, mixing=spec.mixing, seed=st.seed, generation=st.generation,
            evaluations=st.evaluations, env_steps=st.env_steps, fitness=fitness, reused=g.reused,
            reused_im=g.reused_from_previous, reused_eim=g.reused_from_older, reevaluated=p.reevaluated,
            popsize=spec.popsize, sigma_mean=dist.sigma_mean,
        ))  # fmt: skip
        finite = np.isfinite(fitness)
        if finite.any() and np.max(fitness[finite]) > st.best_return:  # strictly better: the first best is kept
            top = np.flatnonzero(finite)[np.argmax(fitness[finite])]
            # with policy.obs_norm, as the policy on raw observations it was evaluated as
            st.best_params, st.best_return = policy_params(spec, st, g.samples[top : top + 1], evaluator)[0], float(fitness[top])
        if warm:
            st.obs_norm.add(*observed)
            st.obs_norm.end_generation()
    measure_distribution_means(states, spec, evaluator)


def measure_distribution_means(states: list[SeedState], spec, evaluator) -> None:
    """Fill the last row's ``mean_policy_*`` columns; every ``eval_mean_every`` generations, the return of
    each seed's distribution mean on ``eval_mean_episodes`` fresh episodes, all seeds in one batch.
    ES papers report this policy -- the one a user deploys -- rather than the population's mean return. Its episodes are counted apart, never as evaluations."""
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
        params = np.concatenate([np.repeat(policy_params(spec, st, st.es.distribution.mean[None, :], evaluator), episodes, axis=0) for st in due])
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


def policy_params(spec, st: SeedState, params: np.ndarray, evaluator) -> np.ndarray:
    """ES points ``params`` (B, search_dim) as the evaluator's policies (B, num_params) on raw
    observations: zero biases put back (``policy.bias=false``), then the seed's normaliser folded
    in, if any (the fold gives the first layer a bias even where the policy had none)."""
    params = np.array(params, dtype=np.float64)
    if not spec.policy_bias:
        params = with_zero_biases(params, evaluator.obs_dim, evaluator.out_dim, evaluator.hidden)
    if st.obs_norm is None:
        return params
    return st.obs_norm.fold(params, evaluator.out_dim, evaluator.hidden)
