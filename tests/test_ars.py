"""ARS (algo=ars): the step is the paper's, and mixing keeps its mirrored pairs exactly ARS's pairs.

Mixing for pairs (imix_cli.core.mixing.mirrored): the anchors are mixed from earlier anchors, each mirror is
drawn fresh around the new mean. The statistical tests check what must then hold: every pair is
(m + nu delta, m - nu delta) with the N directions delta independent N(0, I) -- in one step (KS,
pooled over many independent steps) and along chains of hundreds of generations whose mean moves
(z-scores of E[z] and E[z^2] across independent chains, as tests/test_mixing.py). Tolerances are
stated at each test; seeds are fixed.
"""

import json
import os
import signal
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from imix_cli.core.algorithms import ARS, make_es
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation
from imix_cli.core.mixing.mirrored import mix_pairs

KS_P_MIN = 1e-3
IMIX = str(Path(sys.executable).parent / "imix")


# ------------------------------------------------------------------------------- the ARS step
def test_the_step_is_alpha_over_b_sigma_r_times_the_sum_over_the_top_b_pairs():
    """Hand-computed: 3 directions in 2-D, top b = 2, alpha 0.1, nu 0.5."""
    es = ARS(2, popsize=6, sigma=0.5, lr=0.1, top=2, mean=[1.0, -1.0])
    deltas = np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, 1.0]])
    plus, minus = es.mean + 0.5 * deltas, es.mean - 0.5 * deltas
    r_plus, r_minus = np.array([3.0, 1.0, 10.0]), np.array([1.0, 5.0, 2.0])
    # max(r+, r-): 3, 5, 10 -> the top 2 are directions 3 and 2 (by r+ alone: 3 and 1); their 4 returns 10, 2, 1, 5
    sigma_r = np.std([10.0, 2.0, 1.0, 5.0])
    expected = np.array([1.0, -1.0]) + 0.1 / (2 * sigma_r) * ((10.0 - 2.0) * deltas[2] + (1.0 - 5.0) * deltas[1])
    es.tell(np.concatenate([plus, minus]), np.concatenate([r_plus, r_minus]))
    np.testing.assert_allclose(es.mean, expected, rtol=1e-12)
    assert es.last_return_std == pytest.approx(sigma_r)


def test_without_top_every_direction_counts_and_the_pairs_order_does_not_matter():
    rng = np.random.default_rng(0)
    es = ARS(4, popsize=10, sigma=0.1, lr=0.05, top=3)
    members = es.ask(rng)
    fitness = -np.sum((members - 1.0) ** 2, axis=1)
    perm = rng.permutation(5)
    other = ARS(4, popsize=10, sigma=0.1, lr=0.05, top=3)
    es.tell(members, fitness)
    other.tell(np.concatenate([members[:5][perm], members[5:][perm]]), np.concatenate([fitness[:5][perm], fitness[5:][perm]]))
    np.testing.assert_allclose(other.mean, es.mean, rtol=0, atol=1e-15)
    full = ARS(4, popsize=10, sigma=0.1, lr=0.05)
    full.tell(members, fitness)
    deltas = (members[:5] - members[5:]) / 0.2
    expected = 0.05 / (5 * np.std(fitness)) * ((fitness[:5] - fitness[5:]) @ deltas)
    np.testing.assert_allclose(full.mean, expected, rtol=1e-12, atol=1e-15)


def test_ars_climbs_a_sphere_and_refuses_odd_popsizes_and_a_top_beyond_n():
    rng = np.random.default_rng(1)
    es = make_es("ars", 10, popsize=16, sigma=0.1, lr=0.05, top=4, mean=np.full(10, 3.0))
    start = np.sum(es.mean**2)
    for _ in range(200):
        x = es.ask(rng)
        es.tell(x, -np.sum(x * x, axis=1))
    assert np.sum(es.mean**2) < 0.05 * start
    with pytest.raises(ValueError, match="even"):
        ARS(3, popsize=5)
    with pytest.raises(ValueError, match="top"):
        ARS(3, popsize=6, top=4)


# ----------------------------------------------------------------- the compiled step: numpy's step, bit for bit
def _numpy_step(mean, samples, fitness, nu, lr, top):
    """The numpy step the compiled one replaced (imix before the ARS step was compiled), kept as the reference:
    numpy's ``@`` (BLAS), ``zlib.crc32`` tie keys, ``np.lexsort``, ``np.std``. Returns (new mean, sigma_R or None)."""
    n = samples.shape[0] // 2
    r_plus, r_minus = fitness[:n], fitness[n:]
    deltas = (samples[:n] - samples[n:]) / (2.0 * nu)
    pairs = np.flatnonzero(np.isfinite(r_plus) & np.isfinite(r_minus))
    if pairs.size == 0:
        return mean, None
    b = min(top, pairs.size)
    keys = np.array([zlib.crc32(np.ascontiguousarray(row).tobytes()) for row in deltas[pairs]], dtype=np.int64)
    used = pairs[np.lexsort((keys, -np.maximum(r_plus[pairs], r_minus[pairs])))[:b]]
    return_std = float(np.std(np.concatenate([r_plus[used], r_minus[used]])))
    if not return_std > 0.0:
        return mean, return_std
    return mean + (lr / (b * return_std)) * ((r_plus[used] - r_minus[used]) @ deltas[used]), return_std


def _step_cases(seed: int, count: int):
    """Random ARS steps: dimensions from 1 (numpy's dot product) to 400, ties (rounded returns), non-finite returns,
    all returns equal."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n, d = int(rng.integers(1, 30)), int(rng.choice([1, 2, 3, 4, 5, 7, 8, 16, 33, 102, 130, 400]))
        top = int(rng.integers(1, n + 1))
        es = ARS(d, popsize=2 * n, sigma=float(rng.uniform(0.01, 1)), lr=float(rng.uniform(0.001, 0.5)), top=top, mean=rng.standard_normal(d))
        samples = es.ask(rng)
        fitness = np.round(rng.standard_normal(2 * n) * 10, int(rng.integers(0, 3)))
        if rng.random() < 0.2:
            fitness[rng.integers(0, 2 * n)] = rng.choice([np.nan, np.inf, -np.inf])
        if rng.random() < 0.05:
            fitness[:] = 3.0
        yield es, samples, fitness


def _steps_differing_from_numpys(seed: int, count: int) -> int:
    differing = 0
    for es, samples, fitness in _step_cases(seed, count):
        expected, return_std = _numpy_step(es.mean.copy(), samples, fitness, es.sigma, es.lr, es.top)
        es.tell(samples, fitness)
        same_std = return_std is None and np.isnan(es.last_return_std) or return_std == es.last_return_std
        differing += not (np.array_equal(es.mean, expected) and same_std)
    return differing


def test_the_compiled_step_is_numpys_step_bit_for_bit():
    """The published ARS studies (docs/ars.md) ran the numpy step; the compiled step (ars_update) must give its bits:
    BLAS's order for the sum over directions (numba's np.dot), zlib's crc32, lexsort's order, numpy's std. Made to
    fail by summing the directions in a fixed order (lk.vec_mat_kernel): 190 of 400 steps differed."""
    assert _steps_differing_from_numpys(7, 400) == 0


@pytest.mark.parametrize("coretype", ["Prescott", "Haswell"])
def test_the_compiled_step_is_numpys_step_under_other_openblas_kernels(coretype):
    """Under another OpenBLAS kernel numpy's ``@`` sums in another order; the compiled step follows it (numba's
    np.dot calls scipy's OpenBLAS, which takes the same kernel): the two agree under each kernel."""
    script = "import sys; sys.path.insert(0, sys.argv[1]); import test_ars; print(test_ars._steps_differing_from_numpys(8, 150))"
    env = {**os.environ, "OPENBLAS_CORETYPE": coretype, "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", script, str(Path(__file__).parent)], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["0"]


def test_the_direction_keys_are_zlibs_crc32():
    from imix_cli.core.algorithms.ars import _crc32

    rng = np.random.default_rng(3)
    for d in (1, 2, 7, 130):
        for row in rng.standard_normal((20, d)) * rng.uniform(1e-3, 1e3):
            assert _crc32(row) == zlib.crc32(row.tobytes())


# --------------------------------------------------------------------- pairs under mixing: one step
def _old_anchors(old, n, rng):
    return mix_pairs(old, [], n, rng, None)[0]


@pytest.mark.parametrize("variant", ["sun2009", "exact"])
@pytest.mark.parametrize("shift", [0.3, 1.5])
def test_one_mixed_generation_is_n_exact_ars_pairs_around_the_new_mean(variant, shift):
    """3-D, nu = 0.5, N = 8 directions, the mean moved by ``shift`` nu along the first axis; 2000
    independent steps pooled. Every member is standardised by the NEW mean: all 3 coordinates of the
    directions must be N(0, 1) (KS p > 1e-3), every mirror is exactly 2 m' - anchor, and a member is
    never taken twice. Power: reusing old pairs whole (old mirrors) puts the mirrors at -delta -
    2 shift, far off N(0, 1) at 2000 x 8 draws."""
    rng = np.random.default_rng(7)
    nu, n, dim = 0.5, 8, 3
    old = DiagonalGaussian(np.zeros(dim), nu)
    new_mean = np.array([shift * nu, 0.0, 0.0])
    new = DiagonalGaussian(new_mean, nu)
    plus, minus, reused = [], [], 0
    for _ in range(2000):
        archive = [_old_anchors(old, n, rng)]
        if variant == "exact":
            archive.append(_old_anchors(DiagonalGaussian(np.array([-shift * nu, 0.0, 0.0]), nu), n, rng))
        anchors, members = mix_pairs(new, archive, n, rng, variant)
        np.testing.assert_array_equal(members[:n], anchors.samples)
        np.testing.assert_allclose(members[:n] + members[n:], np.tile(2 * new_mean, (n, 1)), rtol=0, atol=1e-12)  # pairs around m'
        assert np.unique(members, axis=0).shape[0] == 2 * n  # no member twice
        plus.append((members[:n] - new_mean) / nu)
        minus.append((members[n:] - new_mean) / nu)
        reused += anchors.reused
    plus, minus = np.concatenate(plus), np.concatenate(minus)
    for coord in range(dim):
        assert stats.kstest(plus[:, coord], "norm").pvalue > KS_P_MIN, coord
        assert stats.kstest(minus[:, coord], "norm").pvalue > KS_P_MIN, coord
    assert 0.0 < reused / (2000 * n) < 1.0


# --------------------------------------------------------------- pairs under mixing: chains
# As tests/test_mixing.py's chains: per chain the mean of z and of z^2 over the generations after
# a burn-in (z: every member standardised by the mean and nu of its own generation, anchors and
# mirrors), across 40 independent chains their means with standard errors from the spread between
# chains; |z-score| < 4 and |E[z^2] - 1| < 0.025 (the standard error of E[z^2] is ~0.01 here).
# Each chain: 300 generations, d = 2, N = 10 directions, the mean random-walking by ~0.25 nu per
# generation or drifting by 0.2 nu per generation (reuse ~88-92 %). The means are exogenous, as in
# tests/test_mixing.py: when ARS's own steps move the mean, stored returns pull it toward the
# members that are reused (README, "Reused returns and selection bias") and E[z^2] drops to
# 0.86-0.88 (benchmarks/ars_pairs.py; docs/ars.md). Power: mirrors left around the old mean
# (whole pairs reused) fail both this and the single-step test.
CHAINS, CHAIN_GENERATIONS, BURN_IN = 40, 300, 20


def pair_chain_statistics(variant, motion, seed, dim=2, n=10, nu=1.0):
    rng = np.random.default_rng(seed)
    first, second, reuse = [], [], []
    for _ in range(CHAINS):
        es = ARS(dim, popsize=2 * n, sigma=nu, lr=0.4, top=n)
        archive, settings, zs, reused = Archive(), MixingSettings(variant, 3), [], 0
        mean = np.zeros(dim)
        for t in range(CHAIN_GENERATIONS):
            if motion != "ars":  # an exogenous mean: the ES's mean is set, its steps are not used
                es.set_state(type(es.state)(mean.copy(), np.full(dim, nu)))
            plan = plan_generation(es, archive, settings, rng)
            g = plan.generation
            m = es.distribution.mean
            assert np.unique(g.samples, axis=0).shape[0] == 2 * n
            if t >= BURN_IN:
                zs.append(((g.samples - m) / nu).ravel())
                reused += g.reused
            x = g.samples[plan.evaluate]
            returns = x[:, 0] + 0.5 * rng.standard_normal(x.shape[0])  # ARS keeps climbing it: the mean never settles
            finish_generation(es, archive, settings, plan, returns)
            if motion == "walk":
                mean = mean + nu * 0.25 * rng.standard_normal(dim)
            elif motion == "drift":
                mean = mean + nu * 0.2 * np.eye(dim)[0]
        zs = np.concatenate(zs)
        first.append(zs.mean())
        second.append(np.mean(zs * zs))
        reuse.append(reused / ((CHAIN_GENERATIONS - BURN_IN) * n))
    first, second = np.array(first), np.array(second)
    return {
        "z_mean": first.mean() / (first.std(ddof=1) / np.sqrt(CHAINS)),
        "E[z^2]": second.mean(),
        "z_var": (second.mean() - 1.0) / (second.std(ddof=1) / np.sqrt(CHAINS)),
        "reuse": float(np.mean(reuse)),
    }


@pytest.mark.slow
@pytest.mark.parametrize("motion", ["walk", "drift"])
@pytest.mark.parametrize("variant", ["sun2009", "exact"])
def test_chains_of_mixed_pair_generations_stay_ars_pairs(variant, motion):
    r = pair_chain_statistics(variant, motion, seed=2026)
    assert abs(r["z_mean"]) < 4 and abs(r["z_var"]) < 4, r
    assert abs(r["E[z^2]"] - 1.0) < 0.025, r
    assert r["reuse"] > 0.3, r  # the chain really reuses (anchors reused per direction)


def test_every_member_is_told_the_return_of_its_own_parameters():
    """Honesty of stored returns: with a deterministic objective, the fitness a generation is told is
    f(member) for every member -- fresh anchors, reused anchors (their stored return) and mirrors --
    along a chain that reuses (small ARS steps), and the reused ones come from the archive."""
    rng = np.random.default_rng(3)
    es = ARS(3, popsize=12, sigma=1.0, lr=0.05)
    archive, settings, reused = Archive(), MixingSettings("exact", 3), 0

    def f(x):
        return -np.sum((x - 2.0) ** 2, axis=1) + np.sin(7 * x[:, 0])

    for _ in range(60):
        plan = plan_generation(es, archive, settings, rng)
        g = plan.generation
        assert np.all(plan.evaluate >= 0) and set(range(6, 12)) <= set(plan.evaluate.tolist())  # mirrors always fresh
        fitness = finish_generation(es, archive, settings, plan, f(g.samples[plan.evaluate]))
        np.testing.assert_array_equal(fitness, f(g.samples))
        reused += g.reused
        assert len(archive.generations) <= 3 and archive.generations[0].samples.shape == (6, 3)  # anchors only
    assert reused > 60  # > 1 reused anchor per generation on average


# ---------------------------------------------------------------------------------- imix run
SWIMMER = ["run", "algo=ars", "env=swimmer", "eim=true", "env.max_steps=50", "popsize=8", "sigma=0.1", "lr=0.002", "policy.hidden=[]",
           "seeds=2", "checkpoint_every=4", "checkpoint_seconds=0", "workers=1", "progress=false", "eval_mean_every=5", "eval_mean_episodes=2"]  # fmt: skip


def _csvs(root: Path) -> dict:
    return {p.relative_to(root): pd.read_csv(p).drop(columns=["wall_time"]) for p in sorted(root.rglob("seed_*.csv")) if ".partial" not in p.name}


@pytest.mark.slow
@pytest.mark.mujoco
def test_imix_run_ars_on_swimmer_saves_policies_and_resumes_after_a_kill(tmp_path):
    """The real console script, algo=ars env=swimmer eim=true: SIGKILL the process group once a
    checkpoint exists, re-run the same command, and get the CSVs of an uninterrupted run (but for
    wall time), with reuse, policies and the checkpoint's resume message."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    args = [*SWIMMER, "generations=40"]
    subprocess.run([IMIX, *args, f"results_dir={tmp_path / 'ref'}"], check=True, env=env, capture_output=True)
    target = tmp_path / "killed"
    proc = subprocess.Popen([IMIX, *args, f"results_dir={target}"], env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline and not list(target.rglob(".checkpoints/seed_*.npz")):
        time.sleep(0.05)
    killed = proc.poll() is None
    if killed:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert killed, "the run ended before a checkpoint could be killed"
    done = subprocess.run([IMIX, *args, f"results_dir={target}"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "imix: resuming" in done.stderr, done.stderr
    expected, got = _csvs(tmp_path / "ref"), _csvs(target)
    assert sorted(got) == sorted(expected) and len(got) == 2
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])
        assert got[name]["reused"].sum() > 0  # the archive (anchors, returns, heights) came back with the checkpoint
    run_dir = next(target.glob("default/ars-Swimmer-v5-eim*"))
    for seed in (0, 1):
        for kind in ("mean", "best"):
            with np.load(run_dir / f"policy_{seed}_{kind}.npz", allow_pickle=False) as saved:
                assert np.all(np.isfinite(saved["params"])) and saved["params"].shape == (8 * 2 + 2,)  # linear: 8 observations -> 2 actions


def test_bad_ars_settings_are_one_line_errors(tmp_path, capsys):
    from imix_cli.commands.cli import main

    for bad, key in ((["popsize=7"], "popsize must be even"), (["algo.top=5", "popsize=8"], "top must be in")):
        assert main(["run", "algo=ars", "env=cartpole", "seeds=1", "generations=1", f"results_dir={tmp_path}", *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and key in err and "algo=ars" in err, err
    assert not list(tmp_path.iterdir())  # nothing written


def test_algo_top_is_checked_against_the_runs_own_popsize():
    """algo.top <= popsize/2 with the popsize of the run (200: top up to 100), not the default popsize's 25."""
    from imix_cli.running.config.compose import validate_overrides

    (spec,) = validate_overrides(["algo=ars", "popsize=200", "algo.top=80"])
    assert spec.algo_options == {"top": 80, "alive_bonus_offset": 0.0} and spec.popsize == 200


# ----------------------------------------------------------------- ARS's linear policy a = M s, clipped
def test_clip_output_is_the_outputs_clipped_to_the_action_bounds():
    """policy.output=clip: the action is the network's output itself, cut at the bounds (ARS,
    sb3-contrib's ARSLinearPolicy) -- not tanh of it, which bends even small outputs."""
    from imix_cli.core.evaluation.policies import BatchPolicy, forward, num_params

    rng = np.random.default_rng(0)
    obs = rng.normal(size=(7, 5))
    params = 0.7 * rng.normal(size=(7, num_params(5, 3, ())))
    y = forward(params, obs, 3, ())
    for low, high in (([-1.0] * 3, [1.0] * 3), ([-2.0, -0.5, 0.0], [0.5, 0.25, 3.0])):
        clipped = BatchPolicy(params, 5, 3, discrete=False, hidden=(), low=low, high=high, output="clip")(obs)
        np.testing.assert_array_equal(clipped, np.clip(y, low, high))
        inside = (y > np.array(low)) & (y < np.array(high))
        assert inside.any() and (~inside).any()  # the case has outputs on both sides of the bounds
        squashed = BatchPolicy(params, 5, 3, discrete=False, hidden=(), low=low, high=high)(obs)
        assert not np.any(squashed[inside] == clipped[inside])  # tanh (the default) is another policy


def test_a_bias_free_policy_is_its_weights_with_zero_biases():
    """policy.bias=false: the ES's point is the weights alone, in layout order; the policy they make
    has every bias 0 (a linear one is obs @ W, a hidden layer tanh(obs @ W1) @ W2)."""
    from imix_cli.core.evaluation.policies import forward, num_params, weight_columns, with_zero_biases

    rng = np.random.default_rng(1)
    obs = rng.normal(size=(4, 6))
    for hidden in ((), (5,)):
        columns = weight_columns(6, 2, hidden)
        sizes = [6, *hidden, 2]
        assert columns.size == num_params(6, 2, hidden) - sum(sizes[1:])
        weights = rng.normal(size=(4, columns.size))
        params = with_zero_biases(weights, 6, 2, hidden)
        biases = np.setdiff1d(np.arange(params.shape[1]), columns)
        assert np.all(params[:, biases] == 0.0) and np.array_equal(params[:, columns], weights)
        W = [weights[:, :36].reshape(4, 6, -1)] if not hidden else [weights[:, :30].reshape(4, 6, 5), weights[:, 30:].reshape(4, 5, 2)]
        x = obs
        for i, w in enumerate(W):
            x = np.einsum("bi,bij->bj", x, w)
            x = np.tanh(x) if i < len(W) - 1 else x
        np.testing.assert_allclose(forward(params, obs, 2, hidden), x, rtol=1e-12, atol=1e-12)


def test_with_obs_norm_the_bias_free_weights_act_on_normalised_observations():
    """ARS V2 with policy.bias=false: the policy is a = M (s - mu) / sd. The zero biases are put back
    before the normaliser is folded in (the fold gives the layer the bias -M mu / sd)."""
    from types import SimpleNamespace

    from imix_cli.core.evaluation.policies import ObsNormalizer, forward
    from imix_cli.running.loop.lockstep import policy_params, search_dim

    rng = np.random.default_rng(2)
    norm = ObsNormalizer(3, 1)
    states = rng.normal(loc=[5.0, -2.0, 0.5], scale=[3.0, 0.2, 1.0], size=(50, 3))
    norm.add(states.sum(0)[None], (states**2).sum(0)[None], np.array([50]))
    norm.end_generation()
    evaluator = SimpleNamespace(obs_dim=3, out_dim=2, hidden=(), num_params=8)
    spec = SimpleNamespace(policy_bias=False)
    assert search_dim(spec, evaluator) == 6
    M = rng.normal(size=(1, 6))
    raw = policy_params(spec, SimpleNamespace(obs_norm=norm), M, evaluator)
    expected = ((states - norm.mean) / norm.std) @ M.reshape(3, 2)
    np.testing.assert_allclose(forward(np.repeat(raw, 50, axis=0), states, 2, ()), expected, rtol=1e-10, atol=1e-10)


def test_the_variance_floor_is_the_configs_and_survives_a_checkpoint():
    """policy.obs_var_floor: the V2 presets set ARS's 1e-8 (imix's 0.01 cost ARS V2-t on Hopper two
    thirds of its return, docs/ars.md); a coordinate of variance 1e-4 is then scaled by its own
    1/std = 100, not the default floor's 10. A checkpoint keeps the floor (an older checkpoint,
    without it, had 0.01)."""
    import yaml

    from imix_cli.core.evaluation.policies import OBS_VAR_FLOOR, ObsNormalizer
    from imix_cli.running.config.keys import POLICY_DEFAULTS

    states = np.stack([np.linspace(-1.0, 1.0, 101) * 0.01 * np.sqrt(3.0), np.linspace(-3.0, 3.0, 101)], axis=1)
    for floor, expected in ((1e-8, 0.01), (OBS_VAR_FLOOR, 0.1)):
        norm = ObsNormalizer(2, 1, floor)
        norm.add(states.sum(0)[None], (states**2).sum(0)[None], np.array([len(states)]))
        norm.end_generation()
        assert norm.std[0] == pytest.approx(expected, rel=0.02) and norm.std[1] > 1.0
        again = ObsNormalizer.from_state(norm.to_state())
        assert again.var_floor == floor and np.array_equal(again.std, norm.std)
    old_state = {k: v for k, v in norm.to_state().items() if k != "var_floor"}
    assert ObsNormalizer.from_state(old_state).var_floor == OBS_VAR_FLOOR
    # one default in three places (the normaliser's, the config's, the key check's): they must agree
    config = yaml.safe_load((Path(__file__).parents[1] / "conf" / "config.yaml").read_text())
    assert POLICY_DEFAULTS["obs_var_floor"] == OBS_VAR_FLOOR == config["policy"]["obs_var_floor"]


@pytest.mark.mujoco
def test_the_ars_presets_variance_floor_names_the_run_and_reaches_each_seed():
    """The V2 presets' floor (1e-8, see the test above) is in the run's name and in every seed's normaliser;
    the default floor keeps the folder name runs had before the key. Validating env=hopper needs MuJoCo."""
    from types import SimpleNamespace

    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.loop.lockstep import loop_settings, new_seed_state

    for env in ("hopper", "halfcheetah", "walker2d"):
        (spec,) = validate_overrides(["algo=ars", f"env={env}", f"+ars={env}"])
        assert spec.obs_var_floor == 1e-8 and "obs_var_floor=1e-08" in spec.run_name
    (default,) = validate_overrides(["algo=ars", "env=hopper", "+ars=hopper", "policy.obs_var_floor=0.01"])
    assert "obs_var_floor" not in default.run_name  # the default keeps the folder runs had before the key
    evaluator = SimpleNamespace(obs_dim=11, out_dim=3, hidden=())
    settings = loop_settings(spec, evaluator)
    assert all(new_seed_state(settings, seed).obs_norm.var_floor == 1e-8 for seed in range(3))


@pytest.mark.mujoco
def test_the_ars_presets_run_the_papers_policy_and_eval_acts_with_it(tmp_path):
    """+ars=<env>: no biases (the ES searches 16 weights on Swimmer), clipped actions; the saved
    policies keep zero biases and say "clip", and imix eval acts with the clip."""
    from imix_cli.commands.cli import main
    from imix_cli.commands.eval_command import evaluator_for
    from imix_cli.core.evaluation import make_evaluator
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.files.policy_files import read_policy

    for env in ("swimmer", "hopper", "halfcheetah", "walker2d"):
        (spec,) = validate_overrides(["algo=ars", f"env={env}", f"+ars={env}"])
        assert (spec.policy_bias, spec.policy_output, spec.hidden) == (False, "clip", ())
    args = ["run", "algo=ars", "env=swimmer", "+ars=swimmer", "env.max_steps=60", "lr=0.5", "seeds=1", "generations=6", "progress=false", "workers=1"]
    assert main([*args, f"results_dir={tmp_path}"]) == 0
    (run_dir,) = tmp_path.glob("default/ars-Swimmer-v5-*")
    assert "bias=False" in run_dir.name and "output=clip" in run_dir.name
    policy = read_policy(run_dir / "policy_0_mean.npz")
    assert policy.header["output"] == "clip" and policy.params.shape == (18,)
    assert np.all(policy.params[16:] == 0.0) and np.any(policy.params[:16] != 0.0)
    params, seeds = np.repeat(policy.params[None, :], 3, axis=0), np.arange(3)
    returns, _ = evaluator_for(policy.header, run_dir=run_dir).evaluate(params, seeds)
    np.testing.assert_array_equal(returns, make_evaluator("Swimmer-v5", 60, hidden=(), output="clip").evaluate(params, seeds)[0])
    assert not np.array_equal(returns, make_evaluator("Swimmer-v5", 60, hidden=()).evaluate(params, seeds)[0])


@pytest.mark.mujoco
def test_the_alive_bonus_offset_reshapes_training_returns_only(tmp_path):
    """algo.alive_bonus_offset=-1 (ARS's shift, +ars=hopper): members are told return - episode length.
    On Swimmer every episode lasts env.max_steps, so the shift is the same constant for every member:
    ARS's step (return differences over their std) and hence the whole run are unchanged, the
    population columns move by exactly the offset x length, and the mean policy's fresh episodes
    (mean_policy_score) stay on the env's own return."""
    from imix_cli.commands.cli import main

    es = make_es("ars", 3, popsize=4, alive_bonus_offset=-1.0)
    np.testing.assert_array_equal(es.training_fitness(np.array([10.0, 5.0]), np.array([100, 7])), [-90.0, -2.0])
    plain = make_es("ars", 3, popsize=4)
    returns = np.array([10.0, 5.0])
    assert plain.training_fitness(returns, np.array([100, 7])) is returns
    args = ["run", "algo=ars", "env=swimmer", "+ars=swimmer", "env.max_steps=50", "seeds=1", "generations=5", "eval_mean_every=1", "eval_mean_episodes=2",
            "progress=false", "workers=1"]  # fmt: skip
    assert main([*args, f"results_dir={tmp_path / 'plain'}"]) == 0
    assert main([*args, "algo.alive_bonus_offset=-1", f"results_dir={tmp_path / 'shifted'}"]) == 0
    (a,), (b,) = (list((tmp_path / k).glob("default/ars-*/seed_0.csv")) for k in ("plain", "shifted"))
    a, b = pd.read_csv(a), pd.read_csv(b)
    pd.testing.assert_series_equal(a["mean_policy_score"], b["mean_policy_score"])
    np.testing.assert_allclose(b["mean_score"], a["mean_score"] - 50.0, rtol=0, atol=1e-6)  # the CSV keeps 10 significant digits
    np.testing.assert_allclose(b["best_score"], a["best_score"] - 50.0, rtol=0, atol=1e-6)  # the CSV keeps 10 significant digits


def test_a_bias_free_shifted_ars_run_resumes_from_its_checkpoint(tmp_path, capsys):
    """A checkpoint's best member is a policy (biases included) while the ES searches the weights
    only, and its training returns include the offset per step: the checkpoint must be taken back,
    not refused as foreign (which would silently restart the seed)."""
    from imix_cli.commands.cli import main

    args = ["run", "algo=ars", "env=continuous_cartpole", "policy.bias=false", "algo.alive_bonus_offset=-2", "popsize=4", "seeds=1",
            "progress=false", "workers=1", f"results_dir={tmp_path}"]  # fmt: skip
    assert main([*args, "generations=4"]) == 0
    capsys.readouterr()
    assert main([*args, "generations=6"]) == 0
    err = capsys.readouterr().err
    assert "resuming seed 0 of" in err and "at generation 4" in err and "ignored" not in err, err
    frame = pd.read_csv(next(tmp_path.glob("default/ars-*/seed_0.csv")))
    assert len(frame) == 6 and (frame["mean_score"] < 0).all()  # every step's reward 1 - 2: the training returns are negative


def test_policy_files_written_before_the_output_field_read_as_tanh(tmp_path):
    from imix_cli.running.files.policy_files import HEADER_FIELDS, read_policy, write_policy

    header = {k: None for k in HEADER_FIELDS}
    header.update(format="imix-policy/1", env_name="swimmer", env_id="Swimmer-v5", max_steps=1000, obs_dim=8, out_dim=2, hidden=[],
                  discrete=False, action_start=0, action_low=[-1.0, -1.0], action_high=[1.0, 1.0], seed=0, which="mean", generation=3)  # fmt: skip
    write_policy(tmp_path / "new.npz", np.zeros(18), {**header, "output": "clip"})
    assert read_policy(tmp_path / "new.npz").header["output"] == "clip"
    old = tmp_path / "old.npz"  # as an earlier imix wrote it: no "output" in the header
    np.savez(old, params=np.zeros(18), header=np.array(json.dumps({k: v for k, v in header.items() if k != "output"})))
    assert read_policy(old).header["output"] == "tanh"


def test_bad_policy_outputs_are_one_line_errors(tmp_path, capsys):
    from imix_cli.commands.cli import main

    for bad, key in (
        (["env=cartpole", "policy.output=clip"], "policy.output=clip: only on gymnasium environments with continuous actions"),
        (["env=gym", "env.id=CartPole-v1", "policy.output=clip"], "CartPole-v1 has discrete actions"),
        (["env=cartpole", "policy.output=sigmoid"], "policy.output='sigmoid'"),
        (["env=cartpole", "policy.bias=maybe"], "policy.bias='maybe'"),
        (["env=cartpole", "policy.obs_var_floor=-1"], "policy.obs_var_floor=-1: must be > 0"),
        (["env=cartpole", "policy.obs_var_floor=0"], "policy.obs_var_floor=0: must be > 0"),
    ):
        assert main(["run", "algo=ars", "seeds=1", "generations=1", f"results_dir={tmp_path}", *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and key in err, err
    assert not list(tmp_path.iterdir())  # nothing written


# ------------------------------------------------------------------------------ the study's outputs
def _fake_run(folder: Path, scores, episodes_per_generation: int, popsize=None, reused=None) -> None:
    folder.mkdir(parents=True)
    n = len(scores)
    frame = {
        "generation": np.arange(n), "evaluations": episodes_per_generation * np.arange(1, n + 1),
        "env_steps": 1000 * episodes_per_generation * np.arange(1, n + 1), "mean_policy_score": scores,
        "wall_time": np.arange(1, n + 1, dtype=float),
    }  # fmt: skip
    if popsize is not None:
        frame["popsize"] = np.full(n, popsize)
        frame["reused"] = reused
        frame["evaluations"] = np.cumsum(popsize - np.asarray(reused))
    pd.DataFrame(frame).to_csv(folder / "seed_0.csv", index=False)


def test_the_study_table_counts_episodes_to_the_papers_threshold_and_the_episodes_mixing_saved(tmp_path):
    from imix_cli.plotting.ars import main as plot_main

    exp = tmp_path / "ars"
    nan = float("nan")
    _fake_run(exp / "sb3_ars-Swimmer-v5", [nan, 100.0, nan, 330.0, nan, 340.0], 2)  # crosses 325 at 8 episodes
    # imix + EIM: 4 members per generation, 1 then 2 reused: 4, 3, 2, 2 episodes -> crosses at 4 + 3 + 2 = 9
    _fake_run(exp / "ars-Swimmer-v5-eim-algo.top=1", [nan, 200.0, 326.0, 300.0], 4, popsize=4, reused=[0, 1, 2, 2])
    assert plot_main([f"results_dir={tmp_path}", "experiment=ars", "resamples=50"]) == 0
    table = pd.read_csv(exp / "figures" / "ars_table.csv").set_index("method")
    assert table.loc["sb3-contrib ARS", "episodes_to_threshold"] == 8 and table.loc["sb3-contrib ARS", "reached"] == "1/1"
    assert table.loc["imix ARS + EIM", "episodes_to_threshold"] == 9
    assert table.loc["imix ARS + EIM", "final_mean_policy_return"] == 300.0
    assert table.loc["imix ARS + EIM", "episodes_saved"] == pytest.approx(5 / 16)
    assert (exp / "figures" / "ars_swimmer.png").exists()


def test_the_study_table_gives_the_wall_time_per_seed_of_seeds_run_together(tmp_path):
    """imix advances a run's seeds together in each of its ``workers`` processes, so every seed's last
    wall_time is its process's run time: 4 seeds in 2 processes that took 8 s are 4 s a seed (the
    table said 8). sb3-contrib's peer runs one seed at a time; a run without config.yaml keeps its own."""
    from imix_cli.plotting.ars import main as plot_main

    exp = tmp_path / "ars"
    for k in range(4):
        _fake_run(exp / "ars-Swimmer-v5-none-x" / f"s{k}", [300.0, 330.0], 2, popsize=2, reused=[0, 0])
        (exp / "ars-Swimmer-v5-none-x" / f"s{k}" / "seed_0.csv").rename(exp / "ars-Swimmer-v5-none-x" / f"seed_{k}.csv")
    (exp / "ars-Swimmer-v5-none-x" / "config.yaml").write_text("seeds: 4\nworkers: 2\n")
    _fake_run(exp / "sb3_ars-Swimmer-v5", [300.0, 330.0], 2)  # wall_time 1, 2: its last, 2 s
    _fake_run(exp / "ars-Swimmer-v5-eim-x", [300.0, 330.0], 2, popsize=2, reused=[0, 0])  # no config.yaml
    assert plot_main([f"results_dir={tmp_path}", "experiment=ars", "resamples=50"]) == 0
    table = pd.read_csv(exp / "figures" / "ars_table.csv").set_index("method")
    assert table.loc["imix ARS", "wall_time_s"] == 1.0  # the runs' last wall_time 2 s, 2 seeds per process
    assert table.loc["sb3-contrib ARS", "wall_time_s"] == 2.0 and table.loc["imix ARS + EIM", "wall_time_s"] == 2.0


def test_the_study_table_says_whether_imix_differs_from_sb3_contrib_beyond_noise(tmp_path):
    """Rank tests, seeds that never reach the threshold ranked last: 5 seeds that all reach it against
    5 that never do are as far apart as 5 against 5 can be (exact two-sided p = 2 / C(10, 5))."""
    from imix_cli.plotting.ars import p_vs_peer, summary_rows

    inf = float("inf")
    assert p_vs_peer([inf] * 5, [300, 200, 100, 400, 250]) == pytest.approx(2 / 252)
    assert p_vs_peer([1.0, 2.0, 3.0, 4.0, 5.0], [6.0, 7.0, 8.0, 9.0, 10.0]) == pytest.approx(2 / 252)
    assert p_vs_peer([inf, inf, 20.0], [inf, inf, 20.0]) == 1.0 and p_vs_peer([inf] * 3, [inf] * 3) == 1.0
    assert p_vs_peer([100.0, 300.0, 200.0], [150.0, 250.0, 120.0]) > 0.5  # interleaved: no evidence
    nan = float("nan")
    frames = lambda scores: [_frame(s) for s in scores]  # noqa: E731
    runs = {"Swimmer-v5": {
        "sb3_ars": frames([[nan, 330.0, 340.0], [nan, 400.0, 350.0], [nan, 200.0, 326.0]]),  # reach at 4, 4, 6 episodes
        "none": frames([[nan, 100.0, 90.0], [nan, 110.0, 120.0], [nan, 330.0, 100.0]]),  # one reaches (at 4)
    }}  # fmt: skip
    rows = {r["method"]: r for r in summary_rows(runs, resamples=20)}
    assert rows["imix ARS"]["p_episodes_vs_sb3"] == pytest.approx(p_vs_peer([inf, inf, 4], [4, 4, 6]))
    assert rows["imix ARS"]["p_final_vs_sb3"] == pytest.approx(p_vs_peer([90.0, 120.0, 100.0], [340.0, 350.0, 326.0]))
    assert np.isnan(rows["sb3-contrib ARS"]["p_final_vs_sb3"])


def _frame(scores) -> pd.DataFrame:
    n = len(scores)
    return pd.DataFrame({
        "generation": np.arange(n), "evaluations": 2 * np.arange(1, n + 1), "env_steps": 2000 * np.arange(1, n + 1),
        "mean_policy_score": scores, "wall_time": np.arange(1, n + 1, dtype=float), "popsize": np.full(n, 2),
    })  # fmt: skip


@pytest.mark.slow
@pytest.mark.ars
def test_the_sb3_contrib_peer_writes_a_csv_of_whole_iterations(tmp_path):
    from imix_cli.bench.ars_peer import main as peer_main

    args = ["--envs", "swimmer", "--seeds", "1", "--episodes", "3", "--eval-every", "1", "--eval-episodes", "1", "--results-dir", str(tmp_path)]
    assert peer_main(args) == 0
    frame = pd.read_csv(tmp_path / "ars" / "sb3_ars-Swimmer-v5" / "seed_0.csv")
    assert frame["evaluations"].tolist() == [2, 4]  # N = 1: 2 episodes per iteration, until >= 3
    assert frame["env_steps"].tolist() == [2000, 4000] and frame["mean_policy_episodes"].tolist() == [1, 2]
    assert np.all(np.isfinite(frame["mean_policy_score"]))
