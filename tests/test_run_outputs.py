"""What `imix run` leaves for the user: the summary's comparison with and without mixing, and the
partial CSV that lets `imix plot` / `imix status` follow a running seed."""

from __future__ import annotations

import re

import numpy as np
import pytest

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.results import partial_csv_path, read_run_csv
from imix_cli.running.runner import run_seeds

TINY = ["algo=cem", "env=cartpole", "generations=4", "popsize=8", "progress=false", "workers=1"]


def test_summary_compares_with_and_without_mixing_and_has_no_nan(tmp_path, capsys):
    assert main(["run", *TINY, "seeds=1", "eim=false", f"results_dir={tmp_path}"]) == 0
    first = capsys.readouterr().out
    assert "nan" not in first  # one seed: the value without a CI
    assert main(["run", *TINY, "seeds=1", "eim=true", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert "episodes/seed" in lines[0]
    runs = [line.split()[0] for line in lines[1:3]]
    assert runs == ["cem-cartpole-eim-popsize=8", "cem-cartpole-none-popsize=8"]
    none = read_run_csv(tmp_path / "default" / "cem-cartpole-none-popsize=8" / "seed_0.csv")["evaluations"].iloc[-1]
    eim = read_run_csv(tmp_path / "default" / "cem-cartpole-eim-popsize=8" / "seed_0.csv")["evaluations"].iloc[-1]
    assert f"{none / eim:.2f}x fewer episodes for the same 4 generations" in out
    # the header's columns line up with long run names
    assert lines[0].index("seeds") + len("seeds") == lines[1].index(" 1 ") + 2


def test_partial_csv_at_each_checkpoint_then_removed(tmp_path, monkeypatch):
    monkeypatch.setenv("IMIX_COMPILED_LOOP", "0")  # a progress call per generation (the compiled loop's come per chunk)
    spec = validate_overrides([*TINY, "seeds=1", "generations=5", "checkpoint_every=2", "checkpoint_seconds=0", f"results_dir={tmp_path}"])[0]
    spec.run_dir.mkdir(parents=True)
    seen = []

    def progress(_n):  # called after every generation, once its checkpoint (if any) is written
        path = partial_csv_path(spec.run_dir, 0)
        seen.append(len(read_run_csv(path)) if path.exists() else 0)

    run_seeds(spec, [0], progress=progress)
    assert seen == [0, 2, 2, 4, 0]  # rows up to the last checkpoint; gone once seed_0.csv exists
    assert not partial_csv_path(spec.run_dir, 0).exists() and (spec.run_dir / "seed_0.csv").exists()


def test_missing_env_extra_is_one_line_with_its_install_hint(tmp_path, capsys):
    import importlib.util

    import pytest

    if importlib.util.find_spec("Box2D") is not None:
        pytest.skip("Box2D is installed here")
    assert main(["run", "env=gym", "env.id=LunarLander-v3", "seeds=1", "generations=1", f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "LunarLander-v3" in err[0] and 'pip install "gymnasium[box2d]"' in err[0]
    assert not any(tmp_path.iterdir())  # nothing written, not even config.yaml


def test_argparse_style_option_suggests_key_value(tmp_path, capsys):
    assert main(["run", "--seeds", "3", f"results_dir={tmp_path}"]) == 2
    assert main(["run", "--seeds=3", f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all("seeds=3" in line for line in err)


def test_summary_leads_with_theta_on_fresh_episodes_then_the_population_and_says_which_has_no_reused_returns(tmp_path, capsys):
    """The first score of the summary is θ on fresh episodes, the population mean (stored returns) beside it; the line
    comparing a run with its twin without mixing compares θ. Made to fail by swapping the columns back."""
    assert main(["run", "-m", *TINY, "seeds=2", "eim=false,true", "eval_mean_every=2", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    lines = out[out.index("sweep: 2 run(s)") :].splitlines()
    assert lines[1].index("θ fresh") < lines[1].index("population")
    for line in lines[2:4]:
        run = line.split()[0]
        frames = [read_run_csv(tmp_path / "default" / run / f"seed_{k}.csv") for k in (0, 1)]
        theta = np.mean([f["mean_policy_score"].dropna().iloc[-1] for f in frames])
        population = np.mean([f["mean_score"].iloc[-1] for f in frames])
        scores = line.split()[2:]  # after the name and the seeds: θ's mean, ±, half-width, then the population's
        assert float(scores[0]) == pytest.approx(theta, abs=0.006) and float(scores[3]) == pytest.approx(population, abs=0.006)
    assert main(["run", *TINY, "seeds=2", "eim=true", "eval_mean_every=2", f"results_dir={tmp_path}"]) == 0
    comparison = [line for line in capsys.readouterr().out.splitlines() if " vs " in line]
    assert comparison and "(the same settings but the mixing)" in comparison[0] and "final θ fresh" in comparison[0]
    lines = out.splitlines()
    assert any("θ fresh: distribution mean on fresh episodes" in line and "free of reused returns" in line for line in lines)


def test_a_sweep_ends_with_one_table_of_every_point(tmp_path, capsys):
    assert main(["run", "-m", *TINY, "seeds=1", "eim=false,true", "popsize=8,9", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    table = out[out.index("sweep: 4 run(s)") :].splitlines()
    runs = sorted(line.split()[0] for line in table[2:6])
    assert runs == sorted(f"cem-cartpole-{m}-popsize={p}" for m in ("none", "eim") for p in (8, 9))
    # ... and only that table: each point before it says one line, not its own table
    before = out[: out.index("sweep: 4 run(s)")].splitlines()
    assert len(before) == 4 and all(re.fullmatch(rf"\[{k}/4\] cem-cartpole-\w+-popsize=\d done", line) for k, line in enumerate(before, 1)), before


def test_version(capsys):
    from imix_cli import __version__

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"imix {__version__}"


def test_a_sweep_table_says_whether_its_runs_with_mixing_differ_from_their_twins_in_the_mixing_alone():
    """The sweep's table names any resolved setting besides the mixing that differs between a run with mixing and its
    nearest run without (CMA-ES's step-size rule once did, by default). Made to fail: with the comparison reading only
    the top-level keys, the step-size rule (algo.step_size_control, nested) went unnamed."""
    from imix_cli.running.summary import mixing_pairs_note

    assert mixing_pairs_note(validate_overrides(["algo=cmaes", "eim=false,true", "popsize=20,30"])) == (
        "with and without mixing: each pair of runs differs in the mixing alone"
    )
    mismatched = [*validate_overrides(["algo=cmaes", "eim=false"]), *validate_overrides(["algo=cmaes", "eim=true", "algo.step_size_control=csa"])]
    assert (
        mixing_pairs_note(mismatched)
        == "cmaes-cartpole-eim-algo.step_size_control=csa vs cmaes-cartpole-none: differ in algo.step_size_control besides the mixing"
    )
    assert mixing_pairs_note(validate_overrides(["algo=cmaes", "eim=true", "popsize=20,30"])) is None
