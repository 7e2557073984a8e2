"""`imix plot` on small synthetic result sets written through the CSV contract."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import yaml

from imix_cli.plotting import main
from imix_cli.plotting.data import (
    RunGroup,
    align_on_grid,
    first_crossing,
    load_experiment,
    mean_ci,
    threshold_stats,
)
from imix_cli.plotting.didactic import Gauss1D, extended_importance_mixing
from imix_cli.running.files.results import run_dir_name, write_run_csv

EXPERIMENT = "synthetic"


def run_rows(algo, env, mixing, seed, scores, popsize=10, reused=None, reused_eim=None, steps_per_episode=20):
    """Rows of one seed: ``scores[g]`` is the population mean of generation g."""
    n = len(scores)
    reused = [0] * n if reused is None else list(reused)
    reused_eim = [0] * n if reused_eim is None else list(reused_eim)
    rows, evaluations = [], 0
    for g, score in enumerate(scores):
        evaluations += popsize - reused[g]
        rows.append(
            dict(
                algo=algo,
                env=env,
                mixing=mixing,
                seed=seed,
                generation=g,
                evaluations=evaluations,
                env_steps=evaluations * steps_per_episode,
                mean_score=float(score),
                best_score=float(score) + 1.0,
                reused=reused[g],
                reused_im=reused[g] - reused_eim[g],
                reused_eim=reused_eim[g],
                popsize=popsize,
                sigma_mean=0.25,
                nonfinite=0,
                wall_time=0.01 * g + 1e-4 * seed,  # seeds differ somewhere, as real ones do (identical rows read as a copy)
            )
        )
    return rows


def write_group(root, algo, env, mixing, seeds, gens=40, overrides="", config=None, popsize=10):
    run_dir = root / EXPERIMENT / run_dir_name(algo, env, mixing, overrides)
    run_dir.mkdir(parents=True, exist_ok=True)
    conf = {
        "im": mixing != "none",
        "eim": mixing == "eim",
        "seeds": len(seeds),
        "generations": gens,
        "popsize": popsize,
        "sigma": 0.25,
        "lr": 0.01,
        "algo": {"name": algo},
        "env": {"name": env},
    }
    conf.update(config or {})
    (run_dir / "config.yaml").write_text(yaml.safe_dump(conf))
    speed = {"snes": 8.0, "cem": 4.0, "cmaes": 6.0, "ddpg": 3.0}.get(algo, 5.0)
    for seed in seeds:
        rng = np.random.default_rng(seed + 100 * len(algo))
        scores = 200 - 180 * np.exp(-np.arange(gens) / speed) + rng.normal(0, 3, gens)
        reused = [0] + [int(rng.integers(popsize // 2, popsize)) if mixing != "none" else 0 for _ in range(gens - 1)]
        reused_eim = [min(int(r >= popsize - 2), r) for r in reused]  # never more than reused (popsize=1: none)
        write_run_csv(run_dir / f"seed_{seed}.csv", run_rows(algo, env, mixing, seed, scores, popsize, reused, reused_eim))
    return run_dir


@pytest.fixture
def results(tmp_path):
    """2 algos x cartpole x {none, eim} x 3 seeds, plus cmaes-cartpole-eim with only 2 seeds."""
    for algo in ("snes", "cem"):
        for mixing in ("none", "eim"):
            write_group(tmp_path, algo, "cartpole", mixing, range(3))
    write_group(tmp_path, "cmaes", "cartpole", "eim", range(2))
    return tmp_path


def figures_dir(root):
    return root / EXPERIMENT / "figures"


def test_main_writes_every_figure_and_table(results, capsys):
    status = main([f"results_dir={results}", f"experiment={EXPERIMENT}"])
    out, err = capsys.readouterr()
    assert status == 0, err
    fig_dir = figures_dir(results)
    stems = [
        "convergence_cartpole",
        "efficiency_cartpole",
    ]
    for stem in stems:
        for ext in ("png", "pdf"):
            path = fig_dir / f"{stem}.{ext}"
            assert path.stat().st_size > 1000, path
            assert str(path) in out  # prints where each file went
        assert (fig_dir / f"{stem}.png").stat().st_size < 150_000
    for stem in ("reuse", "evaluations_to_threshold"):
        for ext in ("csv", "md", "tex"):
            assert (fig_dir / f"{stem}.{ext}").stat().st_size > 100
    # the group with fewer seeds is flagged
    assert "cmaes-cartpole-eim" in err and "2 seed" in err
    reuse = pd.read_csv(fig_dir / "reuse.csv")
    assert set(reuse["algo"]) == {"snes", "cem", "cmaes"} and set(reuse["mixing"]) == {"eim"}
    assert "\\begin{tabular}" in (fig_dir / "reuse.tex").read_text()


def test_mean_ci_matches_hand_computation():
    mean, half, n = mean_ci([1.0, 2.0, 3.0, 4.0], level=0.68)
    sem = math.sqrt(((1.5**2 + 0.5**2) * 2) / 3) / 2  # sample std (ddof=1) / sqrt(4) = 0.645497
    assert mean == pytest.approx(2.5)
    assert n == 4
    assert sem == pytest.approx(0.645497, abs=1e-6)
    assert half == pytest.approx(1.188929 * sem, rel=1e-5)  # t_{0.84, 3} = 1.188929
    # per column, NaN ignored; one value gives no interval
    means, halves, counts = mean_ci(np.array([[1.0, 5.0], [3.0, np.nan]]), axis=0)
    assert means.tolist() == [2.0, 5.0] and counts.tolist() == [2, 1]
    assert halves[0] == pytest.approx(1.818993 * 1.0, rel=1e-5)  # t_{0.84, 1} * (sqrt(2) / sqrt(2))
    assert math.isnan(halves[1])


def _group(frames):
    return RunGroup("snes", "cartpole", "eim", "", None, {}, {i: f for i, f in enumerate(frames)})


def test_evaluations_to_threshold_on_hand_made_data():
    # seed 0 costs 10 per generation, seed 1 reuses 5 from generation 1 on, seed 2 never reaches 195
    s0 = pd.DataFrame(run_rows("snes", "cartpole", "eim", 0, [50, 150, 196, 180, 199]))
    s1 = pd.DataFrame(run_rows("snes", "cartpole", "eim", 1, [50, 195, 100, 100, 100], reused=[0, 5, 5, 5, 5]))
    s2 = pd.DataFrame(run_rows("snes", "cartpole", "eim", 2, [50, 60, 70, 80, 194.9]))
    assert first_crossing(s0, 195) == 30.0  # first reached at generation 2, after 10 + 10 + 10 episodes
    assert first_crossing(s1, 195) == 15.0  # generation 1: 10 + 5 (>= counts)
    assert first_crossing(s2, 195) is None
    info = threshold_stats(_group([s0, s1, s2]), 195)
    assert info["n_seeds"] == 3 and info["reached"] == 2
    assert info["mean"] == pytest.approx(22.5) and info["median"] == pytest.approx(22.5)
    assert info["ci"] == pytest.approx(1.818993 * 7.5, rel=1e-5)  # t_{0.84,1} * std([30, 15]) / sqrt(2)
    none = threshold_stats(_group([s2]), 195)
    assert none["reached"] == 0 and math.isnan(none["mean"])


def test_align_on_grid_holds_last_generation_within_budget():
    # evaluations 10, 15, 15 (a generation fully reused), 25
    a = pd.DataFrame(run_rows("snes", "cartpole", "eim", 0, [1, 2, 3, 4], reused=[0, 5, 10, 0]))
    b = pd.DataFrame(run_rows("snes", "cartpole", "eim", 1, [10, 20, 30, 40, 50], popsize=5))  # 5, 10, ..., 25
    grid, matrix = align_on_grid(_group([a, b]), points=4)
    assert grid.tolist() == [10.0, 15.0, 20.0, 25.0]  # common support: max first (10) to min last (25)
    assert matrix[0].tolist() == [1, 3, 3, 4]  # at 15 the later of the two generations with 15 episodes
    assert matrix[1].tolist() == [20, 30, 40, 50]


def test_threshold_table_reduction_and_seeds_that_never_reach(tmp_path, capsys):
    root = tmp_path
    for mixing, costs in (("none", 10), ("eim", 2)):
        run_dir = root / EXPERIMENT / run_dir_name("snes", "cartpole", mixing)
        run_dir.mkdir(parents=True)
        reused = [0] + [10 - costs] * 9
        for seed, reach_at in enumerate((4, 6, None)):
            scores = [100.0] * 10 if reach_at is None else [100.0] * reach_at + [200.0] * (10 - reach_at)
            write_run_csv(run_dir / f"seed_{seed}.csv", run_rows("snes", "cartpole", mixing, seed, scores, 10, reused))
    assert main([f"results_dir={root}", f"experiment={EXPERIMENT}", "only=threshold"]) == 0
    table = pd.read_csv(figures_dir(root) / "evaluations_to_threshold.csv").set_index("mixing")
    # none: generation 4 -> 50 episodes, generation 6 -> 70; eim: 10 + 4*2 = 18 and 10 + 6*2 = 22
    assert table.loc["none", "evaluations_mean"] == pytest.approx(60)
    assert table.loc["eim", "evaluations_mean"] == pytest.approx(20)
    assert table.loc["eim", "reached"] == 2 and table.loc["eim", "seeds"] == 3
    assert table.loc["eim", "reduction"] == pytest.approx(3.0)
    markdown = (figures_dir(root) / "evaluations_to_threshold.md").read_text()
    assert "2/3" in markdown and "×3.00" in markdown


def test_reuse_table_hand_values(tmp_path):
    run_dir = tmp_path / EXPERIMENT / run_dir_name("cem", "acrobot", "eim")
    run_dir.mkdir(parents=True)
    # 4 generations of 10: reused 0, 6, 8, 6 -> 20/40 = 50 %; from EIM 1 + 1 of 20 -> 10 %
    write_run_csv(run_dir / "seed_0.csv", run_rows("cem", "acrobot", "eim", 0, [-200, -150, -120, -90], 10, [0, 6, 8, 6], [0, 1, 0, 1]))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=reuse"]) == 0
    row = pd.read_csv(figures_dir(tmp_path) / "reuse.csv").iloc[0]
    assert row["total_reuse_pct"] == pytest.approx(50.0)
    assert row["from_im_pct"] == pytest.approx(90.0) and row["from_eim_pct"] == pytest.approx(10.0)


def test_corrupt_csv_is_named_and_the_rest_still_plots(results, capsys):
    bad = results / EXPERIMENT / "snes-cartpole-eim" / "seed_1.csv"
    bad.write_text("algo,env\nthis is,not a result\n")
    (results / EXPERIMENT / "cem-cartpole-none" / "seed_2.csv").write_text("")
    status = main([f"results_dir={results}", f"experiment={EXPERIMENT}", "only=convergence,efficiency,reuse,threshold"])
    out, err = capsys.readouterr()
    assert status == 0
    assert str(bad) in err and "cem-cartpole-none/seed_2.csv" in err
    assert (figures_dir(results) / "convergence_cartpole.png").exists()
    assert (figures_dir(results) / "efficiency_cartpole.pdf").exists()
    assert "Traceback" not in err
    exp = load_experiment(results, EXPERIMENT, warn=lambda message: None)
    assert {g.name: g.n_seeds for g in exp.groups}["snes-cartpole-eim"] == 2


@pytest.mark.parametrize(
    "arg, key",
    [
        ("foo=1", "foo"),
        ("threshold.cartpole=abc", "threshold.cartpole"),
        ("ci=2", "ci"),
        ("only=nothing", "only"),
        ("dpi=ten", "dpi"),
        ("formats=gif", "formats"),
        ("results_dir", "results_dir"),
    ],
)
def test_bad_key_or_value_exits_2_with_one_line(arg, key, capsys):
    assert main([arg]) == 2
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and key in err and "Traceback" not in err


def test_help_and_missing_experiment(tmp_path, capsys):
    assert main(["--help"]) == 0
    out, _ = capsys.readouterr()
    assert "threshold.<env>" in out and "results_dir" in out
    assert main([f"results_dir={tmp_path}", "experiment=nope"]) == 1
    _, err = capsys.readouterr()
    assert "nope" in err and err.count("\n") == 1


def test_gridsearch_and_ddpg_figures(tmp_path, capsys):
    for popsize in (5, 10, 20):
        write_group(tmp_path, "snes", "continuous_cartpole", "eim", range(2), gens=30, popsize=popsize, overrides=f"popsize={popsize}", config={"sigma": 0.1})
    for sigma in (0.05, 0.5):
        write_group(tmp_path, "snes", "continuous_cartpole", "eim", range(2), gens=30, overrides=f"sigma={sigma}", config={"sigma": sigma})
    write_group(tmp_path, "ddpg", "continuous_cartpole", "none", range(2), gens=60, popsize=1)
    status = main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=gridsearch,ddpg", "threshold.continuous_cartpole=150"])
    _, err = capsys.readouterr()
    assert status == 0, err
    fig_dir = figures_dir(tmp_path)
    assert (fig_dir / "gridsearch_snes_continuous_cartpole_eim_popsize.png").exists()
    assert (fig_dir / "gridsearch_snes_continuous_cartpole_eim_sigma.pdf").exists()
    assert (fig_dir / "ddpg_continuous_cartpole.png").exists()
    ranking = pd.read_csv(fig_dir / "gridsearch_ranking.csv")
    assert sorted(ranking["rank"]) == [1, 2, 3, 4, 5]
    assert ranking.sort_values("rank")["evaluations_mean"].dropna().is_monotonic_increasing


def test_didactic_rules_match_the_paper():
    """Rule 1 keeps old samples with prob min(1, p_new/p_old); Rule 2 keeps new ones with max(0, 1 - p_old/p_new)."""
    old, new = Gauss1D(0.0, 1.0), Gauss1D(0.5, 1.0)
    rng = np.random.default_rng(0)
    result = extended_importance_mixing(new, [(old, old.sample(20000, rng))], 20000, rng, fill=False)
    trials = [t for t in result.trials if t.source == "old"]
    z = np.array([t.z for t in trials])
    accepted = np.array([t.accepted for t in trials])
    # geometric view used by the figure: accepted exactly when the point lies under min(p_old, p_new)
    heights = np.array([t.height for t in trials])
    assert np.array_equal(accepted, heights < np.minimum(old.pdf(z), new.pdf(z)))
    # overall acceptance of old samples = overlap area (2 Phi(-|delta|/2) for unit variances)
    from scipy.stats import norm

    assert accepted.mean() == pytest.approx(2 * norm.cdf(-0.25), abs=0.02)


# --------------------------------------------------------------------------- every run, live runs, robust statistics


def _legend_texts(fig):
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()]


def test_every_run_folder_is_its_own_labelled_curve_and_row(tmp_path):
    from imix_cli.plotting.data import PlotOptions
    from imix_cli.plotting.figures import efficiency_figures

    write_group(tmp_path, "snes", "cartpole", "none", range(5))
    write_group(tmp_path, "snes", "cartpole", "none", range(5), overrides="weight_decay_form=estool", config={"weight_decay_form": "estool"})
    write_group(tmp_path, "snes", "cartpole", "eim", range(5))
    exp = load_experiment(tmp_path, EXPERIMENT, warn=lambda m: None)
    ((_, fig),) = list(efficiency_figures(exp, PlotOptions()))
    assert {"SNES", "SNES (weight_decay_form=estool)"} <= set(_legend_texts(fig))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold,iqm"]) == 0
    table = pd.read_csv(figures_dir(tmp_path) / "evaluations_to_threshold.csv")
    assert sorted(table["overrides"].fillna("")) == ["", "", "weight_decay_form=estool"]
    assert len(pd.read_csv(figures_dir(tmp_path) / "iqm.csv")) == 3


def test_grid_search_points_left_out_of_main_figures_are_named(tmp_path, capsys):
    for popsize in (10, 20):
        write_group(tmp_path, "snes", "cartpole", "eim", range(2), overrides=f"popsize={popsize}", popsize=popsize)
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=efficiency"]) == 0
    err = capsys.readouterr().err
    assert "left out of the main figures" in err and "snes-cartpole-eim-popsize=10" in err and "snes-cartpole-eim-popsize=20" in err


def test_running_seeds_are_read_from_partial_csvs_and_curves_reach_the_longest(tmp_path, capsys):
    from imix_cli.running.files.results import partial_csv_path

    run_dir = write_group(tmp_path, "snes", "cartpole", "none", range(2), gens=40)
    write_run_csv(partial_csv_path(run_dir, 2), run_rows("snes", "cartpole", "none", 2, np.linspace(20, 60, 12)))
    warnings = []
    exp = load_experiment(tmp_path, EXPERIMENT, warn=warnings.append)
    (group,) = exp.groups
    assert sorted(group.seeds) == [0, 1, 2] and group.partial == {2}
    assert any("still running" in w and "2" in w for w in warnings)
    from imix_cli.plotting.data import align_by_generation

    gens, matrix = align_by_generation(group)
    assert len(gens) == 40 and np.isnan(matrix[2, 12:]).all() and np.isfinite(matrix[:2]).all()
    grid, matrix = align_on_grid(group)
    assert grid[-1] == 400  # the longest seed's 40 generations x 10 episodes, not the running seed's 120
    # a finished seed wins over a stale partial file of the same seed
    write_run_csv(partial_csv_path(run_dir, 0), run_rows("snes", "cartpole", "none", 0, [1.0, 2.0]))
    exp = load_experiment(tmp_path, EXPERIMENT, warn=lambda m: None)
    assert len(exp.groups[0].seeds[0]) == 40 and exp.groups[0].partial == {2}


def test_efficiency_overlays_mixing_on_one_axis_log_x_when_it_helps_and_bands_stay_within_achievable_returns(tmp_path):
    from matplotlib.collections import PolyCollection

    from imix_cli.plotting.data import PlotOptions
    from imix_cli.plotting.figures import efficiency_figures

    def experiment(eim_reuse):
        root = tmp_path / f"reuse{eim_reuse}"
        for mixing in ("none", "eim"):
            run_dir = root / EXPERIMENT / run_dir_name("snes", "cartpole", mixing)
            run_dir.mkdir(parents=True)
            reused = [0] + [eim_reuse if mixing == "eim" else 0] * 9
            for seed, top in enumerate((200.0, 200.0, 120.0)):  # two seeds at the cap, one far below: a wide CI
                write_run_csv(run_dir / f"seed_{seed}.csv", run_rows("snes", "cartpole", mixing, seed, np.linspace(50, top, 10), reused=reused))
        ((_, fig),) = list(efficiency_figures(load_experiment(root, EXPERIMENT, warn=lambda m: None), PlotOptions()))
        return fig

    similar, far_apart = experiment(2), experiment(9)  # EIM evaluates 8 or 1 of 10 members per generation
    for fig in (similar, far_apart):
        (ax,) = fig.axes  # no mixing and mixing on one axis
        assert len([line for line in ax.get_lines() if line.get_label() in ("SNES", "SNES + EIM")]) == 2
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(bands) == 2 and max(path.vertices[:, 1].max() for c in bands for path in c.get_paths()) <= 200.0
        assert "3 seeds, <5: weak CI" in fig.get_suptitle()
    assert similar.axes[0].get_xscale() == "linear" and far_apart.axes[0].get_xscale() == "log"


def test_main_figures_say_which_grid_search_runs_they_leave_out(tmp_path):
    from imix_cli.plotting.data import PlotOptions
    from imix_cli.plotting.figures import convergence_figures, efficiency_figures

    write_group(tmp_path, "snes", "cartpole", "eim", range(2))
    for popsize in (10, 20):
        write_group(tmp_path, "snes", "cartpole", "eim", range(2), overrides=f"popsize={popsize}", popsize=popsize)
    exp = load_experiment(tmp_path, EXPERIMENT, warn=lambda m: None)
    for draw in (convergence_figures, efficiency_figures):
        ((_, fig),) = list(draw(exp, PlotOptions()))
        assert "not shown: 2 grid-search run(s)" in fig.get_suptitle()


def test_profile_axis_fits_the_final_returns_and_its_threshold_is_in_the_legend(tmp_path):
    from imix_cli.plotting.data import PlotOptions
    from imix_cli.plotting.figures import profile_figures

    write_group(tmp_path, "snes", "cartpole", "none", range(5))  # final returns near 200 (170-200 with noise)
    exp = load_experiment(tmp_path, EXPERIMENT, warn=lambda m: None)
    ((_, fig),) = list(profile_figures(exp, PlotOptions(thresholds={"cartpole": 195.0})))
    (ax,) = fig.axes
    finals = [f["mean_score"].iloc[-1] for f in exp.groups[0].frames()]
    lo, hi = ax.get_xlim()
    assert lo < min(finals) and hi > max(finals, default=0) and hi - lo < 0.5 * 200  # not the 0-200 of achievable returns
    assert "threshold 195" in [t.get_text() for t in ax.get_legend().get_texts()]


@pytest.mark.slow
def test_didactic_figures_only_when_asked(tmp_path, capsys):
    write_group(tmp_path, "snes", "cartpole", "none", range(2))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=convergence,efficiency,reuse"]) == 0
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "formats=png"]) == 0
    assert not list(figures_dir(tmp_path).glob("didactic_*"))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "formats=png", "didactic=true"]) == 0
    assert len(list(figures_dir(tmp_path).glob("didactic_*.png"))) == 3
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "didactic=maybe"]) == 2


def test_iqm_and_improvement_tables_hand_values(tmp_path):
    # eim reaches 195 at generation 2 (10 + 2*2 = 14 episodes) on every seed; none at generation 5 (60 episodes)
    for mixing, cost, reach in (("none", 10, 5), ("eim", 2, 2)):
        run_dir = tmp_path / EXPERIMENT / run_dir_name("cem", "cartpole", mixing)
        run_dir.mkdir(parents=True)
        for seed in range(8):
            scores = [100.0] * reach + [190.0 + seed] * (10 - reach)
            scores[reach] = 200.0  # the crossing
            write_run_csv(run_dir / f"seed_{seed}.csv", run_rows("cem", "cartpole", mixing, seed, scores, 10, [0] + [10 - cost] * 9))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=iqm,improvement,profile"]) == 0
    iqm = pd.read_csv(figures_dir(tmp_path) / "iqm.csv").set_index("mixing")
    assert iqm.loc["eim", "episodes_iqm"] == 14 and iqm.loc["none", "episodes_iqm"] == 60
    # final returns 190..197: IQM of 8 cuts 2 at each end -> mean(192..195) = 193.5
    assert iqm.loc["none", "final_iqm"] == pytest.approx(193.5)
    assert iqm.loc["none", "final_iqm_low"] <= 193.5 <= iqm.loc["none", "final_iqm_high"]
    improvement = pd.read_csv(figures_dir(tmp_path) / "improvement.csv")
    assert improvement["p_fewer_episodes"].tolist() == [1.0] and improvement["ci_low"].tolist() == [1.0]
    assert (figures_dir(tmp_path) / "profile_cartpole.png").stat().st_size > 1000


def test_an_env_no_seed_reaches_is_left_out_of_the_threshold_table_with_one_warning(tmp_path, capsys):
    """A short run (make reproduce-quick: 30 generations) reaches no threshold: its rows would all be 0/n and –."""
    write_group(tmp_path, "snes", "cartpole", "none", range(3))
    write_group(tmp_path, "snes", "cartpole", "eim", range(3))
    write_group(tmp_path, "snes", "acrobot", "eim", range(3))
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold", "threshold.acrobot=1000"]) == 0
    err = capsys.readouterr().err
    assert "evaluations_to_threshold leaves out acrobot (no seed reached 1000)" in err and "cartpole" not in err.split("leaves out")[1].split("\n")[0], err
    table = pd.read_csv(figures_dir(tmp_path) / "evaluations_to_threshold.csv")
    assert set(table["env"]) == {"cartpole"} and (table["reached"] > 0).all()
    (figures_dir(tmp_path) / "evaluations_to_threshold.md").unlink()
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold", "threshold.acrobot=1000", "threshold.cartpole=1000"]) == 0
    assert not (figures_dir(tmp_path) / "evaluations_to_threshold.md").exists()  # no table at all rather than one of 0/3


def test_one_runs_figure_titles_lie_inside_the_figure(tmp_path):
    """The main job's figures of a single run (one panel): every line of the three-line title is drawn inside the
    figure (the title was wider than the 5-inch figure and lost both ends). Made to fail: with fig.suptitle in place
    of fitted_suptitle, the convergence title's box ran from x=-148 to 648 px on a 500 px wide figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from imix_cli.plotting.data import PlotOptions
    from imix_cli.plotting.figures import convergence_figures, efficiency_figures

    write_group(tmp_path, "snes", "cartpole", "none", range(1))
    exp = load_experiment(tmp_path, EXPERIMENT, warn=lambda m: None)
    for draw in (convergence_figures, efficiency_figures):
        ((name, fig),) = list(draw(exp, PlotOptions()))
        renderer = FigureCanvasAgg(fig).get_renderer()
        fig.draw(renderer)
        title, box = fig.get_suptitle(), fig._suptitle.get_window_extent(renderer)
        assert title.count("\n") >= 2, (name, title)  # still the whole title: what, how, the dots
        assert 0 <= box.x0 and box.x1 <= fig.bbox.width and 0 <= box.y0 and box.y1 <= fig.bbox.height, (name, box, fig.bbox)


def _noisy_pair(root, theta_measured=True):
    """A noisy task where the population flatters mixing: with EIM the population mean (reused members keep lucky
    stored returns) crosses 195 at generation 2 while θ on fresh episodes only does at generation 8; without mixing
    both cross at generation 5. Costs: 10 episodes per generation without mixing, 4 with EIM (6 reused)."""
    for mixing, population_at, theta_at, reused in (("none", 5, 5, 0), ("eim", 2, 8, 6)):
        run_dir = root / EXPERIMENT / run_dir_name("cem", "cartpole", mixing)
        run_dir.mkdir(parents=True)
        for seed in range(6):
            population = [150.0] * population_at + [199.0] * (10 - population_at)
            rows = run_rows("cem", "cartpole", mixing, seed, population, 10, [0] + [reused] * 9)
            for g, row in enumerate(rows):  # θ measured every other generation, as eval_mean_every=2 does
                measured = theta_measured and g % 2 == 0
                row["mean_policy_score"] = (196.0 + 0.5 * seed if g >= theta_at else 120.0) if measured else float("nan")
            write_run_csv(run_dir / f"seed_{seed}.csv", rows)


def test_headline_tables_and_figures_measure_theta_on_fresh_episodes_where_the_population_flatters_mixing(tmp_path, capsys):
    """Where population and θ disagree (a noisy task), the threshold, iqm, improvement tables, the efficiency figure and
    the profile rank by θ by default; measure=population gives the paper's measure. Made to fail: with the threshold
    table's column fixed to mean_score the default run reads the population's 60 and 18 episodes, not θ's 70 and 42."""
    _noisy_pair(tmp_path)
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold,iqm,improvement,efficiency,profile"]) == 0
    assert "warning" not in capsys.readouterr().err
    table = pd.read_csv(figures_dir(tmp_path) / "evaluations_to_threshold.csv").set_index("mixing")
    # θ: none at generation 6 (first measurement at or after 5): 70 episodes; eim at 8: 10 + 8 * 4 = 42
    assert table.loc["none", "evaluations_mean"] == pytest.approx(70) and table.loc["eim", "evaluations_mean"] == pytest.approx(42)
    assert set(table["measure"]) == {"θ on fresh episodes"}
    iqm = pd.read_csv(figures_dir(tmp_path) / "iqm.csv").set_index("mixing")
    assert iqm.loc["eim", "final_iqm"] == pytest.approx(197.25)  # θ's final 196 + seed / 2 (middle four); the population ends at 199
    assert table.loc["eim", "reached"] == 6
    assert "θ on fresh episodes" in (figures_dir(tmp_path) / "evaluations_to_threshold.md").read_text()
    improvement = pd.read_csv(figures_dir(tmp_path) / "improvement.csv")
    assert improvement["p_fewer_episodes"].tolist() == [1.0]  # 42 < 70 on every pair, by θ too
    (figures_dir(tmp_path) / "evaluations_to_threshold.csv").unlink()
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold", "measure=population"]) == 0
    table = pd.read_csv(figures_dir(tmp_path) / "evaluations_to_threshold.csv").set_index("mixing")
    assert table.loc["none", "evaluations_mean"] == pytest.approx(60) and table.loc["eim", "evaluations_mean"] == pytest.approx(18)
    assert set(table["measure"]) == {"population mean return"}


def test_the_efficiency_figure_draws_theta_held_between_measurements_and_the_population_thin_beside_it(tmp_path):
    from imix_cli.plotting.data import PlotOptions, load_experiment
    from imix_cli.plotting.figures import efficiency_curves, efficiency_figures, efficiency_groups

    _noisy_pair(tmp_path)
    exp = load_experiment(tmp_path, EXPERIMENT)
    ((stem, fig),) = list(efficiency_figures(exp, PlotOptions()))
    ax = fig.axes[0]
    assert ax.get_ylabel() == "θ on fresh episodes"
    assert any("thin: population mean return" in t.get_text() for t in fig.legends[0].get_texts())
    _, curves = efficiency_curves(efficiency_groups(exp, "cartpole"), "mean_policy_score")
    for _group, _x, matrix in curves:
        assert np.isfinite(matrix).all()  # held from each measurement to the next, never a gap
        assert set(np.unique(matrix[0])) == {120.0, 196.0}  # seed 0: before and after θ's crossing


def test_a_run_without_theta_falls_back_to_the_population_for_the_whole_output_with_one_warning(tmp_path, capsys):
    _noisy_pair(tmp_path, theta_measured=False)
    assert main([f"results_dir={tmp_path}", f"experiment={EXPERIMENT}", "only=threshold"]) == 0
    err = capsys.readouterr().err
    assert err.count("no θ measured in") == 1 and "eval_mean_every=0" in err
    table = pd.read_csv(figures_dir(tmp_path) / "evaluations_to_threshold.csv")
    assert set(table["measure"]) == {"population mean return"}


def test_measure_key_is_checked():
    assert main(["measure=fresh"]) == 2
