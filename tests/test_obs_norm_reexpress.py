"""policy.obs_norm_freeze=false: statistics that keep updating, and an archive re-expressed under each new one.

The policy function, the density of a re-expressed generation, chains of mixed generations whose archive is
re-expressed every generation, a run whose every reused return is the return of its member's current parameters,
checkpoints, and the keys' refusals (imix_cli.core.evaluation.policies, "Observation normalisation").
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import interrupted_run

from imix_cli.commands.cli import main
from imix_cli.core.distributions import AffinePushforward, DiagonalGaussian, FullGaussian
from imix_cli.core.evaluation.policies import BatchPolicy, NormalizerChange, ObsNormalizer, fold_normalizer, num_params
from imix_cli.core.mixing import Generation, _whitened, mix, variant_spec
from imix_cli.core.mixing.generation import Archive
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.loop import lockstep
from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state


def random_change(rng, obs_dim, out_dim, hidden):
    mean0, mean1 = rng.normal(size=obs_dim) * 3, rng.normal(size=obs_dim) * 3
    std0, std1 = rng.uniform(0.1, 5, obs_dim), rng.uniform(0.1, 5, obs_dim)
    return NormalizerChange(obs_dim, out_dim, hidden, mean0, std0, mean1, std1)


def affine_matrix(change: NormalizerChange) -> tuple[np.ndarray, np.ndarray]:
    """``(A, c)`` of ``change``, read off its action on 0 and on the unit vectors."""
    c = change.forward(np.zeros((1, change.dim)))[0]
    return (change.forward(np.eye(change.dim)) - c).T, c


# ------------------------------------------------------------------------------ 1. the same function
@pytest.mark.parametrize("hidden", [(), (8, 8)], ids=["linear", "mlp-8x8"])
def test_reexpressed_parameters_are_the_same_policy_under_the_new_statistics(hidden):
    rng = np.random.default_rng(0)
    obs_dim, out_dim = 5, 3
    change = random_change(rng, obs_dim, out_dim, hidden)
    theta = rng.normal(size=(6, num_params(obs_dim, out_dim, hidden)))
    obs = change.mean0 + change.std0 * rng.normal(size=(6, obs_dim)) * 2
    before = BatchPolicy(fold_normalizer(theta, obs_dim, out_dim, hidden, change.mean0, change.std0), obs_dim, out_dim, discrete=False, hidden=hidden)
    after = BatchPolicy(fold_normalizer(change.forward(theta), obs_dim, out_dim, hidden, change.mean1, change.std1), obs_dim, out_dim,
                        discrete=False, hidden=hidden)  # fmt: skip
    np.testing.assert_allclose(after.outputs(obs), before.outputs(obs), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(change.inverse(change.forward(theta)), theta, rtol=1e-12, atol=1e-12)
    assert np.array_equal(change.forward(theta[2:3])[0], change.forward(theta)[2])  # a row's image never depends on the others
    h1 = hidden[0] if hidden else out_dim
    assert change.log_det == pytest.approx(h1 * np.sum(np.log(change.std1 / change.std0)), rel=1e-12)
    A, _ = affine_matrix(change)
    assert change.log_det == pytest.approx(np.linalg.slogdet(A)[1], rel=1e-10, abs=1e-10)


# ------------------------------------------------------------------------------ 2. the density
@pytest.mark.parametrize("hidden", [(), (3,)])
def test_the_pushforward_is_the_gaussian_of_the_mapped_mean_and_covariance(hidden):
    rng = np.random.default_rng(1)
    obs_dim, out_dim = 3, 2
    d = num_params(obs_dim, out_dim, hidden)
    change, later = random_change(rng, obs_dim, out_dim, hidden), random_change(rng, obs_dim, out_dim, hidden)
    base = DiagonalGaussian(rng.normal(size=d), rng.uniform(0.3, 2.0, d))
    push = AffinePushforward(base, change)
    theta = base.sample(400, rng)
    x = change.forward(theta)
    np.testing.assert_allclose(push.log_prob(x), base.log_prob(theta) - change.log_det, rtol=1e-10)
    np.testing.assert_allclose(push.log_prob(x, rows=[3, 1]), push.log_prob(x)[[3, 1]], rtol=0, atol=0)
    A, c = affine_matrix(change)
    gauss = FullGaussian(A @ base.mean + c, A @ np.diag(base.std**2) @ A.T)
    np.testing.assert_allclose(push.log_prob(x), gauss.log_prob(x), rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(push.mean, gauss.mean, rtol=1e-12, atol=1e-12)
    # its draws: the mapped base's, whose moments are the Gaussian's
    draws = push.sample(20000, np.random.default_rng(2))
    np.testing.assert_allclose(draws.mean(0), gauss.mean, atol=5 * np.sqrt(np.diag(gauss.cov) / 20000).max())
    # pushed again: one map from the base's coordinates (composed), the density of the two maps in turn
    both = AffinePushforward(push, NormalizerChange(obs_dim, out_dim, hidden, change.mean1, change.std1, later.mean1, later.std1))
    assert both.base is base
    y = both.transform.forward(theta)
    A2, c2 = affine_matrix(both.transform)
    gauss2 = FullGaussian(A2 @ base.mean + c2, A2 @ np.diag(base.std**2) @ A2.T)
    np.testing.assert_allclose(both.log_prob(y), gauss2.log_prob(y), rtol=1e-8, atol=1e-8)
    # whitening (variant "conditional") is the base's at the preimage
    np.testing.assert_allclose(_whitened(push, x), _whitened(base, theta), rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------ 3. chains
# As tests/test_mixing.py's chains: the search distribution N(m, s^2 I) random-walks (0.125 s per generation, log s
# by 0.02), each generation mixed from the previous K = 3; and after each, the observation statistics of a linear
# policy with bias (obs 2 -> 1: d = 3) random-walk too (mean by 0.1 std, log std by 0.1 per coordinate), the archive
# re-expressed under them. Members standardised by their own generation's distribution; per chain the mean of z and of
# z^2 after a burn-in of 20, their means over 20 chains with standard errors from the spread between chains. Tolerance:
# |z-score| < 4 and |E[z^2] - 1| < 0.06 (seen: <= 0.03 over seeds 0-3, reuse ~80 %). Power: with the samples mapped
# but the distributions left as they were, E[z^2] is 1.16-1.30 (z 3.5-8).
CHAIN_GENERATIONS, CHAIN_COUNT, CHAIN_BURN_IN, CHAIN_Z2_TOLERANCE = 300, 20, 20, 0.06


def reexpressed_chains(variant: str, dists_too: bool = True, seed: int = 0, obs_dim=2, out_dim=1, hidden=()):
    rng = np.random.default_rng(seed)
    d, k, popsize = num_params(obs_dim, out_dim, hidden), 3, 20
    first, second, reused, n = [], [], 0, 0
    for _ in range(CHAIN_COUNT):
        mean, log_std, mu, s = np.zeros(d), 0.0, np.zeros(obs_dim), np.ones(obs_dim)
        archive, s1, s2, count = Archive(), np.zeros(d), np.zeros(d), 0
        for t in range(CHAIN_GENERATIONS):
            g = mix(DiagonalGaussian(mean, np.exp(log_std)), archive.generations, popsize, rng, variant=variant, eim_generations=k)
            if t >= CHAIN_BURN_IN:
                z = (g.samples - mean) / np.exp(log_std)
                s1, s2, count = s1 + z.sum(0), s2 + (z * z).sum(0), count + popsize
                reused, n = reused + g.reused, n + popsize
            archive.generations = [g, *archive.generations][: variant_spec(variant).depth(k)]
            mu_next, s_next = mu + 0.1 * s * rng.standard_normal(obs_dim), s * np.exp(0.1 * rng.standard_normal(obs_dim))
            change = NormalizerChange(obs_dim, out_dim, hidden, mu, s, mu_next, s_next)
            if dists_too:
                archive.reexpress(change)
            else:  # the bug: members mapped, their generations' distributions left
                for e in archive.generations:
                    e.samples = change.forward(e.samples)
            mu, s = mu_next, s_next
            mean = mean + np.exp(log_std) * 0.125 * rng.standard_normal(d)
            log_std += 0.02 * rng.standard_normal()
        first.append(s1 / count)
        second.append(s2 / count)
    first, second = np.array(first), np.array(second)
    se1, se2 = first.std(0, ddof=1) / np.sqrt(CHAIN_COUNT), second.std(0, ddof=1) / np.sqrt(CHAIN_COUNT)
    return first.mean(0) / se1, (second.mean(0) - 1.0) / se2, second.mean(0), reused / n


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["exact", "paper", "sun2009"])
def test_chains_with_a_reexpressed_archive_stay_distributed_as_their_distribution(variant):
    z_mean, z_var, second, reuse = reexpressed_chains(variant)
    print(f"{variant}: E[z^2] {np.round(second, 4)}, z-scores {np.round(z_mean, 2)} / {np.round(z_var, 2)}, reuse {100 * reuse:.1f} %")
    assert reuse > 0.5  # the re-expressed archive is reused
    assert np.all(np.abs(z_mean) < 4) and np.all(np.abs(z_var) < 4), (z_mean, z_var, second)
    assert np.all(np.abs(second - 1.0) < CHAIN_Z2_TOLERANCE), second


@pytest.mark.slow
def test_chains_whose_distributions_are_not_reexpressed_are_biased():
    """The power of the test above: mapping the members without pushing their distributions forward inflates E[z^2]."""
    _, z_var, second, _ = reexpressed_chains("exact", dists_too=False)
    assert np.any(np.abs(second - 1.0) > 2 * CHAIN_Z2_TOLERANCE) and np.any(np.abs(z_var) > 4), (z_var, second)


# ------------------------------------------------------------------------------ 4. a run
class RecordingEvaluator:
    """Wraps an evaluator and remembers every parameter row it evaluated, with its episode seed and return."""

    def __init__(self, inner):
        self.inner, self.params, self.seeds, self.returns = inner, [], [], []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def evaluate(self, params, seeds):
        returns, steps = self.inner.evaluate(params, seeds)
        self.params.extend(np.asarray(params)), self.seeds.extend(np.asarray(seeds)), self.returns.extend(returns)
        return returns, steps


PENDULUM = ["env=gym", "env.id=Pendulum-v1", "algo=snes", "eim=true", "popsize=10", "sigma=0.05", "lr=0.01", "policy.hidden=[4]",
            "policy.obs_norm=true", "policy.obs_norm_warmup=3", "policy.obs_norm_freeze=false", "seeds=1"]  # fmt: skip


def reused_members_not_measured_as_they_are(generations: int = 12, variant: tuple = ()) -> tuple[list, int]:
    """Run PENDULUM (its algo and mixing replaced by ``variant``'s, if given); for every reused member, its parameters now
    (the current statistics folded in) must be those of an episode evaluated earlier, and a fresh episode of them with
    that episode's seed must return its stored return.
    Returns the members where that fails and the number of reused members."""
    args = [a for a in PENDULUM if not (variant and a in ("algo=snes", "eim=true"))]
    (spec,) = validate_overrides([*args, *variant])
    ev = RecordingEvaluator(lockstep_evaluator(spec))
    settings = loop_settings(spec, ev)
    st = new_seed_state(settings, 0)
    wrong, reused, means = [], 0, []
    for generation in range(generations):
        advance_lockstep([st], settings, ev)
        means.append(st.obs_norm.mean)
        if generation < spec.obs_norm_warmup:
            assert st.rows[-1]["reused"] == 0 and not st.archive.generations
            continue
        assert not st.obs_norm.frozen
        g, stored = st.archive.generations[0], st.archive.returns[0]  # this generation, re-expressed under the newest statistics
        evaluated = np.array(ev.params)
        for i in np.flatnonzero(g.source > 0):
            reused += 1
            folded = st.obs_norm.fold(g.samples[i : i + 1], ev.out_dim, ev.hidden)[0]
            gap = np.abs(evaluated - folded).max(axis=1)
            j = int(np.argmin(gap))
            if gap[j] > 1e-9 * max(1.0, np.abs(folded).max()):
                wrong.append((generation, i, "no episode of these parameters", float(gap[j])))
                continue
            fresh, _ = ev.inner.evaluate(folded[None, :], np.array([ev.seeds[j]]))
            if not (stored[i] == ev.returns[j] and abs(fresh[0] - stored[i]) <= 1e-9 * max(1.0, abs(stored[i]))):
                wrong.append((generation, i, float(stored[i]), float(fresh[0])))
    assert not np.allclose(means[spec.obs_norm_warmup], means[-1])  # the statistics kept moving after the warm-up
    return wrong, reused


def lockstep_evaluator(spec):
    from imix_cli.core.evaluation import make_evaluator

    return make_evaluator(spec.evaluator_key, spec.env_max_steps, hidden=spec.hidden)


VARIANTS = {
    "eim-exact": ("algo=snes", "eim=true"),
    "eim-conditional": ("algo=snes", "eim=true", "eim_variant=conditional"),
    "im-paper": ("algo=snes", "im=true"),
    "im-sun2009": ("algo=openes", "im=true", "im_variant=sun2009"),
    "ars-eim": ("algo=ars", "eim=true", "policy.hidden=[]", "popsize=16", "sigma=0.02"),
}


@pytest.mark.parametrize("variant", list(VARIANTS), ids=list(VARIANTS))
def test_every_reused_return_is_the_return_of_the_members_reexpressed_parameters(variant):
    wrong, reused = reused_members_not_measured_as_they_are(variant=VARIANTS[variant])
    assert reused > 20  # the check was exercised
    assert not wrong, wrong[:5]


def test_without_reexpression_reused_returns_belong_to_other_policies(monkeypatch):
    """The power of the test above: statistics that keep updating under an archive left as it was."""
    monkeypatch.setattr(lockstep, "reexpress_archive", lambda *args: None)
    wrong, reused = reused_members_not_measured_as_they_are()
    assert reused > 20 and len(wrong) == reused


# ------------------------------------------------------------------------------ checkpoints
def test_a_checkpoint_with_reexpressed_generations_resumes_to_the_uninterrupted_csv(tmp_path, capfd):
    import pandas as pd

    from imix_cli.running.files.checkpoints import checkpoint_path

    common = ["env=gym", "env.id=Pendulum-v1", "algo=snes", "eim=true", "seeds=1", "generations=10", "popsize=6", "policy.hidden=[]",
              "policy.obs_norm=true", "policy.obs_norm_warmup=2", "policy.obs_norm_freeze=false", "checkpoint_every=2", "checkpoint_seconds=0",
              "workers=1", "progress=false"]  # fmt: skip
    assert main(["run", *common, f"results_dir={tmp_path / 'ref'}"]) == 0
    spec = interrupted_run(common, tmp_path / "stop", after=7)
    assert "obs_norm_freeze=False" in spec.run_dir.name
    path = checkpoint_path(spec.run_dir, 0)
    with np.load(path) as npz:
        header = json.loads(npz["header"].tobytes())
    assert header["generation"] == 6 and "AffinePushforward" in json.dumps(header["state"])  # the archive holds re-expressed generations
    capfd.readouterr()
    assert main(["run", *common, f"results_dir={tmp_path / 'stop'}"]) == 0
    err = capfd.readouterr().err
    assert "checkpoint ignored" not in err, err  # resumed from generation 6, not recomputed from scratch
    name = spec.run_dir.relative_to(tmp_path / "stop")
    expected = read_run_csv(tmp_path / "ref" / name / "seed_0.csv").drop(columns="wall_time")
    got = read_run_csv(spec.run_dir / "seed_0.csv").drop(columns="wall_time")
    pd.testing.assert_frame_equal(got, expected)
    assert got["reused"].iloc[3:].sum() > 0


def test_a_pushforward_is_checkpointed_as_data_and_read_back_exactly(tmp_path):
    from imix_cli.running.files.checkpoints import read_checkpoint, write_checkpoint

    rng = np.random.default_rng(5)
    first, then = random_change(rng, 3, 2, ()), random_change(rng, 3, 2, ())
    second = NormalizerChange(3, 2, (), first.mean1, first.std1, then.mean1, then.std1)
    base = DiagonalGaussian(rng.normal(size=8), rng.uniform(0.5, 1.5, 8))
    push = AffinePushforward(AffinePushforward(base, first), second)
    archive = Archive(generations=[Generation(push.sample(5, rng), np.zeros(5, np.int64), np.full(5, -1, np.int64), push)])
    write_checkpoint(tmp_path / "c.npz", archive, identity={}, seed=0, generation=0)
    back = read_checkpoint(tmp_path / "c.npz", Archive(), identity={}, seed=0).generations[0]
    assert type(back.dist) is AffinePushforward and type(back.dist.base) is DiagonalGaussian and type(back.dist.transform) is NormalizerChange
    x = archive.generations[0].samples
    assert np.array_equal(back.samples, x) and np.array_equal(back.dist.log_prob(x), push.log_prob(x))
    assert back.dist.transform.log_det == push.transform.log_det


def test_a_normaliser_keeps_updating_after_the_warm_up_unless_frozen():
    x = np.random.default_rng(3).normal(3.0, 2.0, (10, 2))
    for freeze in (True, False):
        norm = ObsNormalizer(2, warmup=1, freeze=freeze)
        norm.add(x[:5], x[:5] ** 2, np.ones(5))
        norm.end_generation()
        assert not norm.warming and norm.frozen == freeze
        before = norm.mean
        norm.add(x[5:], x[5:] ** 2, np.ones(5))
        assert np.array_equal(norm.mean, before) == freeze
        assert ObsNormalizer.from_state(norm.to_state()).freeze == freeze
    old = {k: v for k, v in norm.to_state().items() if k != "freeze"}  # a checkpoint written before the key: frozen
    assert ObsNormalizer.from_state(old).freeze


# ------------------------------------------------------------------------------ the keys
def test_freeze_false_with_mixing_and_no_biases_is_refused_in_one_line(tmp_path, capsys):
    args = ["env=gym", "env.id=Pendulum-v1", "algo=snes", "policy.obs_norm=true", "policy.obs_norm_freeze=false", "policy.bias=false",
            "generations=2", "popsize=4", "progress=false", f"results_dir={tmp_path}"]  # fmt: skip
    for mixing in ("eim=true", "im=true"):
        assert main(["run", *args, mixing]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "policy.obs_norm_freeze=false" in err and "policy.bias=true" in err and "Traceback" not in err, err
    assert not tmp_path.exists() or not any(tmp_path.rglob("*.csv"))
    (spec,) = validate_overrides(args[:-1])  # without mixing: nothing to re-express, any bias
    assert not spec.obs_norm_freeze and not spec.policy_bias
    assert main(["run", *args[:3], "policy.obs_norm_freeze=false", "generations=2", "popsize=4", "progress=false", f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "policy.obs_norm=true" in err, err


def test_the_default_keeps_the_run_folder_and_config():
    base = [a for a in PENDULUM if a != "policy.obs_norm_freeze=false"]
    (frozen,) = validate_overrides(base)
    (explicit,) = validate_overrides([*base, "policy.obs_norm_freeze=true"])
    (updating,) = validate_overrides(PENDULUM)
    assert frozen.obs_norm_freeze and frozen.run_dir == explicit.run_dir and frozen.identity() == explicit.identity()
    assert "obs_norm_freeze" not in json.dumps(frozen.config.get("policy"))
    assert updating.run_dir != frozen.run_dir and updating.identity() != frozen.identity()
