"""Does the way Swimmer's training episodes pick their start states decide ARS's outcome?

``python benchmarks/ars_sb3_gap.py resets`` runs sb3-contrib's ARS (N = b = 1) for 100 episodes on
seeds 0-9 with the episodes starting where its env's reset stream is (median mean-policy return
271) and with each episode at ``reset(seed=s)`` (41). Both are i.i.d. uniform start states on
+-0.1, independent of the directions, so on paper the two runs are one random process. The checks:

* ``replay``: sb3-contrib's ARS on seeds ``first .. last-1`` (its update, its torch directions),
  its candidates' episodes run by imix's evaluator from the start states sb3-contrib's own loop
  draws (its env's reset stream, every other reset: the ``DummyVecEnv``'s auto-reset comes
  between), next to sb3-contrib's own loop (``native``) and imix's evaluator on fresh
  ``reset(seed=s)`` (``fresh``); the first iterations' start states are checked against the ones
  the native loop's env really drew;
* ``arms``: one ARS loop (sb3-contrib's update for N = b = 1 in float64: a step of
  alpha * (r+ - r-) / std([r+, r-], ddof=1) * delta, alpha 0.02, sigma 0.01; numpy directions, the
  same for every arm of a seed; imix's evaluator, many seeds batched) on several ways to choose the
  training episodes' start states:

  - ``fresh``: a fresh ``reset(seed=s)`` per episode (imix);
  - ``stream``: the start states of one env's reset stream, every other reset (sb3-contrib);
  - ``crn``: one fresh seed per pair, shared by r+ and r- (common random numbers);
  - ``fixed``: the same two seeds (r+ on one, r- on the other) every iteration;
  - ``fixed_crn``: the same single seed for both episodes every iteration (a deterministic objective);
  - ``consecutive``: reset seeds 1000 * seed + 0, 1, 2, ... (small consecutive integers);

  prints each arm's mean-policy return after ``episodes`` training episodes (10 episodes on fixed
  seeds), the count >= 150 and, with ``--every``, the episodes to 325 (3 fresh episodes every
  20 training episodes), with Mann-Whitney / Wilcoxon (paired by seed) / Fisher p against ``fresh``;
* ``correlation``: start states of ``reset(seed=s)`` and ``reset(seed=s+1)`` for consecutive small
  seeds: any correlation?

    python benchmarks/ars_start_states.py replay [first last iterations [native]]  # default 0 10 50 1
    python benchmarks/ars_start_states.py arms [first last episodes [every]]     # default 0 30 100
    python benchmarks/ars_start_states.py correlation [count]                    # default 4000

Needs the ars and mujoco extras (sb3-contrib, torch, mujoco).
"""

from __future__ import annotations

import sys

import numpy as np
from ars_sb3_gap import ACT, OBS, THRESHOLD, _as_imix, _driven_ars, _imix_evaluator, _one_iteration, _sb3_model

from imix_cli.core.evaluation.policies import with_zero_biases

NOISE = 0.1  # Swimmer-v5's reset_noise_scale
EVAL_SEEDS = np.arange(10) + 10**6  # the mean policy's final measurement, as ``ars_sb3_gap.py resets``


class StartsEvaluator:
    """imix's evaluator whose next call may start its episodes from given states: set ``starts`` to
    (qpos (B, 5), qvel (B, 5)) and the episodes of that call start there (the seeds are then ignored);
    with ``starts`` None it is imix's evaluator (``reset(seed=s)``)."""

    def __init__(self):
        self.inner, self.starts = _imix_evaluator(), None
        episodes = self.inner._episodes
        original = episodes.reset

        def reset(seeds):
            obs = original(seeds)
            if self.starts is None:
                return obs
            qpos, qvel = self.starts
            for i in range(len(seeds)):
                episodes.set_state(i, qpos[i], qvel[i])
            return episodes._observations(np.arange(len(seeds)))

        episodes.reset = reset

    def evaluate(self, params, seeds):
        try:
            return self.inner.evaluate(params, seeds)
        finally:
            self.starts = None


class ResetStream:
    """The start states one Swimmer-v5 env's reset stream hands out as sb3-contrib trains on it:
    ``reset(seed=seed)`` (its ``learn``'s first reset), then unseeded resets of which every other one
    starts a candidate's episode (the others are the ``DummyVecEnv``'s auto-resets)."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)  # gymnasium's np_random after reset(seed=seed)
        self._draw()

    def _draw(self):
        return self.rng.uniform(-NOISE, NOISE, size=5), self.rng.uniform(-NOISE, NOISE, size=5)  # qpos, qvel (init 0)

    def take(self, n: int):
        states = []
        for _ in range(n):
            states.append(self._draw())
            self._draw()  # the auto-reset at the episode's end
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])


def _seeded_states(seeds):
    """The start states (qpos, qvel) of ``reset(seed=s)`` for each s (Swimmer-v5, init state 0)."""
    states = [ResetStream.__new__(ResetStream) for _ in seeds]
    for st, s in zip(states, seeds):
        st.rng = np.random.default_rng(int(s))
    drawn = [st._draw() for st in states]
    return np.array([d[0] for d in drawn]), np.array([d[1] for d in drawn])


def _stats(a, b) -> str:
    from scipy.stats import fisher_exact, mannwhitneyu, wilcoxon

    a, b = np.asarray(a), np.asarray(b)
    mw = mannwhitneyu(a, b).pvalue
    wx = wilcoxon(a, b).pvalue if len(a) == len(b) and np.any(a != b) else float("nan")
    ka, kb = int(np.sum(a >= 150)), int(np.sum(b >= 150))
    fi = fisher_exact([[ka, len(a) - ka], [kb, len(b) - kb]]).pvalue
    return f"Mann-Whitney p {mw:.3f}, Wilcoxon (paired) p {wx:.3f}, Fisher (>= 150) p {fi:.3f}"


def replay(first: int = 0, last: int = 10, iterations: int = 50, native: int = 1) -> None:
    """sb3-contrib's ARS, native loop against its episodes replayed on imix's evaluator from the same
    start states, and on fresh ``reset(seed=s)``; each seed's mean-policy return after ``2 * iterations`` episodes."""
    import torch

    evaluator, driven = StartsEvaluator(), _driven_ars()
    names = ("native", "replay", "fresh") if native else ("replay", "fresh")
    scores = {n: [] for n in names}
    for seed in range(first, last):
        line, native_starts = [], []
        for name in names:
            model = _sb3_model(seed, driven)
            model.rollout, model.evaluator, model.torch_state = ("native" if name == "native" else "imix"), evaluator, torch.get_rng_state()
            if name == "native":  # record the start state of every reset of its env
                env = model.env.envs[0]
                native_reset = env.reset

                def recording_reset(*args, _env=env, _reset=native_reset, _starts=native_starts, **kwargs):
                    out = _reset(*args, **kwargs)
                    _starts.append((_env.unwrapped.data.qpos.copy(), _env.unwrapped.data.qvel.copy()))
                    return out

                env.reset = recording_reset
            stream, episodes = ResetStream(seed), np.random.default_rng(seed)
            for _ in range(iterations):
                model.next_seeds = episodes.integers(0, 2**62, size=2)
                if name == "replay":
                    evaluator.starts = stream.take(2)
                _one_iteration(model)
            if name == "native":  # resets 1, 3 (the first iteration's episodes) equal the stream's first two
                used = np.array([np.concatenate(s) for s in native_starts[1:4:2]])
                expected = np.concatenate(ResetStream(seed).take(2), axis=1)
                assert np.array_equal(used, expected), "the native loop's start states are not the modelled reset stream"
            score = float(evaluator.evaluate(np.repeat(_as_imix(model.weights.numpy()), 10, axis=0), EVAL_SEEDS)[0].mean())
            scores[name].append(score)
            line.append(f"{name} {score:6.1f}")
        print(f"seed {seed}: " + "  ".join(line), flush=True)
    summary = "; ".join(f"{n}: median {np.median(v):.1f}, {np.sum(np.array(v) >= 150)}/{len(v)} at >= 150" for n, v in scores.items())
    print(f"after {2 * iterations} episodes: {summary}")
    print(f"replay against fresh: {_stats(scores['replay'], scores['fresh'])}")
    if native:
        print(f"native against fresh: {_stats(scores['native'], scores['fresh'])}")


ARMS = ("fresh", "stream", "crn", "fixed", "fixed_crn", "consecutive")


def _arm_starts(arm: str, seeds: list[int], it: int, rngs: dict, streams: dict):
    """Iteration ``it``'s start states of every seed's (r+, r-) episodes: (qpos (2n, 5), qvel (2n, 5)),
    rows 0..n-1 the + episodes, n..2n-1 the - episodes."""
    if arm == "stream":
        taken = [streams[s].take(2) for s in seeds]
        return tuple(np.concatenate([np.array([t[k][0] for t in taken]), np.array([t[k][1] for t in taken])]) for k in (0, 1))
    if arm == "fresh":
        pair = np.array([rngs[s].integers(0, 2**62, size=2) for s in seeds])
    elif arm == "crn":
        pair = np.repeat(np.array([rngs[s].integers(0, 2**62, size=1) for s in seeds]), 2, axis=1)
    elif arm == "fixed":
        pair = np.array([np.random.default_rng([s, 7]).integers(0, 2**62, size=2) for s in seeds])
    elif arm == "fixed_crn":
        pair = np.repeat(np.array([np.random.default_rng([s, 7]).integers(0, 2**62, size=1) for s in seeds]), 2, axis=1)
    elif arm == "consecutive":
        pair = np.array([[1000 * s + 2 * it, 1000 * s + 2 * it + 1] for s in seeds])
    else:
        raise ValueError(arm)
    return _seeded_states(np.concatenate([pair[:, 0], pair[:, 1]]))


def _run_arm(arm: str, seeds: list[int], iterations: int, every: int, evaluator: StartsEvaluator):
    """ARS (N = b = 1, sb3-contrib's update, float64) on ``seeds`` in lockstep; returns the mean
    policy's returns (10 episodes on EVAL_SEEDS) after 100 training episodes and at the end
    ({episodes: (n,)}) and the episodes to THRESHOLD (None: not reached)."""
    n, alpha, sigma = len(seeds), 0.02, 0.01
    w = np.zeros((n, OBS * ACT))  # imix's layout: W (8 x 2) row-major
    directions = {s: np.random.default_rng([s, 1]) for s in seeds}
    rngs = {s: np.random.default_rng([s, 2]) for s in seeds}
    measure = {s: np.random.default_rng([s, 3]) for s in seeds}
    streams = {s: ResetStream(s) for s in seeds}
    reached, marks = [None] * n, {}

    def mean_policy(params, episode_seeds):
        k = len(episode_seeds) // n
        return evaluator.evaluate(np.repeat(with_zero_biases(params, OBS, ACT, ()), k, axis=0), episode_seeds)[0].reshape(n, k).mean(1)

    for it in range(iterations):
        delta = np.array([directions[s].standard_normal(OBS * ACT) for s in seeds])
        params = with_zero_biases(np.concatenate([w + sigma * delta, w - sigma * delta]), OBS, ACT, ())
        evaluator.starts = _arm_starts(arm, seeds, it, rngs, streams)
        r = evaluator.evaluate(params, np.zeros(2 * n, dtype=np.int64))[0]
        diff = r[:n] - r[n:]
        std = np.abs(diff) / np.sqrt(2.0)  # std([r+, r-], ddof=1)
        w = w + (alpha / (std + 1e-6) * diff)[:, None] * delta
        if every and (it + 1) % every == 0:
            scores = mean_policy(w, np.concatenate([measure[s].integers(0, 2**62, size=3) for s in seeds]))
            for i in range(n):
                if reached[i] is None and scores[i] >= THRESHOLD:
                    reached[i] = 2 * (it + 1)
        if 2 * (it + 1) == 100 or it + 1 == iterations:
            marks[2 * (it + 1)] = mean_policy(w, np.tile(EVAL_SEEDS, n))
    return marks, reached


def arms(first: int = 0, last: int = 30, episodes: int = 100, every: int = 0, names: tuple[str, ...] = ()) -> None:
    """Each arm's mean-policy return after 100 and ``episodes`` training episodes, seeds ``first .. last-1``."""
    from scipy.stats import fisher_exact

    evaluator, seeds = StartsEvaluator(), list(range(first, last))
    # the evaluator from given start states is imix's from reset(seed=s) when they are reset(seed=s)'s
    check = np.array([3, 11]), with_zero_biases(0.3 * np.random.default_rng(0).standard_normal((2, OBS * ACT)), OBS, ACT, ())
    evaluator.starts = _seeded_states(check[0])
    assert np.array_equal(evaluator.evaluate(check[1], np.zeros(2, dtype=np.int64))[0], evaluator.evaluate(check[1], check[0])[0])
    results = {}
    for arm in names or ARMS:
        marks, reached = _run_arm(arm, seeds, episodes // 2, every // 2, evaluator)
        results[arm] = marks, reached
        for mark, final in marks.items():
            q1, q3 = np.percentile(final, [25, 75])
            line = f"{arm:12s} {mark:4d} episodes: median {np.median(final):6.1f}  IQR {q1:6.1f} - {q3:6.1f}  >= 150: {np.sum(final >= 150):2d}/{len(final)}"
            if arm != "fresh" and "fresh" in results:
                line += "  vs fresh: " + _stats(final, results["fresh"][0][mark])
            print(line, flush=True)
            print("    per seed: " + " ".join(f"{x:.0f}" for x in final), flush=True)
        if every:
            hits = [e for e in reached if e is not None]
            median = np.median(hits) if hits else float("nan")
            line = f"{arm:12s} reached {THRESHOLD:.0f} (3 episodes every {every}): {len(hits):2d}/{len(seeds)}, median episodes {median:.0f}"
            if arm != "fresh" and "fresh" in results:
                ka, kb = len(hits), sum(e is not None for e in results["fresh"][1])
                line += f"; vs fresh Fisher p {fisher_exact([[ka, len(seeds) - ka], [kb, len(seeds) - kb]]).pvalue:.3f}"
            print(line, flush=True)


def correlation(count: int = 4000) -> None:
    """reset(seed=s) against reset(seed=s+1), s = 0 .. count-1: the largest correlation between any
    coordinate of one and any coordinate of the next, and of the same coordinate."""
    q, v = _seeded_states(np.arange(count + 1))
    x = np.concatenate([q, v], axis=1)
    c = np.corrcoef(x[:-1].T, x[1:].T)[:10, 10:]
    same, any_pair = np.abs(np.diag(c)).max(), np.abs(c).max()
    print(f"reset(seed=s) vs reset(seed=s+1), s < {count}: largest corr, same coordinate {same:.3f}, any pair {any_pair:.3f} (2/sqrt(n): {2 / count**0.5:.3f})")


if __name__ == "__main__":
    what, args = (sys.argv[1] if len(sys.argv) > 1 else "arms"), sys.argv[2:]
    if what == "arms":
        arms(*[int(a) for a in args if a.isdigit()], names=tuple(a for a in args if not a.isdigit()))
    else:
        {"replay": lambda: replay(*map(int, args)), "correlation": lambda: correlation(*map(int, args))}[what]()
